"""Noise against speed: the certified noise gain of a problem's designs over its certified decays.

``uiofmu tradeoff PROBLEM -o tradeoff.png`` designs the problem at decays spread from the fastest one its
family certifies (``decay = "max"``) toward 1, twice at each: the default design (least overshoot bound) and
the least-noise design (``observer.noise = "min"``). Every point is a design certified as ``uiofmu design``
certifies it, and its ``gain_y`` is the card's (:mod:`uiofmu.noise`): what a sensor noise does to the estimate,
against how fast the estimate converges. The plot marks the problem's own design and its noise-optimal one
(and, with ``observer.noise_gain``, the fastest decay within that gain); a table with the same numbers is
written next to it.

The module imports what it uses when it runs (the command line reads :data:`POINTS` only when it shows
``uiofmu tradeoff --help`` or runs the command).

A family offers the trade-off when its module has ``noise_options(options, decay, noise)``: its options at
another decay with the noise objective ``"default"`` or ``"min"`` (:mod:`uiofmu.families`), and reads the decay
asked for as ``options.decay``; a family that has none may say why in ``NO_NOISE_DESIGN``.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

#: Decays a trade-off designs at by default (besides the fastest), and the fraction of the way from the fastest
#: decay to 1 the slowest of them lies at.
POINTS = 12
SLOWEST = 0.95


@dataclass
class Point:
    """One decay of the trade-off: the certified ``gain_y`` and overshoot bound of its two designs (None where
    the design found no certificate, ``why`` says why)."""

    decay: float
    gain_default: float | None = None
    gain_least: float | None = None
    overshoot_default: float | None = None
    overshoot_least: float | None = None
    why: list = field(default_factory=list)


@dataclass
class Tradeoff:
    """A problem's trade-off: its points, and the designs the plot marks (``label -> (decay, gain_y)``)."""

    name: str
    fastest: float
    points: list
    marks: dict


def families_with_tradeoff() -> list[str]:
    """The families whose module offers ``noise_options`` (the noise-aware designs a trade-off needs)."""
    from .families import available_family
    from .runtime.registry import AVAILABLE

    return [name for name in AVAILABLE if hasattr(available_family(name), "noise_options")]


def _card(problem, options):
    """The card of ``problem`` with ``options``, or the reason there is none."""
    from .runtime.errors import InfeasibleError, NoObserverError
    from .synthesis import design

    try:
        return design(replace(problem, options=options)), None
    except (InfeasibleError, NoObserverError) as exc:
        return None, str(exc)


def _figures(card) -> tuple:
    if card is None:
        return None, None
    return (card.data.get("noise") or {}).get("gain_y"), card.data.get("overshoot_bound")


def tradeoff(problem, points: int = POINTS, progress=None) -> Tradeoff:
    """Design ``problem`` at ``points`` decays from its fastest certified one toward 1, by default and by least
    noise.

    Parameters
    ----------
    problem : Problem
        A problem of a family in :func:`families_with_tradeoff`.
    points : int
        Decays besides the fastest (at least 2).
    progress : callable, optional
        Called once per design made (a progress bar's ``update``).

    Returns
    -------
    Tradeoff

    Raises
    ------
    ProblemError
        When the family has no noise-aware design, or ``points`` is below 2.
    NoObserverError, InfeasibleError
        When the problem has no certified design at all.
    """
    from .families import available_family
    from .runtime.errors import ProblemError
    from .synthesis import design

    family = available_family(problem.family)
    if not hasattr(family, "noise_options"):
        why = getattr(family, "NO_NOISE_DESIGN", None)                  # a family that says why it has none
        raise ProblemError(f"uiofmu tradeoff: observer.family = {problem.family!r} has no noise-aware design; the "
                           f"trade-off is drawn for {', '.join(families_with_tradeoff())}"
                           + (f" ({why})" if why else ""))
    if points < 2:
        raise ProblemError(f"--points = {points}: a trade-off needs at least 2 decays")
    tick = progress or (lambda *_: None)
    opts = problem.options
    given = design(problem)
    tick()
    fastest_card = given if opts.decay == "max" and opts.noise == "default" and getattr(opts, "noise_gain", None) \
        is None else design(replace(problem, options=family.noise_options(opts, "max", "default")))
    tick()
    fastest = float(fastest_card.data["decay_bound"])
    least_card, _ = _card(problem, family.noise_options(opts, opts.decay, "min"))
    tick()
    goal = getattr(opts, "noise_gain", None)
    label = "this problem's design" if goal is None else f"this problem's design (noise_gain = {goal:g})"
    marks = {label: (given.data["decay_bound"], _figures(given)[0])}
    if least_card is not None:
        marks["noise = \"min\" at its decay"] = (least_card.data["decay_bound"], _figures(least_card)[0])
    rows = []
    for k in range(points):
        decay = fastest + (1.0 - fastest) * SLOWEST * k / (points - 1)
        point = Point(decay)
        for noise in ("default", "min"):
            card, why = (fastest_card, None) if k == 0 and noise == "default" else \
                _card(problem, family.noise_options(opts, decay, noise))
            gain, over = _figures(card)
            if noise == "default":
                point.gain_default, point.overshoot_default = gain, over
            else:
                point.gain_least, point.overshoot_least = gain, over
            if why:
                point.why.append(f"{noise}: {why}")
            tick()
        rows.append(point)
    return Tradeoff(problem.name, fastest, rows, marks)


