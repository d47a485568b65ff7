"""pytest helpers for validation suites of observer FMUs: assertions and fixtures, driven by fmpy.

Every assertion is a plain function that runs the FMUs through uiofmu's co-simulation master
(:func:`uiofmu.cosim.master.cosimulate`, on fmpy through :class:`uiofmu.cosim.fmi.Fmu`) or its
validation (:func:`uiofmu.cosim.validate.validate`) and raises :class:`AssertionError` with a
message that says what was expected, what was measured and at which step::

    from uiofmu.testing import assert_bound_respected, assert_converges, assert_matches_runtime

    assert_converges("observer.fmu", "plant.fmu", steps="fixed:0.1", within=0.75, seed=3)
    assert_bound_respected("observer.fmu", "plant.fmu", seed=3, xhat0_error=0.5)
    assert_matches_runtime("observer.fmu", card="design.json")

The fixtures ``uiofmu_seed`` and ``uiofmu_fmus`` are registered by naming this module as a plugin,
in a test module or in the project's top-level ``conftest.py``::

    pytest_plugins = ["uiofmu.testing"]

``uiofmu_seed`` is 0 unless a test parametrises it (``@pytest.mark.parametrize("uiofmu_seed",
[0, 1, 2])``); a test that does not is run once per seed of the environment variable
``UIOFMU_SEEDS`` (``"0,1,2"`` or ``"0-9"``) when it is set; a value that names no seed (``"5-1"``), is
malformed or names more than :data:`MAX_SEEDS` seeds is an error collecting the test, never a skip.
``uiofmu_fmus(problem)`` designs a problem file and builds its observer and plant FMUs once per
session, in a temporary folder.

No assertion passes for want of something to check: arguments that leave nothing to compare (no
steps, a ``within`` longer than the run, a run that ends before a functional observer's first full
window, a tolerance that is not finite and > 0, a run whose error is 0 throughout) are a
:class:`ValueError` naming the parameter and its value, and an error or a bound that is NaN or
infinite anywhere fails the assertion (a NaN compares False with every tolerance).

A stale card: an observer FMU whose packed design card no longer passes its certificate
re-check (its gain edited after the design, say) is refused by the master. So that such an
observer fails :func:`assert_converges` and :func:`assert_bound_respected` for what it does, the
helpers then run the same co-simulation loop themselves (the master's routing and inputs, the
same FMI calls through :class:`~uiofmu.cosim.fmi.Fmu`), measure it, and add the failed check to
the message; :func:`assert_bound_respected` always fails on it, since such a card certifies no
bound.

The assertions raise their errors themselves, so pytest need not rewrite this module's ``assert``
statements (it has none): PYTEST_DONT_REWRITE, which also spares the warning pytest gives when a
test module imports the helpers before naming the plugin.
"""

from __future__ import annotations

import math
import numbers
import os
import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .runtime.card import Card, card_from_data, read_card
from .runtime.errors import CardError, FmuError, ProblemError

try:  # the assertions work without pytest; the fixtures need it
    import pytest
except ImportError:  # pragma: no cover - pytest is in the test extra
    pytest = None

#: The default convergence tolerance: a fraction of the initial error norm.
CONVERGENCE_TOL = 0.01

#: Most seeds ``UIOFMU_SEEDS`` may name. Each seed costs every test that takes ``uiofmu_seed`` one pytest item,
#: about 5 KB of memory (measured: 2.7 KB per item collected, 5.2 KB per item run; ``0-3000000`` took 8.5 GB
#: before a test ran), and at least one co-simulation or validation (0.03 to 0.08 s with C FMUs, 0.08 to 0.15 s
#: with Python ones, for the 695 steps of Example 1): 10 000 seeds are some 50 MB and 5 to 25 minutes of one core
#: per test, more than a validation suite runs.
MAX_SEEDS = 10_000
#: The largest seed (32 bits).
MAX_SEED = 2**32 - 1


def _real(value, name: str, low: float = 0.0, strict: bool = True, high: float | None = None) -> float:
    """``value`` as a float: a finite number above ``low`` (at least ``low`` if not ``strict``), at most ``high``.

    A NaN, an infinity, a bool or anything not a real number is a ValueError naming ``name`` and the value.
    """
    want = f"a finite number {'>' if strict else '>='} {low:g}" + ("" if high is None else f" and <= {high:g}")
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name}: expected {want}, found {value!r}")
    v = float(value)
    if not (math.isfinite(v) and (v > low if strict else v >= low) and (high is None or v <= high)):
        raise ValueError(f"{name}: expected {want}, found {value!r}")
    return v


def _count(value, name: str, low: int = 1) -> int:
    """``value`` as an int of at least ``low`` (a bool or a float is a ValueError naming ``name``)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < low:
        raise ValueError(f"{name}: expected an integer >= {low}, found {value!r}")
    return int(value)


def _seed(value, name: str = "seed") -> int:
    """``value`` as a seed: an integer from 0 to :data:`MAX_SEED`."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or not 0 <= value <= MAX_SEED:
        raise ValueError(f"{name}: expected an integer from 0 to {MAX_SEED}, found {value!r}")
    return int(value)


