"""The co-simulation report: one figure a person understands at a glance."""

from __future__ import annotations

import math
import re
import textwrap
from pathlib import Path

import numpy as np

from ..runtime.errors import ProblemError
from ..runtime.files import atomic_output
from ..runtime.labels import axis_label, check_labels, element_label
from .metrics import allowance
from .result import run_result


def pyplot():
    """matplotlib's pyplot on the Agg backend (no display needed) and the colours of its property cycle.

    Returns
    -------
    plt : module
        ``matplotlib.pyplot``.
    colors : list of str
        The colours of ``axes.prop_cycle``, in order.
    """
    try:
        import matplotlib
    except ValueError as exc:               # matplotlib validates MPLBACKEND (and matplotlibrc) on import
        raise ProblemError(f"matplotlib refuses its settings ({str(exc)[:160]}): unset MPLBACKEND or fix the "
                           "matplotlibrc (uiofmu draws with Agg whatever it says)") from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt, plt.rcParams["axes.prop_cycle"].by_key()["color"]


def _panels(plt, rows: int, cols: int, figsize: tuple, shade):
    """A figure of panels over one shared time axis, each shaded by ``shade`` and gridded.

    Parameters
    ----------
    plt : module
        ``matplotlib.pyplot``.
    rows, cols : int
        The panels' layout.
    figsize : tuple of float
        The figure's size in inches.
    shade : callable
        ``shade(ax)`` draws the stretches to shade on one panel (before anything else is drawn).

    Returns
    -------
    fig : Figure
    axes : ndarray of Axes
    """
    fig, axes = plt.subplots(rows, cols, figsize=figsize, sharex=True, constrained_layout=True)
    for ax in axes.flat:
        shade(ax)
        ax.grid(alpha=0.3)
    return fig, axes


def _plot_states(ax, t, result, colors, title: str) -> None:
    """The true states (solid) and their estimates (dashed) in one colour per component.

    Parameters
    ----------
    ax : Axes
    t : ndarray
        The time axis.
    result : CosimResult
        Its ``x`` and ``xhat`` are drawn.
    colors : list of str
        The colours, cycled over the components.
    title : str
        The panel's title.
    """
    labels = result.labels
    functional = result.estimate == "zhat"       # x holds Lf x, xhat the observer's zhat
    for i in range(result.x.shape[1]):
        c = colors[i % len(colors)]
        ax.plot(t, result.x[:, i], color=c, lw=1.6,
                label=f"Lf x[{i + 1}]" if functional else axis_label(labels, "x", i))
        ax.plot(t, result.xhat[:, i], color=c, lw=1.2, ls="--",
                label=f"zhat[{i + 1}]" if functional else axis_label(labels, "xhat", i))
    if functional:
        ax.set_ylabel("Lf x, zhat")
        title = "the functionals Lf x (solid) and their estimate zhat (dashed)"
    else:
        _unit_axis(ax, labels, "x", result.x.shape[1], "state", "state")
    ax.set_title(title)
    ax.legend(ncol=2, fontsize=8, loc="best")


#: The units of a time axis: (seconds per unit, name, longest run drawn in that unit).
TIME_UNITS = ((1.0, "s", 600.0), (60.0, "min", 600 * 60.0), (3600.0, "h", 240 * 3600.0), (86400.0, "d", math.inf))


def time_unit(t_end: float) -> tuple[float, str]:
    """The unit of a run's time axis: seconds up to 10 min, minutes up to 10 h, hours up to 10 days,
    days beyond.

    Parameters
    ----------
    t_end : float
        The run's length in seconds.

    Returns
    -------
    scale : float
        Seconds per unit.
    unit : str
        ``"s"``, ``"min"``, ``"h"`` or ``"d"``.
    """
    for scale, unit, longest in TIME_UNITS:
        if t_end <= longest:
            return scale, unit
    return TIME_UNITS[-1][:2]


def _wrap_titles(fig, title: str | None) -> None:
    """Give the figure its title ``title``, and break every title wider than its panel (the figure's
    wider than the figure) into lines that fit (a long title is wrapped, never clipped)."""
    texts = [(ax.title, 0.85 * _columns(ax)) for ax in fig.axes]
    if title:                                          # a name is text, never mathtext
        texts.append((fig.suptitle(title.replace("$", r"\$")), 0.95))
    renderer = fig.canvas.get_renderer()
    for text, share in texts:
        _fit(text, share * fig.bbox.width, renderer)


def _columns(ax) -> float:
    """The share of the figure's width the grid gives ``ax`` (its columns over the grid's)."""
    spec = ax.get_subplotspec()
    return 1.0 if spec is None else len(spec.colspan) / spec.get_gridspec().ncols


def _fit(text, width: float, renderer) -> None:
    """Break each line of the Text ``text`` that is wider than ``width`` (pixels) into lines that fit."""
    lines = text.get_text().split("\n")
    drawn = text.get_window_extent(renderer).width
    longest = max(len(line) for line in lines)
    if drawn <= width or longest == 0:
        return
    chars = max(20, int(longest * width / drawn))
    text.set_text("\n".join(textwrap.fill(line, chars) for line in lines))