COLUMNS = ("decay", "gain_y_default", "gain_y_least_noise", "overshoot_default", "overshoot_least_noise", "why")


def table_text(result: Tradeoff) -> str:
    """The trade-off as CSV (one row per decay; an empty cell where that design found no certificate)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(COLUMNS)
    cell = lambda v: "" if v is None else repr(float(v))     # noqa: E731
    for p in result.points:
        writer.writerow([repr(p.decay), cell(p.gain_default), cell(p.gain_least), cell(p.overshoot_default),
                         cell(p.overshoot_least), "; ".join(p.why)])
    return out.getvalue()


def plot(result: Tradeoff, path) -> Path:
    """Draw the trade-off: ``gain_y`` and the overshoot bound against the decay, both designs, the marks."""
    from .cosim.report import pyplot
    from .runtime.files import atomic_output

    plt, colors = pyplot()
    from matplotlib.ticker import FuncFormatter, NullFormatter
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(7.5, 7.0), sharex=True, constrained_layout=True)
    decays = [p.decay for p in result.points]
    value = lambda v: math.nan if v is None else float(v)     # noqa: E731
    for ax, key, label in ((top, "gain", "certified gain_y (l2, noise to error)"),
                           (bottom, "overshoot", "overshoot bound")):
        ax.plot(decays, [value(getattr(p, f"{key}_default")) for p in result.points], "o-", color=colors[0],
                label="default design (least overshoot bound)")
        ax.plot(decays, [value(getattr(p, f"{key}_least")) for p in result.points], "s-", color=colors[1],
                label='least noise gain (observer.noise = "min")')
        ax.set_yscale("log")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
    for (label, (decay, gain)), marker, color in zip(result.marks.items(), ("*", "D"), colors[2:]):
        if gain is not None:
            top.plot([decay], [gain], marker, markersize=14, color=color, label=label, linestyle="none")
    top.axvline(result.fastest, color="gray", linestyle=":", label=f"fastest certified decay {result.fastest:.6g}")
    top.legend(fontsize=8)
    for ax in (top, bottom):          # plain numbers; the minor ticks' too where the axis spans under a decade
        low, high = ax.get_ylim()
        ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.yaxis.set_minor_formatter(FuncFormatter(lambda v, _: f"{v:g}") if high < 10 * low else NullFormatter())
    bottom.set_xlabel("decay bound per step (slower to the right)")
    fig.suptitle(f"{result.name}: noise gain against convergence speed")
    path = Path(path)
    with atomic_output(path, "trade-off plot") as part:
        fig.savefig(part, dpi=110, format="png")
    plt.close(fig)
    return path


def write(result: Tradeoff, path) -> tuple:
    """Write the plot to ``path`` and its table next to it (same name, ``.csv``); returns both paths."""
    from .runtime.files import write_atomic

    png = plot(result, path)
    table = write_atomic(Path(path).with_suffix(".csv"), table_text(result), "trade-off table")
    return png, table


__all__ = ["COLUMNS", "POINTS", "SLOWEST", "Point", "Tradeoff", "families_with_tradeoff", "plot", "table_text",
           "tradeoff", "write"]