@dataclass
class Run:
    """One co-simulation made by the helpers.

    Attributes
    ----------
    result : CosimResult
        Histories and metrics (:class:`uiofmu.cosim.result.CosimResult`).
    card : Card
        The design card packed in the observer FMU.
    steps : numpy.ndarray
        The communication steps of the run.
    spec : str
        How the steps were given (a step SPEC, or ``"given"``).
    seed : int
        The seed of the steps and of the initial error.
    certificate_problem : str or None
        Why the card's certificate does not hold at its stored matrices (None when it holds);
        such a run was made by the helpers' own loop, not by the master, which refuses it.
    """

    result: object
    card: Card
    steps: np.ndarray
    spec: str
    seed: int
    certificate_problem: str | None = None

    def where(self, k: int) -> str:
        """``step k (t = ... s)`` for communication point ``k``.

        Parameters
        ----------
        k : int
            A communication point index.

        Returns
        -------
        str
        """
        return f"step {k} (t = {self.result.times[k]:.6g} s)"

    def context(self, note: bool = True) -> str:
        """What the run was: steps, their count, seed, end time, and a stale certificate if any.

        Parameters
        ----------
        note : bool
            Add the failed certificate check of a stale card.

        Returns
        -------
        str
        """
        r = self.result
        e0 = "" if r.functional is not None else \
            f", initial error ||x0 - xhat0|| = {np.linalg.norm(r.x[0] - r.xhat[0]):.6g}"
        text = f"[{len(self.steps)} steps {self.spec}, seed {self.seed}, t_end {r.times[-1]:.6g} s{e0}]"
        if note and self.certificate_problem:
            text += (f"; note: {self.certificate_problem} (a stale card: the master refuses it, so this run was made "
                     "by uiofmu.testing's own loop on the same FMUs)")
        return text


def _name(path) -> str:
    return Path(path).name


def packed_card(observer_fmu) -> Card:
    """The design card packed in an observer FMU built by uiofmu, schema-checked, certificate not re-checked.

    Parameters
    ----------
    observer_fmu : str or Path
        The observer FMU.

    Returns
    -------
    Card

    Raises
    ------
    AssertionError
        When the FMU is not an observer built by uiofmu, or its card fails the card schema.
    """
    from .cosim.fmi import read_model_json

    try:
        spec = read_model_json(observer_fmu)
        if spec.get("kind") != "observer" or "card" not in spec:
            raise FmuError(f"{observer_fmu}: this FMU is not an observer built by uiofmu")
        return card_from_data(spec["card"])
    except (FmuError, CardError) as exc:
        raise AssertionError(f"{_name(observer_fmu)}: expected an observer FMU built by uiofmu with a valid design "
                             f"card; {exc}") from None


def certificate_problem(card: Card) -> str | None:
    """Why a card's certificate does not hold at its stored matrices, or None when it holds.

    Parameters
    ----------
    card : Card
        A card that passed the schema.

    Returns
    -------
    str or None
        The message of :func:`uiofmu.synthesis.recheck`.
    """
    from .synthesis import recheck

    try:
        recheck(card)
    except CardError as exc:
        return str(exc)
    return None


def _as_card(card) -> Card:
    if isinstance(card, Card):
        return card
    if isinstance(card, dict):
        return card_from_data(card)
    return read_card(card)


def _steps(card: Card, steps, t_end, seed: int) -> tuple[np.ndarray, str]:
    """The step lengths of a run and how they were given; a ValueError naming ``steps`` or ``t_end`` for steps
    that make no run (none, a number, a length that is not finite and > 0) and for ``t_end`` with given lengths."""
    from .cosim.master import default_steps, default_t_end
    from .cosim.steps import MAX_STEPS, step_sequence

    if steps is None or isinstance(steps, str):
        spec = default_steps(card) if steps is None else steps
        horizon = default_t_end(card) if t_end is None else t_end
        try:
            return step_sequence(spec, horizon, seed), spec
        except ProblemError as exc:
            raise ValueError(f"steps={spec!r} (t_end {horizon:g} s): {exc}") from None
    want = "a step SPEC such as 'fixed:0.1', or a 1-D sequence of at least one step length > 0"
    if t_end is not None:
        raise ValueError(f"t_end: applies to a step SPEC only; found t_end={t_end!r} with the step lengths given "
                         "(the run ends at their sum: leave t_end out)")
    if isinstance(steps, numbers.Number):
        raise ValueError(f"steps: expected {want}; found the number {steps!r}")
    try:
        seq = np.asarray(steps, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"steps: expected {want}; found {type(steps).__name__} {steps!r:.80}") from None
    if seq.ndim != 1 or not seq.size:
        raise ValueError(f"steps: expected {want}; found an array of shape {seq.shape}")
    if seq.size > MAX_STEPS:
        raise ValueError(f"steps: {seq.size} step lengths, more than the {MAX_STEPS} of one run")
    bad = np.flatnonzero(~(np.isfinite(seq) & (seq > 0)))
    if bad.size:
        k = int(bad[0])
        raise ValueError(f"steps: every step length must be finite and > 0; step {k} is {float(seq[k])!r} "
                         f"({bad.size} of {seq.size} are not)")
    return seq, "given"


def _xhat0(card: Card, xhat0_error: float, seed: int):
    """The card's initial estimate plus a random offset of standard deviation ``xhat0_error`` (None for none)."""
    if not xhat0_error:
        return None
    base = np.asarray(card.data["initial"].get("xhat0", [0.0] * card.dims["n"]), dtype=float)
    return base + xhat0_error * np.random.default_rng([seed, 1]).standard_normal(base.size)


def _prepare(observer_fmu, steps, t_end, seed, xhat0_error):
    """The checked arguments of a run: the packed card, the steps, their SPEC and the initial estimate (or None)."""
    seed = _seed(seed)
    xhat0_error = _real(xhat0_error, "xhat0_error", strict=False)
    if t_end is not None:
        t_end = _real(t_end, "t_end")
    card = packed_card(observer_fmu)
    if xhat0_error and not card.stepper.estimates_x:
        raise ValueError(f"xhat0_error: {_name(observer_fmu)} is a functional observer (kernel window), which has no "
                         f"initial estimate to offset; found xhat0_error={xhat0_error:g} (leave it 0)")
    seq, spec = _steps(card, steps, t_end, seed)
    return card, seq, spec, seed, _xhat0(card, xhat0_error, seed)