def _unit_axis(ax, labels: dict, port: str, size: int, what: str, plain: str) -> None:
    """The y-label of a panel of ``port``'s elements: the element's label when there is one element
    (``T_room [K]``), ``what [unit]`` when every element has that unit, ``what (units in the legend)``
    when they have several, ``plain`` when none has a unit."""
    units = {element_label(labels, port, i)[1] for i in range(size)}
    if size == 1 and element_label(labels, port, 0) != (None, None):
        ax.set_ylabel(axis_label(labels, port, 0))
    elif len(units) == 1 and None not in units:
        ax.set_ylabel(f"{what} [{units.pop()}]")
    else:
        ax.set_ylabel(f"{what} (units in the legend)" if units - {None} else plain)


def _save(plt, fig, path, title: str | None) -> Path:
    """Title the figure, write it as ``path`` (a PNG, atomically) and close it.

    Parameters
    ----------
    plt : module
        ``matplotlib.pyplot``.
    fig : Figure
    path : str or Path
    title : str or None
        The figure's title (none when empty).

    Returns
    -------
    Path
        ``path``.
    """
    _thin_lines(fig)
    _wrap_titles(fig, title)
    path = Path(path)
    with atomic_output(path, "report") as part:
        fig.savefig(part, dpi=110, format="png")
    plt.close(fig)
    return path


#: The most points a line of the report draws; a longer line (a long run) is thinned to about this many
#: (the axes keep the limits of the full data), a shorter one is drawn as it is.
MAX_POINTS = 5000


def _thin_lines(fig, limit: int = MAX_POINTS) -> None:
    """Thin every line of ``fig`` with more than ``limit`` points: a line keeps, in each of ``limit / 4``
    runs of consecutive points, its first, lowest, highest and last (so peaks and steps stay where they
    are); markers without a line keep evenly spaced points."""
    for ax in fig.axes:
        for line in ax.get_lines():
            x, y = np.asarray(line.get_xdata(), dtype=float), np.asarray(line.get_ydata(), dtype=float)
            if x.ndim != 1 or x.shape != y.shape or x.size <= limit:
                continue
            if line.get_linestyle() in ("None", "", " "):
                keep = np.unique(np.linspace(0, x.size - 1, limit).round().astype(int))
            else:
                edges = np.linspace(0, x.size, limit // 4 + 1).round().astype(int)
                picks = []
                for a, b in zip(edges[:-1], edges[1:]):
                    run = y[a:b]
                    finite = np.isfinite(run)
                    picks.append(a)
                    if finite.any():
                        picks += [a + int(np.argmin(np.where(finite, run, np.inf))),
                                  a + int(np.argmax(np.where(finite, run, -np.inf)))]
                    picks.append(b - 1)
                keep = np.unique(picks)
            line.set_data(x[keep], y[keep])


def plot_report(result, path, title: str | None = None) -> Path:
    """Write ``report.png``: states and estimates, error norm against the certified bound and the slack
    its check allows, the communication steps used, and the unknown input against its estimate.

    Parameters
    ----------
    result : CosimResult
    path : str or Path
    title : str, optional

    Returns
    -------
    Path
    """
    if result.functional is not None:
        return plot_functional(result, path, title)
    if result.delayed is not None:
        return plot_delayed(result, path, title)
    plt, colors = pyplot()
    scale, unit = time_unit(float(result.times[-1]))
    t = result.times / scale
    noisy = result.noise is not None
    fig, axes = plt.subplots(3 if noisy else 2, 2, figsize=(12, 12.5 if noisy else 8.5), constrained_layout=True)
    if noisy:
        grid = axes[2, 0].get_gridspec()
        for ax in axes[2]:
            ax.remove()
        plot_noise(fig.add_subplot(grid[2, :]), t, unit, result)
    _plot_states(axes[0, 0], t, result, colors, "true state (solid) and estimate (dashed)")
    _plot_error(axes[0, 1], t, unit, result)
    if result.mode is not None:
        _plot_modes(axes[1, 0], t, result)
    else:
        plot_steps(axes[1, 0], t, result.h, unit)
    _plot_inputs(axes[1, 1], t, result, colors)
    for ax in (axes[0, 0], axes[0, 1], axes[1, 1]):
        ax.set_xlabel(f"time [{unit}]")
        ax.grid(alpha=0.3, which="both" if ax.get_yscale() == "log" else "major")
    return _save(plt, fig, path, title)


def plot_noise(ax, t, unit: str, result) -> None:
    """The error of the observer fed the noisy outputs, its noise part (against its noise-free twin) and the
    noise level: ``||e_k||``, ``||e_k - e_twin,k||``, the noise's std ``||sigma||`` and, with a certified
    gain, that gain times it; the title gives the measured and certified gains and the verdict."""
    nz, m = result.noise, result.metrics
    part = np.linalg.norm(nz["error"] - nz["twin_error"], axis=1)
    error = np.linalg.norm(nz["error"], axis=1)
    level = float(np.linalg.norm(nz["std"]))
    drawn = np.concatenate([error[np.isfinite(error)], part[np.isfinite(part)], [level]])
    bottom = max(float(drawn.max()), 1e-300) * 1e-9
    ax.semilogy(t, np.maximum(error, bottom), lw=1.2, label="||e|| of the observer fed y + v")
    ax.semilogy(t, np.maximum(part, bottom), lw=1.0, alpha=0.8, label="||e - e_twin||: the noise's part")
    ax.axhline(level, color="k", ls=":", lw=1.2, label=f"noise std ||sigma|| = {level:.3g}"
               + (" (with the quantum's Q/sqrt(12))" if (m.get("noise") or {}).get("quantum") else ""))
    certified, measured = m.get("noise_gain_certified"), m.get("noise_gain_measured")
    if certified is not None:
        ax.axhline(certified * level, color="tab:red", ls="--", lw=1.2,
                   label=f"certified gain x noise std = {certified * level:.3g}")
    verdict = ("no certified gain in the card" if certified is None else
               "the card's gain holds with noise-free premises: not checked" if m.get("noise_gain_covers") else
               "respected" if m.get("noise_gain_respected") else "FALSE CERTIFICATE: measured above certified")
    shown = "none" if measured is None else f"{measured:.4g}"
    ax.set_title(f"sensor noise: measured l2 gain {shown}"
                 + ("" if certified is None else f", certified {certified:.4g}") + f" ({verdict})", fontsize=10)
    ax.set_xlabel(f"time [{unit}]")
    ax.set_ylabel("error norm")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8, loc="upper right", ncol=2)


