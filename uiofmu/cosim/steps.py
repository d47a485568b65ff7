"""Communication-step sequences for the co-simulation master (``--steps SPEC``).

``fixed:H``             every step H seconds
``choice:H1,H2,...``    each step drawn uniformly from the list (``--seed``)
``uniform:HMIN:HMAX``   each step drawn uniformly from the interval (``--seed``)
``dropout:H:P:MAX``     nominal step H; each sample is lost with probability P, at most MAX
                        in a row, so h = H (1 + successive losses) (``--seed``)
``file:PATH``           one step per line (blank lines and ``#`` comments skipped)

A message about a step file names the path and the line, never the line's text: the path may name a
file that is no step file (``file:../../etc/passwd``), and what it holds is not shown.

The sequence is drawn once, independently of the run, so a seed gives the same steps for
every observer that is compared on it.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..runtime.errors import ProblemError
from ..runtime.files import read_text

#: Most communication steps of one run.
MAX_STEPS = 10_000_000
#: Most random numbers one block of a random SPEC draws (a dropout that loses nearly every sample needs many a
#: step): 256 MB of them.
MAX_DRAWS = 2**25


def _positive(text: str, what: str, quote: bool = True) -> float:
    """``text`` as a finite step > 0; a message names ``what`` and (``quote``) shows the text.

    Parameters
    ----------
    text : str
        A part of the SPEC, or a line of a step file.
    what : str
        What it is, for messages (``"HMIN"``, ``"line 3 of steps.txt"``).
    quote : bool
        Show the text in a message: a part of the SPEC the user typed, not a line of a file (whose
        content is never shown).
    """
    found = f", found {text!r}" if quote else ""
    try:
        value = float(text)
    except ValueError:
        raise ProblemError(f"--steps: {what} must be a number{found}") from None
    if not (math.isfinite(value) and value > 0):
        raise ProblemError(f"--steps: {what} must be > 0{found}")
    return value


def step_sequence(spec: str, t_end: float, seed: int = 0) -> np.ndarray:
    """The communication steps from 0 until the first point at or after ``t_end``.

    Parameters
    ----------
    spec : str
        A step SPEC (see the module docstring).
    t_end : float
        End time; the run stops at the first communication point at or after it (a step
        is never shortened: an observer may accept only the steps it was designed for).
    seed : int
        Seed of the random kinds.

    Returns
    -------
    numpy.ndarray
        The step lengths h_0, h_1, ...

    Raises
    ------
    ProblemError
        For a malformed SPEC, with what was expected.

    Examples
    --------
    >>> step_sequence("fixed:0.5", 2.0).tolist()
    [0.5, 0.5, 0.5, 0.5]
    """
    _check_t_end(t_end)
    kind, rest = spec.partition(":")[::2]
    if kind == "file":
        return _file_steps(rest, t_end)
    block, _, mean = _random_kind(spec)
    limit = t_end * (1 - 1e-12)
    wanted, drawn = int(min(t_end / mean * 1.25, MAX_STEPS)) + 16, -1
    while True:
        steps = block(np.random.default_rng(seed), wanted)
        reached = np.cumsum(steps)          # sequential sums: the times the loop ``t += h`` reaches
        count = int(np.searchsorted(reached, limit, side="left")) + 1
        if count > MAX_STEPS or (count > len(steps) and len(steps) > MAX_STEPS):
            raise ProblemError(f"--steps {short_spec(spec)} with --t-end {t_end:g} needs more than {MAX_STEPS} steps")
        if count <= len(steps):
            return steps[:count]
        if len(steps) == drawn:             # a block of MAX_DRAWS draws gave no more steps
            raise ProblemError(f"--steps {short_spec(spec)} with --t-end {t_end:g} needs more than {MAX_DRAWS} random "
                               "draws (a sample arrives too rarely)")
        wanted, drawn = 2 * wanted, len(steps)


def short_spec(spec: str, limit: int = 80) -> str:
    """A SPEC for a title or a message: whole up to ``limit`` characters, else its start and its length
    (a ``choice:`` of 100,000 steps made a figure's title that matplotlib took minutes to lay out)."""
    return spec if len(spec) <= limit else f"{spec[:limit]}... ({len(spec)} characters)"


def _check_t_end(t_end) -> None:
    if not (isinstance(t_end, (int, float)) and math.isfinite(t_end) and t_end > 0):
        raise ProblemError(f"--t-end must be > 0, found {t_end!r}")


def _file_steps(rest: str, t_end: float) -> np.ndarray:
    """The steps of ``file:PATH`` up to the first point at or after ``t_end``."""
    lines = read_text(Path(rest), "step file", error=ProblemError).splitlines()
    if len(lines) > MAX_STEPS:
        raise ProblemError(f"--steps file:{rest}: {len(lines)} lines, more than {MAX_STEPS} steps")
    steps = [_positive(line.split("#")[0].strip(), f"line {i + 1} of {rest} (one step in seconds a line, "
                       "# comments and blank lines aside)", quote=False)
             for i, line in enumerate(lines) if line.split("#")[0].strip()]
    if not steps:
        raise ProblemError(f"--steps file:{rest}: no steps in the file")
    out, t = [], 0.0
    for h in steps:
        if t >= t_end:
            break
        out.append(h)
        t += h
    return np.array(out)


def _random_kind(spec: str) -> tuple:
    """``(block, ranges, mean)`` of a SPEC other than ``file:``.

    ``block(rng, wanted)`` draws about ``wanted`` steps at once from ``rng`` (at least one): the same
    steps, in the same order, as one draw a step would give (a Generator's block of draws is its
    single draws one after another); ``ranges`` are the ``(low, high)`` intervals every step lies in
    (``low == high`` for a step that is listed); ``mean`` is about the mean step, to size the blocks.
    """
    kind, _, rest = spec.partition(":")
    if kind == "fixed":
        fixed = _positive(rest, "fixed:H")
        return (lambda rng, wanted: np.full(wanted, fixed)), [(fixed, fixed)], fixed
    if kind == "choice":
        options = np.array([_positive(v, "each choice") for v in rest.split(",") if v.strip()])
        if not len(options):
            raise ProblemError("--steps choice:H1,H2,...: give at least one step")
        return ((lambda rng, wanted: options[rng.integers(len(options), size=wanted)]),
                [(h, h) for h in dict.fromkeys(options.tolist())], float(options.mean()))
    if kind == "uniform":
        parts = rest.split(":")
        if len(parts) != 2:
            raise ProblemError(f"--steps uniform:HMIN:HMAX expected, found {spec!r}")
        lo, hi = _positive(parts[0], "HMIN"), _positive(parts[1], "HMAX")
        if lo > hi:
            raise ProblemError(f"--steps uniform: HMIN = {lo:g} > HMAX = {hi:g}")
        return (lambda rng, wanted: rng.uniform(lo, hi, size=wanted)), [(lo, hi)], 0.5 * (lo + hi)
    if kind == "dropout":
        parts = rest.split(":")
        if len(parts) != 3:
            raise ProblemError(f"--steps dropout:H:P:MAX expected, found {spec!r}")
        nominal = _positive(parts[0], "H")
        try:
            prob, most = float(parts[1]), int(parts[2])
        except ValueError:
            raise ProblemError(f"--steps dropout:H:P:MAX: P must be a number and MAX an integer, found {spec!r}") \
                from None
        if not 0 <= prob < 1 or most < 0:
            raise ProblemError(f"--steps dropout: expected 0 <= P < 1 and MAX >= 0, found P = {prob:g}, MAX = {most}")
        losses = range(most + 1) if prob > 0 else range(1)
        return (lambda rng, wanted: nominal * (1 + _dropout_losses(rng, wanted, prob, most)),
                [(nominal * (1 + j), nominal * (1 + j)) for j in losses[:MAX_LISTED]],
                nominal * (1 + min(prob / (1 - prob), most)))
    raise ProblemError(f"--steps: unknown kind {kind!r} (expected fixed:H, choice:H1,H2,..., "
                       "uniform:HMIN:HMAX, dropout:H:P:MAX or file:PATH)")


def _dropout_losses(rng: np.random.Generator, wanted: int, prob: float, most: int) -> np.ndarray:
    """The losses of the steps that a block of draws decides, for ``dropout:H:P:MAX``.

    A step draws until a sample arrives (a draw ``>= P``) or ``MAX`` samples in a row are lost (then
    without a further draw): a run of ``r`` losses before an arrival makes ``r // MAX`` steps of ``MAX``
    losses and one of ``r % MAX``. With ``MAX = 0`` no step draws at all.
    """
    if most == 0:
        return np.zeros(wanted, dtype=np.int64)
    draws = min(int(wanted * (1 + min(prob / (1 - prob), most))) + 1, MAX_DRAWS)
    arrived = np.flatnonzero(rng.random(draws) >= prob)
    runs = np.diff(arrived, prepend=-1) - 1          # losses before each arrival
    most = min(most, draws + 1)                      # no run of the block is longer: the same steps, in int64
    full, rest = np.divmod(runs, most)
    lost = np.full(int((full + 1).sum()), most, dtype=np.int64)
    lost[np.cumsum(full + 1) - 1] = rest
    return lost


#: Most distinct steps of a SPEC that :func:`step_ranges` lists (a dropout's MAX may be huge).
MAX_LISTED = 10_000


def step_ranges(spec: str, t_end: float) -> list:
    """The steps a SPEC can give over ``[0, t_end]``, whatever the seed.

    Parameters
    ----------
    spec : str
        A step SPEC.
    t_end : float
        The end time (a step file's steps past it are not taken).

    Returns
    -------
    list of (float, float)
        Intervals ``(low, high)`` every step lies in: ``low == high`` for a listed step (``fixed``,
        ``choice``, a dropout's ``H (1 + losses)``, a file's lines), ``low < high`` for ``uniform``.
        At most :data:`MAX_LISTED` of them (a dropout's first ones).

    Examples
    --------
    >>> step_ranges("dropout:0.1:0.5:2", 1.0)
    [(0.1, 0.1), (0.2, 0.2), (0.30000000000000004, 0.30000000000000004)]
    """
    _check_t_end(t_end)
    kind, rest = spec.partition(":")[::2]
    if kind == "file":
        return [(h, h) for h in dict.fromkeys(_file_steps(rest, t_end).tolist())][:MAX_LISTED]
    return _random_kind(spec)[1]