def run_observer(observer_fmu, plant_fmu, steps=None, t_end: float | None = None, seed: int = 0,
                 xhat0_error: float = 0.0) -> Run:
    """Co-simulate an observer FMU with a plant FMU, as the assertions do.

    Parameters
    ----------
    observer_fmu, plant_fmu : str or Path
        The FMUs (the observer built by uiofmu; its card gives the inputs and the bound).
    steps : str or array_like, optional
        A step SPEC of :mod:`uiofmu.cosim.steps` (``"fixed:0.1"``, ``"dropout:600:0.3:11"``, ...)
        or the step lengths themselves (at least one, each finite and > 0); default: the steps the
        observer is designed for.
    t_end : float, optional
        End time for a SPEC, finite and > 0 (default: the card's horizon,
        :func:`uiofmu.runtime.experiments.default_horizon`); not with step lengths.
    seed : int
        Seed of a random SPEC and of the initial error, from 0 to :data:`MAX_SEED`.
    xhat0_error : float
        Standard deviation (finite, >= 0) of a random offset (drawn from ``seed``) added to the
        observer's initial estimate; 0 keeps the card's. Not for a functional observer (kernel window).

    Returns
    -------
    Run

    Raises
    ------
    ValueError
        For arguments that make no run, naming the parameter and its value: ``steps`` that are a
        number, empty, or a length that is not finite and > 0, or a malformed SPEC; ``t_end`` not
        finite and > 0, or given with step lengths; ``seed`` not an integer from 0 to
        :data:`MAX_SEED`; ``xhat0_error`` negative or not finite, or not 0 for a functional observer.
    AssertionError
        When an FMU refuses a call during the run (the master's message), or the observer FMU is not
        an observer built by uiofmu.
    """
    card, seq, spec, seed, xhat0 = _prepare(observer_fmu, steps, t_end, seed, xhat0_error)
    return _execute(observer_fmu, plant_fmu, card, seq, spec, seed, xhat0)


def _execute(observer_fmu, plant_fmu, card: Card, seq: np.ndarray, spec: str, seed: int, xhat0, noise=None) -> Run:
    """The run of :func:`run_observer` on checked arguments (with ``noise``, a ``--noise`` text for the master)."""
    from .cosim.kernels import cosim_kernel
    from .cosim.master import cosimulate

    problem = certificate_problem(card)
    try:
        if problem is None:
            result = cosimulate(plant_fmu, observer_fmu, seq, xhat0=xhat0, show_progress=False, noise=noise)
        elif cosim_kernel(card).random_run:
            result = _stale_run(plant_fmu, observer_fmu, card, seq, xhat0)
        else:
            raise AssertionError(f"{_name(observer_fmu)}: expected a certified observer; {problem}, and uiofmu's "
                                 f"master refuses to co-simulate it (kernel {card.kernel})")
    except (FmuError, CardError) as exc:
        raise AssertionError(f"{_name(observer_fmu)} with {_name(plant_fmu)}: the co-simulation did not run to its "
                             f"end ({len(seq)} steps {spec}, seed {seed}): {exc}") from None
    return Run(result, card, seq, spec, seed, problem)


def _stale_run(plant_path, observer_path, card: Card, steps: np.ndarray, xhat0):
    """The master's loop for an affine-kernel observer whose card fails its certificate re-check.

    The same routing (:func:`uiofmu.cosim.master.routes`), inputs (the card's ``[signals]``), order of
    FMI calls and metrics as :func:`uiofmu.cosim.master.cosimulate`, with the card's claimed bound.
    """
    from .cosim.fmi import Fmu, FmuCallError
    from .cosim.master import CosimResult, default_inputs, driven_inputs, routes
    from .cosim.metrics import error_metrics
    from .families import certified_bound

    inputs = default_inputs(card)
    K = len(steps)
    with Fmu(plant_path, "plant") as plant, Fmu(observer_path, "observer") as obs:
        fed, sourced = routes(plant, obs, inputs.sizes)
        plant.initialize(0.0)
        obs.initialize(0.0, {"xhat0": xhat0} if xhat0 is not None else None)
        size = {**plant.ports("output"), **obs.ports("output"), **inputs.sizes}
        hist = {name: np.zeros((K + 1, size.get(name, 0))) for name in ("x", "y", "u", "d", "xhat", "r", "dhat")}
        plant_inputs = driven_inputs(plant, inputs.sizes)
        T, t = np.zeros(K + 1), 0.0
        for k in range(K + 1):
            values = inputs.values(t)
            for name in plant_inputs:
                plant.set(name, values[name])
            for name in fed:
                obs.set(name, plant.get(name))
            for name in sourced:
                obs.set(name, values[name])
            T[k] = t
            for name in ("x", "y"):
                hist[name][k] = plant.get(name)
            for name in ("u", "d"):
                hist[name][k] = values.get(name, hist[name][k])
            for name in ("xhat", "r", "dhat"):
                if obs.has(name):
                    hist[name][k] = obs.get(name)
            if k == K:
                break
            for who, fmu in (("observer", obs), ("plant", plant)):
                try:
                    fmu.step(t, steps[k])
                except FmuCallError as exc:
                    raise FmuError(f"the {who} FMU refused step {k} (t = {t:g} s, h = {steps[k]:g} s): "
                                   + (exc.messages[-1] if exc.messages else str(exc))) from None
            t += steps[k]
    X, XH, D, DH = hist["x"], hist["xhat"], hist["d"], hist["dhat"]
    result = CosimResult(T, steps, X, XH, hist["y"], hist["u"], D, hist["r"], DH, card=card)
    result.bound = certified_bound(card, X[0] - XH[0], D)
    nq = DH.shape[1]
    result.metrics = error_metrics(T, steps, X, XH, result.bound, card.data.get("decay_bound"),
                                   card.data.get("overshoot_bound"), D if nq else None, DH if nq else None)
    return result