def _plot_error(ax, t, unit: str, result) -> None:
    """The error norm on a log scale, the certified bound, the slack its check allows (shaded up to
    ``bound (1 + rtol) + rtol ||e_0||``, what ``bound_respected`` compares with), the 1 % line and the time
    from which the error stays under it; the title says what was checked and what it found, the legend
    sits under the panel (it hides no data)."""
    m = result.metrics
    norms = np.linalg.norm(result.x - result.xhat, axis=1)
    shown = [norms]
    title = "estimation error"
    if result.bound is not None:
        bound, allowed = result.bound, allowance(result.bound, m["bound_rtol"], m["bound_floor"])
        shown.append(allowed)
    positive = np.concatenate([v[(v > 0) & np.isfinite(v)] for v in shown])
    bottom = float(positive.min()) / 30 if positive.size else 1e-300
    error = "||zhat - Lf x||" if result.estimate == "zhat" else "||x - xhat||"
    ax.semilogy(t, np.maximum(norms, bottom), lw=1.5, label=f"measured {error}", zorder=3)
    if result.bound is not None:
        overshoot = m.get("certified_overshoot")
        ax.semilogy(t, np.maximum(bound, bottom), "k--", lw=1.2,
                    label=f"certified bound (δ = {m['certified_decay']:.4g}"
                          + (f", M = {overshoot:.4g})" if overshoot is not None else ")"))
        ax.fill_between(t, np.maximum(bound, bottom), allowed, color="0.82", lw=0, zorder=1)
        ax.semilogy(t, allowed, color="0.4", ls=":", lw=1.4, label="bound + allowed slack (shaded: the slack)")
        title = f"estimation error: {_bound_verdict(m, len(norms), unit, t)}"
    one = 0.01 * norms[0]
    if one > 0:
        ax.axhline(one, color="tab:gray", ls="-.", lw=1, label="1 % of the initial error")
    k1 = m.get("steps_to_1pct")
    if k1 is not None:
        ax.axvline(t[k1], color="tab:gray", lw=0.8, label=f"under 1 % from t = {t[k1]:.4g} {unit}")
    if np.any(norms < bottom) or (result.bound is not None and np.any(result.bound < bottom)):
        ax.set_ylim(bottom=bottom / 2)           # what falls to 0 (or below the drawing) is drawn at the bottom
    ax.set_title(title, fontsize=10)
    ax.set_ylabel(error)
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2)


def _bound_verdict(m: dict, points: int, unit: str, t) -> str:
    """What the bound check compared and what it found, in words (the error panel's title)."""
    rtol = f"{m['bound_rtol']:.0e}".replace("e-0", "e-")
    leaks = m.get("roundoff_floor")
    carried = " + carried leaks" if leaks and leaks["roundoff"] and leaks["carried"] > 0 else ""
    check = (f"checked at all {points} points: ||e_k|| <= bound_k·(1 + {rtol}) + {rtol}·||e_0||{carried} "
             f"(round-off floor {m['bound_floor']:.2g})")
    if not m["bound_respected"]:
        k = m["first_bound_violation"]
        return (f"bound EXCEEDED from step {k} (t = {t[k]:.4g} {unit}: error {m['error_at_first_violation']:.3g} "
                f"> bound {m['bound_at_first_violation']:.3g}), settles at {m['error_floor']:.2g}\n{check}")
    on_floor = m.get("points_on_floor", 0)
    floor = (f"\nabove the bound itself at {on_floor} points, where the bound is under the floor" if on_floor else "")
    return f"bound + allowed slack respected at every step\n{check}{floor}"


#: Above this many steps the communication-step panel draws how many steps of each length there are (a
#: trace of so many steps is a solid band); up to it, the trace of h_k over time.
STEP_TRACE_LIMIT = 1000

#: Most distinct step lengths drawn as one bar each; more are binned (a histogram of 50 bins).
MAX_STEP_BARS = 30


def plot_steps(ax, t, h, unit: str, limit: int = STEP_TRACE_LIMIT) -> None:
    """The communication steps: their trace over time up to ``limit`` steps, beyond it a histogram of
    their lengths (a bar for each length when there are at most :data:`MAX_STEP_BARS`).

    Parameters
    ----------
    ax : Axes
    t : (K+1,) array
        The communication points, in ``unit``.
    h : (K,) array
        The step lengths in seconds.
    unit : str
        The unit of ``t``.
    limit : int
        The most steps drawn as a trace.
    """
    span = f"{len(h)} steps, h in [{h.min():.4g}, {h.max():.4g}] s"
    if len(h) <= limit or np.ptp(h) == 0:    # a trace of one length is a line, whatever its steps
        ax.step(t[:-1], h, where="post", lw=1.2)
        ax.set_title(f"communication steps ({span})")
        ax.set_xlabel(f"time [{unit}]")
        ax.set_ylabel("h_k [s]")
    else:
        lengths, counts = np.unique(h, return_counts=True)
        if lengths.size <= MAX_STEP_BARS:
            gap = float(np.diff(lengths).min()) if lengths.size > 1 else abs(float(lengths[0])) or 1.0
            ax.bar_label(ax.bar(lengths, counts, width=0.6 * gap), fontsize=8)
        else:
            ax.hist(h, bins=50)
        ax.set_title(f"communication steps ({span}): how many of each length")
        ax.set_xlabel("step length h [s]")
        ax.set_ylabel("number of steps")
    ax.grid(alpha=0.3)


def _plot_modes(ax, t, result) -> None:
    """The mode of each step of a switched run."""
    modes = result.mode[:-1]
    ax.step(t[:-1], modes, where="post", lw=1.2)
    ax.set_yticks(np.unique(modes))
    ax.set_title(f"mode of each step ({result.metrics['modes']['switches']} switches; {len(result.h)} steps of "
                 f"{result.h.min():.4g} s)")
    ax.set_ylabel("alpha_k")
    ax.set_xlabel(f"time [{time_unit(float(result.times[-1]))[1]}]")
    ax.grid(alpha=0.3)


def _plot_inputs(ax, t, result, colors) -> None:
    """The unknown input against its estimate, or the output residual when there is no estimate (a functional
    observer's run, which has neither: the unknown input)."""
    if result.estimate == "zhat":
        for i in range(result.d.shape[1]):
            ax.step(t, result.d[:, i], where="post", color=colors[i % len(colors)], lw=1.6,
                    label=f"{axis_label(result.labels, 'd', i)} (held over step)")
        _unit_axis(ax, result.labels, "d", result.d.shape[1], "unknown input", "d")
        ax.set_title("unknown input (zhat is decoupled from it; no dhat, no residual)")
    elif result.dhat.size and result.dhat.shape[1]:
        for i in range(result.d.shape[1]):
            c = colors[i % len(colors)]
            ax.step(t, result.d[:, i], where="post", color=c, lw=1.6,
                    label=f"{axis_label(result.labels, 'd', i)} (held over step)")
            ax.plot(t[:-1], result.dhat[1:, i], ".", color=c, ms=3,
                    label=f"{axis_label(result.labels, 'dhat', i)} (drawn at its step's start)")
        _unit_axis(ax, result.labels, "d", result.d.shape[1], "unknown input", "d, dhat")
        ax.set_title("unknown input and its estimate" + _clip_outliers(ax, result.d, result.dhat[1:], t[:-1]))
    else:
        for i in range(result.r.shape[1]):
            ax.plot(t, result.r[:, i], lw=1.2, label=axis_label(result.labels, "r", i))
        _unit_axis(ax, result.labels, "r", result.r.shape[1], "residual", "r")
        ax.set_title("output residual r = y - C xhat")
    ax.legend(fontsize=8, loc="best")


#: Fraction of an estimate's points that may lie off the scale of the unknown-input panel: the first
#: estimates of an observer started away from the state can be orders of magnitude off, and drawn to
#: scale they flatten the rest to a line.
OUTLIER_FRACTION = 0.005


def _clip_outliers(ax, d, dhat, t) -> str:
    """Fit the y-axis to ``d`` and all but the farthest :data:`OUTLIER_FRACTION` of ``dhat``; return the
    words that say what is off the scale (empty when nothing is)."""
    finite = dhat[np.isfinite(dhat)]
    if not finite.size:
        return ""
    lo, hi = np.quantile(finite, [OUTLIER_FRACTION, 1.0 - OUTLIER_FRACTION])
    lo, hi = min(lo, float(np.nanmin(d))), max(hi, float(np.nanmax(d)))
    pad = 0.1 * (hi - lo) or 0.1 * max(abs(hi), 1.0)
    lo, hi = lo - pad, hi + pad
    off = np.isfinite(dhat) & ((dhat < lo) | (dhat > hi))
    if not off.any():
        return ""
    ax.set_ylim(lo, hi)
    k = np.unravel_index(np.argmax(np.where(off, np.abs(dhat), -np.inf)), dhat.shape)
    return (f"\n({int(off.sum())} estimate(s) off the scale, the farthest {dhat[k]:.3g} at t = {t[k[0]]:.4g}: "
            "the start from the initial error)")