def _limit(within, K: int, spec: str) -> int:
    """``within`` as a number of steps: an int is one (at most ``K``), a float in (0, 1] a fraction of ``K``."""
    if isinstance(within, bool) or not isinstance(within, numbers.Real) or not within > 0:
        raise ValueError(f"within: expected a number of steps (int >= 1) or a fraction of the run in (0, 1], "
                         f"found {within!r}")
    if isinstance(within, numbers.Integral):
        if within > K:
            raise ValueError(f"within: {int(within)} steps, more than the {K} steps of the run ({spec}), so no point "
                             f"would be checked; give at most {K} steps, a fraction of the run, or a longer run")
        return int(within)
    if within > 1:
        raise ValueError(f"within: a fraction of the run must be in (0, 1], found {within!r}")
    return math.ceil(within * K)


def _error_norms(run: Run) -> np.ndarray:
    r = run.result
    if r.functional is not None:
        f = r.functional
        err = np.linalg.norm(f["gx"] - f["true"], axis=1)
        return np.where(f["valid"] > 0.5, err, np.inf)
    return np.linalg.norm(r.x - r.xhat, axis=1)


def _not_finite(run: Run, values: dict, where: np.ndarray | None = None) -> str:
    """Where the first of ``values`` (name: array over the points) is NaN or infinite (at the points of ``where``),
    with the values there, or ``""`` when all are finite. A NaN compares False with every tolerance, so an
    assertion would let it through unless it is caught here."""
    bad = np.zeros(len(run.result.times), dtype=bool)
    for v in values.values():
        bad |= ~np.isfinite(v)
    if where is not None:
        bad &= where
    at = np.flatnonzero(bad)
    if not at.size:
        return ""
    k = int(at[0])
    shown = ", ".join(f"{name} = {float(v[k]):.6g}" for name, v in values.items())
    r = run.result
    state = "" if r.functional is not None else (f" (x = {np.array2string(r.x[k], precision=6)}, xhat = "
                                                 f"{np.array2string(r.xhat[k], precision=6)})")
    return f"not finite from {run.where(k)} on: {shown}{state}; {at.size} such point(s)"


def _require_error(run: Run, norms: np.ndarray, what: str) -> None:
    """A ValueError when the estimation error is 0 at every point: then the run cannot show what ``what`` says
    (a diverging observer stays at 0 too), whatever the observer."""
    if not np.any(norms):
        raise ValueError(f"xhat0_error: the estimation error ||x - xhat|| is 0 at every one of the {len(norms)} points "
                         f"(the observer starts at the plant's state and nothing drives the error), so the run cannot "
                         f"show {what}; give xhat0_error > 0 for a random initial error {run.context()}")


def assert_converges(observer_fmu, plant_fmu, steps=None, t_end: float | None = None, within=1.0,
                     tol: float = CONVERGENCE_TOL, seed: int = 0, xhat0_error: float = 0.0) -> Run:
    """Assert that the estimation error falls to ``tol`` of its initial norm within a number of steps.

    The error ``||x_k - xhat_k||`` must be finite at every communication point and at most
    ``tol * ||x_0 - xhat_0||`` at every point from step ``within`` on (for a functional observer:
    ``gx`` finite where valid, and valid and within ``tol`` of ``G x``, absolutely, from step
    ``within`` on).

    Parameters
    ----------
    observer_fmu, plant_fmu : str or Path
        The FMUs.
    steps : str or array_like, optional
        A step SPEC or the step lengths (see :func:`run_observer`).
    t_end : float, optional
        End time for a SPEC.
    within : int or float
        A number of steps (int, 1 to the run's number of steps), or a fraction of the run's steps
        in (0, 1] (float; 1.0: by its end).
    tol : float
        The fraction of the initial error norm to fall to (finite, > 0).
    seed : int
        Seed of a random SPEC and of the initial error.
    xhat0_error : float
        Standard deviation of a random offset added to the observer's initial estimate.

    Returns
    -------
    Run
        The run, for further checks.

    Raises
    ------
    ValueError
        For arguments that cannot test convergence, naming the parameter and its value: those of
        :func:`run_observer`; ``within`` not a positive number of steps or a fraction in (0, 1], or
        more steps than the run has (no point would be checked); ``tol`` not finite and > 0; and a
        run whose error is 0 at every point (nothing to converge from: give ``xhat0_error``).
    AssertionError
        When the error is not finite at some point (the first such point and the values there), or
        above the tolerance at some point after the limit: the limit, the tolerance, the last step
        above it and its error, and the largest error.
    """
    tol = _real(tol, "tol")
    card, seq, spec, seed, xhat0 = _prepare(observer_fmu, steps, t_end, seed, xhat0_error)
    K = len(seq)
    limit = _limit(within, K, spec)
    run = _execute(observer_fmu, plant_fmu, card, seq, spec, seed, xhat0)
    norms = _error_norms(run)
    if run.result.functional is not None:
        allowed, what = tol, f"|gx - G x| <= {tol:.3g}"
        label, where = "|gx - G x|", run.result.functional["valid"] > 0.5
    else:
        allowed = tol * norms[0]
        what = f"||x - xhat|| <= {tol:.3g} x {norms[0]:.6g} = {allowed:.6g}"
        label, where = "||x - xhat||", None
    nonfinite = _not_finite(run, {label: norms}, where)
    if nonfinite:
        raise AssertionError(f"{_name(observer_fmu)}: expected a finite estimation error at every point; it is "
                             f"{nonfinite} {run.context()}")
    if run.result.functional is None:
        _require_error(run, norms, "convergence")
    bad = np.flatnonzero(~(norms <= allowed))
    late = bad[bad >= limit]
    if late.size:
        last = int(bad[-1])
        top = int(np.argmax(np.where(np.isnan(norms), np.inf, norms)))
        tail = (f"it never gets there: still {norms[last]:.6g} at the last point, {run.where(last)}"
                if last == K else f"the last point above it is {run.where(last)} with {norms[last]:.6g}, "
                f"{last - limit + 1} step(s) late")
        raise AssertionError(
            f"{_name(observer_fmu)} does not converge within {limit} of {K} steps: expected {what} from "
            f"{run.where(min(limit, K))} on; measured {norms[int(late[0])]:.6g} at {run.where(int(late[0]))}, and "
            f"{tail}; largest error {norms[top]:.6g} at {run.where(top)} {run.context()}")
    if run.certificate_problem:
        warnings.warn(f"{_name(observer_fmu)} converges, but {run.certificate_problem}", UserWarning, stacklevel=2)
    return run


def assert_bound_respected(observer_fmu, plant_fmu, steps=None, t_end: float | None = None, seed: int = 0,
                           xhat0_error: float = 0.0, max_ratio: float = 1.0) -> Run:
    """Assert that the error stays inside the certified bound of the card packed in the observer FMU.

    The comparison is the master's (``bound_respected``, ``max_bound_ratio`` and
    ``first_bound_violation`` of :func:`uiofmu.cosim.metrics.error_metrics`, with its round-off slack),
    after the error and the bound are checked to be finite at every point (a NaN compares False
    with the bound).

    Parameters
    ----------
    observer_fmu, plant_fmu : str or Path
        The FMUs.
    steps : str or array_like, optional
        A step SPEC or the step lengths (see :func:`run_observer`).
    t_end : float, optional
        End time for a SPEC.
    seed : int
        Seed of a random SPEC and of the initial error.
    xhat0_error : float
        Standard deviation of a random offset added to the observer's initial estimate.
    max_ratio : float
        The largest accepted ratio of the error to the bound, in (0, 1] (below 1 to demand a margin).

    Returns
    -------
    Run

    Raises
    ------
    ValueError
        For arguments that cannot test the bound, naming the parameter and its value: those of
        :func:`run_observer`; ``max_ratio`` not in (0, 1]; and a run whose error is 0 at every point
        (any observer stays inside a bound there: give ``xhat0_error``).
    AssertionError
        When the error or the bound is not finite at some point (the first such point and the values
        there), when the error leaves the bound (the first step out, the error and the bound there, the
        largest ratio), when the card certifies no bound (a delayed or functional observer), or when the
        card's certificate does not hold (its bound is then not certified; where the run leaves the claimed
        bound is said too).
    """
    max_ratio = _real(max_ratio, "max_ratio", high=1.0)
    run = run_observer(observer_fmu, plant_fmu, steps, t_end, seed, xhat0_error)
    m, name = run.result.metrics, _name(observer_fmu)
    if run.result.bound is None or "bound_respected" not in m:
        raise AssertionError(f"{name}: expected a card with a certified error bound; the {run.card.family} card "
                             f"(kernel {run.card.kernel}) certifies none to compare the run with"
                             + ("" if run.card.stepper.estimates_x else " (use assert_exact_functional)"))
    formula = run.card.data.get("bound", "the bound")
    norms = np.linalg.norm(run.result.x - run.result.xhat, axis=1)
    nonfinite = _not_finite(run, {"||x - xhat||": norms, "bound": np.asarray(run.result.bound, dtype=float)})
    measured = f"the error or the bound is {nonfinite}" if nonfinite else ""
    if not measured and not m["bound_respected"]:
        k = int(m["first_bound_violation"])
        measured = (f"the error leaves it at {run.where(k)}: ||x - xhat|| = {m['error_at_first_violation']:.6g} > "
                    f"bound {m['bound_at_first_violation']:.6g}; largest ratio error/bound {m['max_bound_ratio']:.6g}")
    elif not measured and not m["max_bound_ratio"] <= max_ratio:
        k = int(np.argmax(norms / np.maximum(run.result.bound, 1e-300)))
        measured = (f"the error reaches {m['max_bound_ratio']:.6g} of the bound (at most {max_ratio:g} accepted), "
                    f"near {run.where(k)}")
    if run.certificate_problem:
        raise AssertionError(f"{name}: expected a certified bound ({formula}); {run.certificate_problem}, so the card "
                             f"certifies no bound; measured against the bound it claims: "
                             + (measured or f"inside it (largest ratio {m['max_bound_ratio']:.6g})")
                             + f" {run.context(note=False)}")
    if measured:
        raise AssertionError(f"{name}: expected ||x - xhat|| inside the certified bound ({formula}) at every step; "
                             f"{measured} {run.context()}")
    _require_error(run, norms, "that the error stays inside a bound")
    return run


def assert_noise_gain_respected(observer_fmu, plant_fmu, noise_std: float = 0.01, steps=None,
                                t_end: float | None = None, seed: int = 0) -> Run:
    """Assert that sensor noise reaches the estimate with at most the card's certified gain.

    The master adds seeded white noise of ``noise_std`` to every output between the plant and the observer and
    runs a noise-free twin of the observer in the same loop (``uiofmu cosim --noise``); the measured gain
    ``||e - e_twin||_2 / ||v||_2`` must be at most the card's ``noise.gain_y``.

    Parameters
    ----------
    observer_fmu, plant_fmu : str or Path
        The FMUs.
    noise_std : float
        Standard deviation of the noise on every output (finite, > 0).
    steps, t_end, seed
        As for :func:`run_observer`; ``seed`` also seeds the noise.

    Returns
    -------
    Run

    Raises
    ------
    ValueError
        For arguments that make no run (those of :func:`run_observer`, ``noise_std`` not finite and > 0).
    AssertionError
        When the card certifies no noise gain (its reason is said), or the measured gain exceeds the certified one
        (both numbers).
    """
    noise_std = _real(noise_std, "noise_std")
    card, seq, spec, seed, xhat0 = _prepare(observer_fmu, steps, t_end, seed, 0.0)
    name, section = _name(observer_fmu), card.data.get("noise") or {}
    if section.get("gain_y") is None:
        raise AssertionError(f"{name}: expected a card with a certified noise gain; the {card.family} card certifies "
                             f"none ({section.get('reason') or 'it has no noise section'})")
    if section.get("covers"):
        raise AssertionError(f"{name}: the {card.family} card's gain_y holds on premises a co-simulation does not keep "
                             f"({section['covers']}): a measured gain does not check it")
    run = _execute(observer_fmu, plant_fmu, card, seq, spec, seed, xhat0, noise=f"y={noise_std!r},{seed}")
    m = run.result.metrics
    if not m.get("noise_gain_respected"):
        raise AssertionError(f"{name}: expected a noise gain of at most the certified {section['gain_y']:.6g}; "
                             f"measured {m.get('noise_gain_measured')!r} with noise std {noise_std:g} {run.context()}")
    return run