def plot_functional(result, path, title: str | None = None) -> Path:
    """``report.png`` of a functional observer: the functional and its estimate (the window-filling
    steps shaded), the error on a log scale with the first exact step, and the inputs.

    Parameters
    ----------
    result : CosimResult
        With ``functional`` (``gx``, ``true``, ``valid``).
    path : str or Path
    title : str, optional

    Returns
    -------
    Path
    """
    plt, colors = pyplot()
    m, f = result.metrics, result.functional
    k = np.arange(len(result.times))
    filling = m["valid_from"] if m["valid_from"] is not None else len(k)
    fig, axes = _panels(plt, 3, 1, (10, 8.5), lambda ax: ax.axvspan(-0.5, filling - 0.5, color="0.9", lw=0))
    ax = axes[0]
    for i in range(f["gx"].shape[1]):
        c = colors[i % len(colors)]
        ax.plot(k, f["true"][:, i], color=c, lw=1.6, label=f"(G x)[{i + 1}] at k - {m['delay']}")
        ax.plot(k, np.where(f["valid"] > 0.5, f["gx"][:, i], np.nan), "o", color=c, ms=3, mfc="none",
                label=f"gx[{i + 1}]")
    ax.set_title(f"the functional and its estimate (window of {m['window']} outputs, delay {m['delay']}; "
                 f"shaded: window filling)")
    ax.set_ylabel("G x, gx")
    ax.legend(fontsize=8, ncol=2, loc="best")
    ax = axes[1]
    err = np.linalg.norm(f["gx"] - f["true"], axis=1)
    ax.semilogy(k, np.maximum(err, 1e-18), ".-", lw=1)
    exact = m["steps_to_exact"]
    if exact is not None:
        ax.axvline(exact, color="k", ls="--", lw=1, label=f"exact (round-off) from step {exact}")
        ax.legend(fontsize=8)
    ax.set_title("error |gx - G x| (0 drawn at 1e-18)")
    ax.set_ylabel("|gx - G x|")
    ax = axes[2]
    for i in range(result.d.shape[1]):
        ax.step(k, result.d[:, i], where="post", lw=1.2, label=f"{axis_label(result.labels, 'd', i)} (unknown)")
    for i in range(result.y.shape[1]):
        ax.plot(k, result.y[:, i], lw=1, label=axis_label(result.labels, "y", i))
    ax.set_title("inputs and outputs")
    ax.set_xlabel("step k")
    ax.set_ylabel("d, y")
    ax.legend(fontsize=8, ncol=3, loc="best")
    return _save(plt, fig, path, title)


def _shade_invalid(ax, t, valid) -> None:
    """Shade the stretches of ``t`` where ``valid`` is 0 (each point's stretch runs to the next point)."""
    bad = np.asarray(valid) < 0.5
    edges = np.flatnonzero(np.diff(np.concatenate([[0], bad.astype(int), [0]])))
    for a, b in zip(edges[::2], edges[1::2]):
        ax.axvspan(t[a], t[min(b, len(t) - 1)], color="0.88", lw=0, zorder=0)


def plot_delayed(result, path, title: str | None = None) -> Path:
    """``report.png`` of a delayed observer with parameter identification (seed 001): states and
    estimates, the state error, the rank margin ``sigma_min`` against the card's premise bound, and
    ``thetahat`` against the true ``theta``; the stretches where the observer says its estimates are not
    valid (start-up, margin below the bound) shaded in every panel.

    Parameters
    ----------
    result : CosimResult
        With ``delayed`` (``thetahat``, ``theta``, ``sigma_min``, ``valid``, ``sigma_bound``).
    path : str or Path
    title : str, optional

    Returns
    -------
    Path
    """
    plt, colors = pyplot()
    m, dl = result.metrics, result.delayed
    scale, unit = time_unit(float(result.times[-1]))
    t, valid = result.times / scale, dl["valid"]
    v = m["validity"]
    fig, axes = _panels(plt, 2, 2, (12, 8), lambda ax: _shade_invalid(ax, t, valid))
    _plot_states(axes[0, 0], t, result, colors, "true state (solid) and estimate (dashed); shaded: not valid")

    ax = axes[0, 1]
    norms = np.linalg.norm(result.x - result.xhat, axis=1)
    floor = max(float(norms.max()), 1e-300) * 1e-9
    ax.semilogy(t, np.maximum(norms, floor), lw=1.5, label=f"measured ||x - xhat|| (below {floor:.1e} drawn there)")
    ax.set_title("state error (no certified bound: it holds on the premise set only)")
    ax.set_ylabel("||x - xhat||")
    ax.legend(fontsize=8, loc="best")

    ax = axes[1, 0]
    sig = np.asarray(dl["sigma_min"], dtype=float)
    low = dl["sigma_bound"] * 1e-3
    ax.semilogy(t, np.maximum(sig, low), lw=1.3, label=f"sigma_min(C D_y) at run time (below {low:.1e} drawn there)")
    ax.set_ylim(bottom=low / 2)
    ax.axhline(dl["sigma_bound"], color="k", ls="--", lw=1.2, label=f"premise bound {dl['sigma_bound']:.3g}")
    ax.set_title(f"rank margin; valid {100 * v['fraction']:.1f} % of the run, from t = "
                 + (f"{v['first_valid_time'] / scale:.4g} {unit}" if v["first_valid_time"] is not None else "never"))
    ax.set_xlabel(f"time [{unit}]")
    ax.set_ylabel("sigma_min(C D_y)")
    ax.legend(fontsize=8, loc="best")

    ax = axes[1, 1]
    th = dl["thetahat"]
    for i in range(th.shape[1]):
        c = colors[i % len(colors)]
        if dl["theta"] is not None:
            ax.axhline(dl["theta"][i], color=c, lw=1.6, label=f"theta[{i + 1}] = {dl['theta'][i]:.4g} (plant)")
        ax.plot(t, th[:, i], color=c, lw=1.1, ls="--", label=f"thetahat[{i + 1}]")
    if dl["theta"] is not None:             # transients while the observer starts may be far off: keep theta in view
        mid, spread = float(np.mean(dl["theta"])), float(np.ptp(dl["theta"])) + float(np.max(np.abs(dl["theta"])))
        ax.set_ylim(mid - 2 * spread, mid + 2 * spread)
    tm = m.get("theta")
    if tm is not None:
        when = (f"within 1 % from t = {tm['time_to_1pct'] / scale:.4g} {unit}" if tm["time_to_1pct"] is not None
                else "never within 1 %")
        ax.set_title(f"parameters: {when}, final relative error {tm['final_relative_error']:.2g}")
    else:
        ax.set_title("parameter estimate (the plant has no parameter theta to compare with)")
    ax.set_xlabel(f"time [{unit}]")
    ax.set_ylabel("theta, thetahat")
    ax.legend(fontsize=8, ncol=2, loc="best")
    return _save(plt, fig, path, title)