def assert_exact_functional(observer_fmu, plant_fmu, steps=None, t_end: float | None = None, seed: int = 0,
                            rtol: float = 1e-9) -> Run:
    """Assert that a dead-beat functional observer's ``gx`` equals ``G x`` from its first full window on.

    The first full window of ``L`` samples (the card's ``schedule.length``) is at step ``L - 1``:
    from there on ``gx_valid`` must be 1 and ``gx`` exact at every point, and so must ``gx`` be
    wherever the observer says it is valid before.

    Parameters
    ----------
    observer_fmu, plant_fmu : str or Path
        The FMUs (the observer of kernel ``window``, seed 003).
    steps : str or array_like, optional
        A step SPEC or the step lengths (default: the observer's ``dt``); the run must reach the first
        full window.
    t_end : float, optional
        End time for a SPEC.
    seed : int
        Seed of a random SPEC.
    rtol : float
        ``gx`` is exact at a point when ``|gx - G x| <= rtol * max(1, |G x|)`` (finite, > 0).

    Returns
    -------
    Run

    Raises
    ------
    ValueError
        For arguments that cannot test the observer, naming the parameter and its value: those of
        :func:`run_observer`; ``rtol`` not finite and > 0; and steps of a run that ends before the
        first full window (no point would be checked).
    AssertionError
        When the observer is not functional, ``gx_valid`` never rises or is 0 at a point from the first
        full window on, or ``gx`` differs from ``G x`` (or is not finite) at such a point or at a point
        where ``gx_valid`` is 1 (the point, both values, the difference and its allowance).
    """
    rtol = _real(rtol, "rtol")
    card, seq, spec, seed, _ = _prepare(observer_fmu, steps, t_end, seed, 0.0)
    name = _name(observer_fmu)
    if card.stepper.estimates_x:
        raise AssertionError(f"{name}: expected a functional observer (kernel window), found a {card.family} "
                             f"observer of kernel {card.kernel} (use assert_converges)")
    window = int(card.schedule["length"])
    first = window - 1
    if len(seq) < first:
        raise ValueError(f"steps: the run has {len(seq)} steps ({spec}, to t = {seq.sum():g} s), but the first full "
                         f"window of {window} samples is at step {first}, so no point would be checked; give a "
                         f"longer t_end or more steps")
    run = _execute(observer_fmu, plant_fmu, card, seq, spec, seed, None)
    f = run.result.functional
    valid = f["valid"] > 0.5
    if not valid.any():
        raise AssertionError(f"{name}: expected gx_valid = 1 from the first full window ({window} samples) on; "
                             f"gx_valid is 0 at every one of the {len(valid)} points {run.context()}")
    err = np.linalg.norm(f["gx"] - f["true"], axis=1)
    scale = np.maximum(1.0, np.linalg.norm(np.nan_to_num(f["true"]), axis=1))
    ok = valid & (err <= rtol * scale)
    checked = valid | (np.arange(len(valid)) >= first)
    bad = np.flatnonzero(checked & ~ok)
    if bad.size:
        k = int(bad[0])
        reason = ("gx_valid is 0" if not valid[k] else
                  f"gx = {np.array2string(f['gx'][k], precision=10)} but G x = "
                  f"{np.array2string(f['true'][k], precision=10)} (|gx - G x| = {err[k]:.3g}, allowed "
                  f"{rtol * scale[k]:.3g})")
        raise AssertionError(f"{name}: expected gx = G x exactly from the first full window ({run.where(first)}) "
                             f"on; at {run.where(k)} {reason}; {bad.size} such point(s) {run.context()}")
    return run


def _matrix_differences(packed: Card, card: Card) -> list[str]:
    """What two cards' designs differ in: the schedule, and every stored matrix with its largest difference."""
    out = []
    if packed.data.get("schedule") != card.data.get("schedule"):
        out.append("the schedule")
    ours, theirs = packed.data["matrices"], card.data["matrices"]
    for key in sorted(set(ours) | set(theirs)):
        try:
            a, b = np.asarray(ours[key], dtype=float), np.asarray(theirs[key], dtype=float)
        except (KeyError, TypeError, ValueError):
            if ours.get(key) != theirs.get(key):
                out.append(f"matrices.{key}")
            continue
        if a.shape != b.shape:
            out.append(f"matrices.{key} (shape {a.shape} in the FMU, {b.shape} in the card)")
            continue
        diff = np.abs(a - b)
        if diff.size and not diff.max() <= 0:
            i = np.unravel_index(int(np.argmax(np.where(np.isnan(diff), np.inf, diff))), diff.shape)
            out.append(f"matrices.{key} by up to {float(diff[i]):.6g} (entry {list(map(int, i))}: FMU "
                       f"{float(a[i]):.6g}, card {float(b[i]):.6g})")
    return out


def _first_runtime_difference(observer_fmu, card: Card, steps: int, seed: int, rtol: float):
    """An affine-kernel observer FMU against :class:`uiofmu.runtime.observer.Runtime` of ``card``, on the random
    inputs and steps of :func:`uiofmu.cosim.validate.validate`; the first step where the largest relative
    difference so far exceeds ``rtol``, with the outputs there, or None."""
    from .cosim.fmi import Fmu
    from .cosim.kernels import random_observer_run
    from .runtime.observer import Runtime

    rt = Runtime(card)
    worst, scale = 0.0, 1.0
    with Fmu(observer_fmu, "testing") as fmu:
        for k in random_observer_run(fmu, rt, steps, np.random.default_rng(seed)):
            got, ref = fmu.get("zhat" if rt.zhat_only else "xhat"), rt.xhat()
            scale = max(scale, float(np.abs(ref).max(initial=0.0)))
            diff = np.abs(got - ref)
            worst = max(worst, float(np.where(np.isnan(diff), np.inf, diff).max(initial=0.0)))
            if worst / scale > rtol:
                return k, got, ref, worst / scale
    return None


def assert_matches_runtime(observer_fmu, card=None, steps: int = 200, rtol: float = 1e-12, seed: int = 0) -> None:
    """Assert that an observer FMU computes what the reference runtime of a design card computes.

    fmpy's static check and the FMU against the reference runtime of the card packed in it, on random
    inputs and steps (:func:`uiofmu.cosim.validate.validate`); with ``card``, also that the FMU runs that
    card: the same matrices, and the same ``xhat`` as its :class:`~uiofmu.runtime.observer.Runtime` on
    random inputs. The reference card must pass its certificate re-check.

    Parameters
    ----------
    observer_fmu : str or Path
        The observer FMU.
    card : Card, dict or str or Path, optional
        The design card the FMU should run (say, the one your project keeps under version control);
        default: the card packed in the FMU.
    steps : int
        Number of random steps (>= 1).
    rtol : float
        Largest accepted difference relative to ``max(1, largest |reference output|)`` over the run
        (finite, > 0); a NaN output counts as an infinite difference.
    seed : int
        Seed of the random inputs and steps, from 0 to :data:`MAX_SEED`.

    Raises
    ------
    ValueError
        Naming the parameter and its value: ``steps`` not an integer >= 1 (no step would be compared),
        ``rtol`` not finite and > 0, or ``seed`` not an integer from 0 to :data:`MAX_SEED`.
    AssertionError
        Naming what differs: fmpy's findings, the matrices that are not the card's, the first step
        where the outputs part and by how much, or the reference card's failed certificate check.
    """
    from .cosim.kernels import cosim_kernel
    from .cosim.validate import validate

    steps, rtol, seed = _count(steps, "steps"), _real(rtol, "rtol"), _seed(seed)
    name = _name(observer_fmu)
    packed = packed_card(observer_fmu)
    ref = packed if card is None else _as_card(card)
    which = "the card packed in it" if card is None else "the given card"
    problem = certificate_problem(ref)
    if problem:
        raise AssertionError(f"{name}: expected a reference card whose certificate holds; {which}: {problem}")
    if card is not None:
        differences = _matrix_differences(packed, ref)
        if differences:
            measured = ""
            if ref.kernel == packed.kernel and cosim_kernel(ref).random_run and ref.dims == packed.dims:
                first = _first_runtime_difference(observer_fmu, ref, steps, seed, rtol)
                if first is not None:
                    k, got, want, rel = first
                    measured = (f"; on random inputs its xhat parts from the card's runtime at step {k}: FMU "
                                f"{np.array2string(got, precision=8)}, runtime {np.array2string(want, precision=8)} "
                                f"(relative difference {rel:.3g} > rtol {rtol:g})")
            raise AssertionError(f"{name}: expected the FMU to run the given card ({ref.name}); the card packed in it "
                                 f"differs in " + "; ".join(differences) + measured)
    try:
        report = validate(observer_fmu, steps=steps, seed=seed)
    except FmuError as exc:
        raise AssertionError(f"{name}: the validation did not run: {exc}") from None
    if report.problems:
        raise AssertionError(f"{name}: expected no findings from fmpy's validate_fmu and no refused call; found: "
                             + "; ".join(report.problems))
    if not report.max_rel_diff <= rtol:
        raise AssertionError(f"{name}: expected its outputs within rtol {rtol:g} of the reference runtime of {which} "
                             f"over {report.steps} random steps (seed {seed}); measured a relative difference of "
                             f"{report.max_rel_diff:.3g} (absolute {report.max_abs_diff:.3g}, scale {report.scale:.3g})"
                             )


@dataclass
class Fmus:
    """The FMUs of a problem built by :func:`build_fmus`.

    Attributes
    ----------
    problem : Problem
    card : Card
        The designed card (written to ``card_path``).
    card_path, observer, plant : Path
    """

    problem: object
    card: Card
    card_path: Path
    observer: Path
    plant: Path


def build_fmus(problem, out_dir, backend: str | None = None) -> Fmus:
    """Design a problem and build its observer and plant FMUs into a folder.

    Parameters
    ----------
    problem : str or Path or Problem
        A problem file (or folder with ``problem.toml``), or a loaded problem.
    out_dir : str or Path
        The folder (created) for ``NAME.design.json``, ``NAME_observer.fmu`` and ``NAME_plant.fmu``.
    backend : {"c", "python"}, optional
        The FMU backend (default: uiofmu's choice).

    Returns
    -------
    Fmus
    """
    from .fmu.export import build_observer, build_plant
    from .problem import Problem, load_problem
    from .synthesis import design

    problem = problem if isinstance(problem, Problem) else load_problem(problem)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    card = design(problem)
    card_path = card.write(out / f"{problem.name}.design.json")
    observer = build_observer(card, out / f"{problem.name}_observer.fmu", backend=backend)
    plant = build_plant(problem.plant, problem.name, out / f"{problem.name}_plant.fmu", backend=backend,
                        experiment_steps=problem.experiment_steps, labels=problem.labels)
    return Fmus(problem, card, Path(card_path), Path(observer), Path(plant))