#: Largest results table ``uiofmu report`` reads (bytes): a run of a few million steps.
MAX_RESULTS_BYTES = 2**30

#: The vectors of a results table (columns ``name[1]``, ``name[2]``, ...).
_VECTOR = re.compile(r"([a-z_]+)\[([1-9][0-9]*)\]")


def redraw(run_dir, title: str | None = None) -> Path:
    """Draw ``RUN_DIR/report.png`` again from the ``results.csv`` and ``metrics.json`` that ``uiofmu cosim
    --out RUN_DIR`` wrote (atomically: a failure leaves the old figure).

    The figure's numbers are computed again from the table (as the co-simulation computed them); from
    ``metrics.json`` come the design's: the certified decay and overshoot, a functional observer's window
    and delay, a delayed observer's premise bound and the plant's true theta, and the title.

    Parameters
    ----------
    run_dir : str or Path
        The run's folder.
    title : str, optional
        The figure's title (default: the one in ``metrics.json``).

    Returns
    -------
    Path
        ``RUN_DIR/report.png``.

    Raises
    ------
    ProblemError
        For a missing or unreadable file, or a table or metrics that are not what ``uiofmu cosim`` writes,
        naming the file and what is wrong.
    """
    from ..runtime.files import check_output_file, parse_json, read_text

    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise ProblemError(f"{run_dir}: no such run folder (give the --out folder of `uiofmu cosim`)")
    check_output_file(run_dir / "report.png", "report")
    metrics = parse_json(read_text(run_dir / "metrics.json", "metrics file", error=ProblemError),
                         f"{run_dir / 'metrics.json'}", error=ProblemError)
    if not isinstance(metrics, dict):
        raise ProblemError(f"{run_dir / 'metrics.json'}: expected a JSON object (the metrics of a run)")
    name = metrics.get("results_file", "results.csv")
    if name not in RESULT_FILES:
        raise ProblemError(f"{run_dir / 'metrics.json'}: results_file: expected one of {', '.join(RESULT_FILES)}")
    table = _read_results(run_dir / name)
    result = _result_from_table(table, run_dir / name, metrics, run_dir / "metrics.json")
    text = title if title is not None else metrics.get("title")
    if text is not None and not isinstance(text, str):
        raise ProblemError(f"{run_dir / 'metrics.json'}: title: expected a string")
    return plot_report(result, run_dir / "report.png", text[:300] if text else None)


#: The results tables ``uiofmu cosim`` writes (``--format``), as ``metrics.json``'s ``results_file`` names them.
RESULT_FILES = ("results.csv", "results.npz", "results.parquet")


def _read_results(path) -> dict:
    """The columns of a results table by name (empty cells are NaN), checked: a header of distinct names,
    numbers in every row, a column ``time`` increasing from 0 and ``h`` its steps, at least one step.
    The table is CSV, or the binary ``.npz`` or ``.parquet`` of ``uiofmu cosim --format``."""
    columns = _binary_columns(path) if path.suffix in (".npz", ".parquet") else _csv_columns(path)
    truth = "zhat_true[1]" if "zhat[1]" in columns else "x[1]"      # a functional affine observer's: Lf x
    for name in ("time", "h", truth):
        if name not in columns:
            raise ProblemError(f"{path}: no column {name} (a table written by `uiofmu cosim` has one)")
    t, h = columns["time"], columns["h"][:-1]
    if t.size < 2 or not (np.all(np.isfinite(t)) and np.all(np.diff(t) > 0)):
        raise ProblemError(f"{path}: time must hold finite increasing times, at least two ({t.size} rows)")
    if not (np.all(np.isfinite(h)) and np.all(h > 0)):
        raise ProblemError(f"{path}: h must hold a finite step > 0 on every line but the last (line "
                           f"{int(np.argmax(~(np.isfinite(h) & (h > 0)))) + 2})")
    bound = columns.get("bound")
    if bound is not None and not np.all(np.isfinite(bound) & (bound >= 0)):
        raise ProblemError(f"{path}: bound must hold finite numbers >= 0 (line "
                           f"{int(np.argmax(~(np.isfinite(bound) & (bound >= 0)))) + 2})")
    return columns