#: One item of ``UIOFMU_SEEDS``: a seed or an inclusive range ``LO-HI`` of ASCII digits.
_SEED_ITEM = re.compile(r"\s*([0-9]+)\s*(?:-\s*([0-9]+)\s*)?", re.ASCII)


def seeds_from_environment(default: str = "0") -> list[int]:
    """The seeds named by ``UIOFMU_SEEDS`` (``"0,1,2"``, ``"0-9"`` or a mix), else ``default``.

    The items are separated by commas; each is a seed or an inclusive range ``LO-HI`` with
    ``LO <= HI``, of integers from 0 to :data:`MAX_SEED`, no seed named twice, and at most
    :data:`MAX_SEEDS` seeds in all. The count is taken from the ranges before any list is made, so
    a range of millions is refused at once.

    Parameters
    ----------
    default : str
        Used when the variable is unset, empty or blank.

    Returns
    -------
    list of int
        The seeds in the order named.

    Raises
    ------
    ValueError
        For a list that names no seed or is malformed: an empty item, an item that is not a seed or a
        range (a sign, a float, a letter), a range that runs backwards (``5-1``), a seed above
        :data:`MAX_SEED`, a seed named twice, or more than :data:`MAX_SEEDS` seeds; the message names
        ``UIOFMU_SEEDS``, quotes its value, says what is wrong and what is accepted.
    """
    raw = os.environ.get("UIOFMU_SEEDS", "")
    text, name = (raw.strip(), "UIOFMU_SEEDS") if raw.strip() else (default, "seeds_from_environment(default)")

    def error(problem: str) -> ValueError:
        shown = text if len(text) <= 80 else text[:77] + "..."
        return ValueError(f"{name}={shown!r}: {problem}; expected seeds and inclusive ranges LO-HI with LO <= HI, "
                          f"separated by commas (such as '0,1,2' or '0-9,20'), of integers from 0 to {MAX_SEED}, "
                          f"each seed once, at most {MAX_SEEDS} seeds in all (MAX_SEEDS)")

    if text.count(",") >= MAX_SEEDS:
        raise error(f"{text.count(',') + 1} items, more than {MAX_SEEDS} seeds")
    ranges = []
    for part in text.split(","):
        match = _SEED_ITEM.fullmatch(part)
        if match is None:
            raise error(f"{part.strip()[:40]!r} is not a seed or a range LO-HI" if part.strip() else "an empty item")
        for digits in match.groups():
            if digits is not None and (len(digits) > len(str(MAX_SEED)) or int(digits) > MAX_SEED):
                raise error(f"{digits[:24]}{'...' if len(digits) > 24 else ''} is above the largest seed {MAX_SEED}")
        lo = int(match[1])
        hi = lo if match[2] is None else int(match[2])
        if lo > hi:
            raise error(f"the range {lo}-{hi} names no seed (it runs backwards)")
        ranges.append(range(lo, hi + 1))
    count = sum(len(r) for r in ranges)
    if count > MAX_SEEDS:
        raise error(f"{count} seeds, more than {MAX_SEEDS} (each costs every test taking uiofmu_seed a run and about "
                    f"5 KB of pytest's memory)")
    spans = sorted(ranges, key=lambda r: r.start)
    for a, b in zip(spans, spans[1:]):
        if b.start < a.stop:
            raise error(f"seed {b.start} is named twice")
    return [s for r in ranges for s in r]


if pytest is not None:
    def pytest_generate_tests(metafunc):
        """Run a test that takes ``uiofmu_seed`` and does not parametrise it once per seed of ``UIOFMU_SEEDS``.

        Parameters
        ----------
        metafunc : pytest.Metafunc

        Raises
        ------
        ValueError
            For a ``UIOFMU_SEEDS`` that names no seed or is malformed (:func:`seeds_from_environment`):
            an error collecting the test, so that pytest fails instead of skipping it.
        """
        if "uiofmu_seed" not in metafunc.fixturenames or "UIOFMU_SEEDS" not in os.environ:
            return
        for mark in metafunc.definition.iter_markers("parametrize"):
            names = mark.args[0] if mark.args else mark.kwargs.get("argnames", "")
            names = [n.strip() for n in names.split(",")] if isinstance(names, str) else list(names)
            if "uiofmu_seed" in names:
                return
        metafunc.parametrize("uiofmu_seed", seeds_from_environment(), ids=lambda s: f"seed{s}")

    @pytest.fixture
    def uiofmu_seed(request):
        """The seed of a validation test: 0, or the value it is parametrised with.

        Parameters
        ----------
        request : pytest.FixtureRequest

        Returns
        -------
        int

        Raises
        ------
        ValueError
            When it is parametrised with a value that is not an integer from 0 to :data:`MAX_SEED`.
        """
        return _seed(getattr(request, "param", 0), "uiofmu_seed")

    @pytest.fixture(scope="session")
    def uiofmu_fmus(tmp_path_factory):
        """A function ``build(problem, backend=None) -> Fmus`` that designs a problem file and builds its
        observer and plant FMUs in a temporary folder, once per problem (and backend) per session.

        Parameters
        ----------
        tmp_path_factory : pytest.TempPathFactory

        Returns
        -------
        callable
        """
        cache: dict = {}

        def build(problem, backend: str | None = None) -> Fmus:
            key = (str(Path(problem).resolve()), backend)
            if key not in cache:
                cache[key] = build_fmus(problem, tmp_path_factory.mktemp("uiofmu_fmus"), backend)
            return cache[key]

        return build


__all__ = ["CONVERGENCE_TOL", "MAX_SEED", "MAX_SEEDS", "Fmus", "Run", "assert_bound_respected", "assert_converges",
           "assert_exact_functional", "assert_matches_runtime", "assert_noise_gain_respected", "build_fmus",
           "certificate_problem", "packed_card", "run_observer", "seeds_from_environment"]