def _csv_columns(path) -> dict:
    """The columns of a CSV results table by name (empty cells are NaN)."""
    import csv
    import io

    from ..runtime.files import read_text

    text = read_text(path, "results table", limit=MAX_RESULTS_BYTES, error=ProblemError)
    rows = csv.reader(io.StringIO(text, newline=""))
    try:
        header = next(rows, None)
        if not header or len(set(header)) != len(header):
            raise ProblemError(f"{path}: the first line must name each column once (time,h,x[1],...)")
        values = []
        for number, row in enumerate(rows, start=2):
            if len(row) != len(header):
                raise ProblemError(f"{path}: line {number} has {len(row)} values, the header {len(header)}")
            try:
                values.append([float(v) if v else math.nan for v in row])
            except ValueError:
                raise ProblemError(f"{path}: line {number}: a value is not a number") from None
    except csv.Error as exc:
        raise ProblemError(f"{path}: not a CSV table ({str(exc)[:120]})") from None
    data = np.array(values, dtype=float).reshape(len(values), len(header))
    return dict(zip(header, data.T))


def _binary_columns(path) -> dict:
    """The columns of an ``.npz`` or ``.parquet`` results table by name: one float64 array each, all as long."""
    if not path.is_file():
        raise ProblemError(f"{path}: no such results table")
    if path.stat().st_size > MAX_RESULTS_BYTES:
        raise ProblemError(f"{path}: larger than {MAX_RESULTS_BYTES} bytes")
    try:
        if path.suffix == ".npz":
            with np.load(path, allow_pickle=False) as z:
                columns = {name: np.asarray(z[name]) for name in z.files}
        else:
            import pyarrow.parquet as pq

            table = pq.read_table(path)
            columns = {name: table.column(name).to_numpy() for name in table.column_names}
    except ImportError:
        raise ProblemError(f"{path}: reading parquet needs pyarrow (pip install pyarrow)") from None
    except Exception as exc:                 # a damaged archive: zipfile, numpy and pyarrow each raise their own
        raise ProblemError(f"{path}: not a results table ({type(exc).__name__}: {str(exc)[:120]})") from None
    rows = {c.shape for c in columns.values()}
    if not columns or len(rows) != 1 or len(rows.pop()) != 1 or any(c.dtype.kind != "f" for c in columns.values()):
        raise ProblemError(f"{path}: expected one float column per name, all of one length")
    return {name: c.astype(float) for name, c in columns.items()}


def _vector(columns: dict, name: str, path) -> np.ndarray:
    """The columns ``name[1]``, ``name[2]``, ... of the table ``path`` as one (rows, n) array (n = 0 without any)."""
    index = sorted(int(m.group(2)) for m in map(_VECTOR.fullmatch, columns) if m and m.group(1) == name)
    if index != list(range(1, len(index) + 1)):
        raise ProblemError(f"{path}: the columns {name}[i] must run from {name}[1] without a gap")
    rows = len(columns["time"])
    return np.stack([columns[f"{name}[{i}]"] for i in index], axis=1) if index else np.zeros((rows, 0))


def _number(metrics: dict, keys: tuple, where, integer: bool = False, optional: bool = False):
    """``metrics[keys[0]][keys[1]]...``, checked to be a finite number (an integer >= 0 with ``integer``);
    None when ``optional`` and absent."""
    value = metrics
    for key in keys:
        value = value.get(key) if isinstance(value, dict) else None
    if value is None and optional:
        return None
    name = ".".join(keys)
    if integer and not (isinstance(value, int) and not isinstance(value, bool) and value >= 0):
        raise ProblemError(f"{where}: {name}: expected an integer >= 0, found {str(value)[:40]}")
    if not integer and not (isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)):
        raise ProblemError(f"{where}: {name}: expected a finite number, found {str(value)[:40]}")
    return value


def _result_from_table(columns: dict, path, metrics: dict, where):
    """A :class:`~uiofmu.cosim.result.CosimResult` of the columns of the table ``path``, with its metrics
    computed again (:func:`~uiofmu.cosim.result.run_result`) from them and the design's numbers in ``metrics``
    (read from ``where``)."""
    T, H = columns["time"], columns["h"][:-1]
    estimate = "zhat" if "zhat[1]" in columns else "xhat"      # a functional affine observer: zhat against Lf x
    X, XH, D, DH = (_vector(columns, n, path) for n in (("zhat_true", "zhat") if estimate == "zhat" else ("x", "xhat"))
                    + ("d", "dhat"))
    Y, U = _vector(columns, "y", path), _vector(columns, "u", path)
    args = [T, H, X, XH, Y, U, D, _vector(columns, "r", path), DH]
    names = metrics.get("plant_labels", {})
    if not isinstance(names, dict):
        raise ProblemError(f"{where}: plant_labels: expected a table of names and units")
    names = check_labels(names, {"n": X.shape[1], "m": U.shape[1], "q": D.shape[1], "p": Y.shape[1]},
                         f"{where}: plant_labels", ProblemError)
    if DH.shape[1] and D.shape != DH.shape:
        raise ProblemError(f"{path}: {D.shape[1]} columns d[i] but {DH.shape[1]} columns dhat[i]")
    mode = columns.get("mode")
    if mode is not None and not np.all(np.isfinite(mode) & (mode == np.round(mode))):
        raise ProblemError(f"{path}: mode must hold an integer on every line (line "
                           f"{int(np.argmax(~(np.isfinite(mode) & (mode == np.round(mode))))) + 2})")
    if "gx_valid" in columns:                            # a functional observer
        return run_result(*args, mode=mode, names=names, **_functional_run(columns, path, metrics, where))
    if X.shape != XH.shape:                              # every observer but the functional one estimates x
        true, est = ("zhat_true", "zhat") if estimate == "zhat" else ("x", "xhat")
        raise ProblemError(f"{path}: {X.shape[1]} columns {true}[i] but {XH.shape[1]} columns {est}[i]")
    if "valid" in columns and "sigma_min" in columns:    # a delayed observer
        return run_result(*args, names=names, delayed=_delayed_run(columns, path, metrics, where))
    bound = columns.get("bound")
    decay = overshoot = None
    if bound is not None:
        decay = _number(metrics, ("certified_decay",), where)
        overshoot = _number(metrics, ("certified_overshoot",), where, optional=True)
    result = run_result(*args, bound=bound, decay=decay, overshoot=overshoot, mode=mode, names=names,
                        roundoff=_roundoff(metrics, where) if bound is not None else None)
    result.estimate = estimate
    return _with_noise(result, columns, path, metrics, where)


def _roundoff(metrics: dict, where) -> dict | None:
    """The run's ``roundoff_floor`` read back (its carried leaks enter the bound check again), or None."""
    leaks = metrics.get("roundoff_floor")
    if leaks is None:
        return None
    if not isinstance(leaks, dict) or not isinstance(leaks.get("roundoff"), bool):
        raise ProblemError(f"{where}: roundoff_floor: expected a table with roundoff true or false")
    return {"roundoff": leaks["roundoff"],
            **{k: _number(leaks, (k,), f"{where}: roundoff_floor") for k in ("carried", "worst_leak", "leak_eps")}}


def _with_noise(result, columns: dict, path, metrics: dict, where):
    """A run read back with its noise columns (``v[i]``, ``xhat_noisy[i]``) and its metrics' noise section:
    ``result.noise`` and the noise metrics, for the report's noise panel."""
    section = metrics.get("noise")
    if "v[1]" not in columns or not isinstance(section, dict) or "std" not in section:
        return result
    v, estimate = _vector(columns, "v", path), _vector(columns, f"{result.estimate}_noisy", path)
    level = section.get("effective_std", section["std"])
    std = np.asarray(level, dtype=float) if isinstance(level, list) else None
    if estimate.shape != result.x.shape or std is None or std.shape != (v.shape[1],):
        raise ProblemError(f"{where}: noise.std and the columns v[i], xhat_noisy[i] of {path} do not match its "
                           "x and y")
    result.noise = {"v": v, "std": std, "estimate": estimate, "error": estimate - result.x,
                    "twin_error": result.xhat - result.x}
    result.metrics.update({k: _number(metrics, (k,), where, optional=True)
                           for k in ("noise_gain_certified", "noise_gain_measured", "noise_gain_ratio")})
    result.metrics["noise_rms_error"] = metrics.get("noise_rms_error")
    respected = metrics.get("noise_gain_respected")
    result.metrics["noise_gain_respected"] = respected if isinstance(respected, bool) else None
    result.metrics["noise"] = section
    return result


def _functional_run(columns: dict, path, metrics: dict, where) -> dict:
    """The ``functional``, ``window`` and ``formula`` of a functional observer's run, from its table and
    ``metrics.json``."""
    gx, true, valid = _vector(columns, "gx", path), _vector(columns, "gx_true", path), columns["gx_valid"]
    if gx.shape != true.shape or not gx.shape[1]:
        raise ProblemError(f"{path}: {gx.shape[1]} columns gx[i] but {true.shape[1]} columns gx_true[i]")
    delay, window = (_number(metrics, (k,), where, integer=True) for k in ("delay", "window"))
    return {"functional": {"gx": gx, "true": true, "valid": valid}, "window": (delay, window),
            "formula": str(metrics.get("formula", ""))[:300]}


def _delayed_run(columns: dict, path, metrics: dict, where) -> dict:
    """The ``delayed`` histories of a delayed observer's run, from its table and ``metrics.json``."""
    thetahat = _vector(columns, "thetahat", path)
    sigma_bound = _number(metrics, ("validity", "sigma_bound"), where)
    theta = metrics.get("theta", {}).get("true") if isinstance(metrics.get("theta"), dict) else None
    if theta is not None and not (isinstance(theta, list) and len(theta) == thetahat.shape[1] and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in theta)):
        raise ProblemError(f"{where}: theta.true: expected {thetahat.shape[1]} finite numbers")
    theta = None if theta is None else np.array(theta, dtype=float)
    return {"thetahat": thetahat, "theta": theta, "sigma_min": columns["sigma_min"], "valid": columns["valid"],
            "sigma_bound": sigma_bound}
