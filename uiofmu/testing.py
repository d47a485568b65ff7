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
``UIOFMU_SEEDS`` (``"0,1,2"`` or ``"0-9"``) when it is set. ``uiofmu_fmus(problem)`` designs a
problem file and builds its observer and plant FMUs once per session, in a temporary folder.

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
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .runtime.card import Card, card_from_data, read_card
from .runtime.errors import CardError, FmuError

try:  # the assertions work without pytest; the fixtures need it
    import pytest
except ImportError:  # pragma: no cover - pytest is in the test extra
    pytest = None

#: The default convergence tolerance: a fraction of the initial error norm.
CONVERGENCE_TOL = 0.01


@dataclass
class Run:
    """One co-simulation made by the helpers.

    Attributes
    ----------
    result : CosimResult
        Histories and metrics (:class:`uiofmu.cosim.master.CosimResult`).
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
    from .cosim.master import default_steps, default_t_end
    from .cosim.steps import step_sequence

    if steps is None or isinstance(steps, str):
        spec = default_steps(card) if steps is None else steps
        horizon = default_t_end(card) if t_end is None else t_end
        return step_sequence(spec, horizon, seed), spec
    return np.asarray(steps, dtype=float), "given"


def _xhat0(card: Card, xhat0_error: float, seed: int):
    """The card's initial estimate plus a random offset of standard deviation ``xhat0_error`` (None for none)."""
    if not xhat0_error or card.kernel == "window":
        return None
    base = np.asarray(card.data["initial"].get("xhat0", [0.0] * card.dims["n"]), dtype=float)
    return base + xhat0_error * np.random.default_rng([seed, 1]).standard_normal(base.size)


def run_observer(observer_fmu, plant_fmu, steps=None, t_end: float | None = None, seed: int = 0,
                 xhat0_error: float = 0.0) -> Run:
    """Co-simulate an observer FMU with a plant FMU, as the assertions do.

    Parameters
    ----------
    observer_fmu, plant_fmu : str or Path
        The FMUs (the observer built by uiofmu; its card gives the inputs and the bound).
    steps : str or array_like, optional
        A step SPEC of :mod:`uiofmu.cosim.steps` (``"fixed:0.1"``, ``"dropout:600:0.3:11"``, ...)
        or the step lengths themselves; default: the steps the observer is designed for.
    t_end : float, optional
        End time for a SPEC (default: the card's horizon, :func:`uiofmu.runtime.observer.default_horizon`).
    seed : int
        Seed of a random SPEC and of the initial error.
    xhat0_error : float
        Standard deviation of a random offset (drawn from ``seed``) added to the observer's initial
        estimate; 0 keeps the card's.

    Returns
    -------
    Run

    Raises
    ------
    AssertionError
        When an FMU refuses a call during the run (the master's message), or the observer FMU is not
        an observer built by uiofmu.
    """
    from .cosim.master import cosimulate

    card = packed_card(observer_fmu)
    seq, spec = _steps(card, steps, t_end, seed)
    xhat0 = _xhat0(card, xhat0_error, seed)
    problem = certificate_problem(card)
    try:
        if problem is None:
            result = cosimulate(plant_fmu, observer_fmu, seq, xhat0=xhat0, show_progress=False)
        elif card.kernel == "affine":
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
    from .cosim.master import CosimResult, default_inputs, routes
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
        plant_inputs = list(plant.ports("input"))
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


def _limit(within, K: int) -> int:
    """``within`` as a number of steps: an int is one, a float in (0, 1] a fraction of ``K``."""
    if isinstance(within, bool) or not isinstance(within, (int, float)) or not within > 0:
        raise ValueError(f"within: expected a number of steps (int >= 1) or a fraction of the run in (0, 1], "
                         f"found {within!r}")
    if isinstance(within, float):
        if within > 1:
            raise ValueError(f"within: a fraction of the run must be in (0, 1], found {within!r}")
        return math.ceil(within * K)
    return int(within)


def _error_norms(run: Run) -> np.ndarray:
    r = run.result
    if r.functional is not None:
        f = r.functional
        err = np.linalg.norm(f["gx"] - f["true"], axis=1)
        return np.where(f["valid"] > 0.5, err, np.inf)
    return np.linalg.norm(r.x - r.xhat, axis=1)


def assert_converges(observer_fmu, plant_fmu, steps=None, t_end: float | None = None, within=1.0,
                     tol: float = CONVERGENCE_TOL, seed: int = 0, xhat0_error: float = 0.0) -> Run:
    """Assert that the estimation error falls to ``tol`` of its initial norm within a number of steps.

    The error ``||x_k - xhat_k||`` must be at most ``tol * ||x_0 - xhat_0||`` at every communication
    point from step ``within`` on (for a functional observer: ``gx`` valid and within ``tol`` of
    ``G x``, absolutely).

    Parameters
    ----------
    observer_fmu, plant_fmu : str or Path
        The FMUs.
    steps : str or array_like, optional
        A step SPEC or the step lengths (see :func:`run_observer`).
    t_end : float, optional
        End time for a SPEC.
    within : int or float
        A number of steps (int), or a fraction of the run's steps in (0, 1] (float; 1.0: by its end).
    tol : float
        The fraction of the initial error norm to fall to.
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
    AssertionError
        When the error is above the tolerance at some point after the limit: the limit, the
        tolerance, the last step above it and its error, and the largest error.
    """
    run = run_observer(observer_fmu, plant_fmu, steps, t_end, seed, xhat0_error)
    K = len(run.steps)
    limit = _limit(within, K)
    norms = _error_norms(run)
    if run.result.functional is not None:
        allowed, what = tol, f"|gx - G x| <= {tol:.3g}"
    else:
        allowed = tol * norms[0]
        what = f"||x - xhat|| <= {tol:.3g} x {norms[0]:.6g} = {allowed:.6g}"
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
    ``first_bound_violation`` of :func:`uiofmu.cosim.metrics.error_metrics`, with its round-off slack).

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
        The largest accepted ratio of the error to the bound (below 1 to demand a margin).

    Returns
    -------
    Run

    Raises
    ------
    AssertionError
        When the error leaves the bound (the first step out, the error and the bound there, the largest
        ratio), when the card certifies no bound (a delayed or functional observer), or when the card's
        certificate does not hold (its bound is then not certified; where the run leaves the claimed bound
        is said too).
    """
    run = run_observer(observer_fmu, plant_fmu, steps, t_end, seed, xhat0_error)
    m, name = run.result.metrics, _name(observer_fmu)
    if run.result.bound is None or "bound_respected" not in m:
        raise AssertionError(f"{name}: expected a card with a certified error bound; the {run.card.family} card "
                             f"(kernel {run.card.kernel}) certifies none to compare the run with"
                             + (" (use assert_exact_functional)" if run.card.kernel == "window" else ""))
    formula = run.card.data.get("bound", "the bound")
    measured = ""
    if not m["bound_respected"]:
        k = int(m["first_bound_violation"])
        measured = (f"the error leaves it at {run.where(k)}: ||x - xhat|| = {m['error_at_first_violation']:.6g} > "
                    f"bound {m['bound_at_first_violation']:.6g}; largest ratio error/bound {m['max_bound_ratio']:.6g}")
    elif m["max_bound_ratio"] > max_ratio:
        k = int(np.argmax(np.linalg.norm(run.result.x - run.result.xhat, axis=1)
                          / np.maximum(run.result.bound, 1e-300)))
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
    return run


def assert_exact_functional(observer_fmu, plant_fmu, steps=None, t_end: float | None = None, seed: int = 0,
                            rtol: float = 1e-9) -> Run:
    """Assert that a dead-beat functional observer's ``gx`` equals ``G x`` from its first full window on.

    Parameters
    ----------
    observer_fmu, plant_fmu : str or Path
        The FMUs (the observer of kernel ``window``, seed 003).
    steps : str or array_like, optional
        A step SPEC or the step lengths (default: the observer's ``dt``).
    t_end : float, optional
        End time for a SPEC.
    seed : int
        Seed of a random SPEC.
    rtol : float
        ``gx`` is exact at a point when ``|gx - G x| <= rtol * max(1, |G x|)``.

    Returns
    -------
    Run

    Raises
    ------
    AssertionError
        When the observer is not functional, ``gx_valid`` never rises, or ``gx`` differs from ``G x`` at a
        point from the first full window on (the point, both values, the difference and its allowance).
    """
    run = run_observer(observer_fmu, plant_fmu, steps, t_end, seed)
    name, f = _name(observer_fmu), run.result.functional
    if f is None:
        raise AssertionError(f"{name}: expected a functional observer (kernel window), found a {run.card.family} "
                             f"observer of kernel {run.card.kernel} (use assert_converges)")
    valid = f["valid"] > 0.5
    on = np.flatnonzero(valid)
    window = int(run.card.schedule["length"])
    if not on.size:
        raise AssertionError(f"{name}: expected gx_valid = 1 from the first full window ({window} samples) on; "
                             f"gx_valid is 0 at every one of the {len(valid)} points {run.context()}")
    err = np.linalg.norm(f["gx"] - f["true"], axis=1)
    scale = np.maximum(1.0, np.linalg.norm(np.nan_to_num(f["true"]), axis=1))
    ok = valid & (err <= rtol * scale)
    bad = np.flatnonzero(~ok[on[0]:]) + on[0]
    if bad.size:
        k = int(bad[0])
        reason = ("gx_valid falls back to 0" if not valid[k] else
                  f"gx = {np.array2string(f['gx'][k], precision=10)} but G x = "
                  f"{np.array2string(f['true'][k], precision=10)} (|gx - G x| = {err[k]:.3g}, allowed "
                  f"{rtol * scale[k]:.3g})")
        raise AssertionError(f"{name}: expected gx = G x exactly from the first full window ({run.where(int(on[0]))}) "
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
    from .cosim.validate import random_observer_run
    from .runtime.observer import Runtime

    rt = Runtime(card)
    worst, scale = 0.0, 1.0
    with Fmu(observer_fmu, "testing") as fmu:
        for k in random_observer_run(fmu, rt, steps, np.random.default_rng(seed)):
            got, ref = fmu.get("xhat"), rt.xhat()
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
        Number of random steps.
    rtol : float
        Largest accepted difference relative to ``max(1, largest |reference output|)`` over the run.
    seed : int
        Seed of the random inputs and steps.

    Raises
    ------
    AssertionError
        Naming what differs: fmpy's findings, the matrices that are not the card's, the first step
        where the outputs part and by how much, or the reference card's failed certificate check.
    """
    from .cosim.validate import validate

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
            if ref.kernel == "affine" and packed.kernel == "affine" and ref.dims == packed.dims:
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
                        experiment_steps=problem.experiment_steps)
    return Fmus(problem, card, Path(card_path), Path(observer), Path(plant))


def seeds_from_environment(default: str = "0") -> list[int]:
    """The seeds named by ``UIOFMU_SEEDS`` (``"0,1,2"``, ``"0-9"`` or a mix), else ``default``.

    Parameters
    ----------
    default : str
        Used when the variable is unset or empty.

    Returns
    -------
    list of int

    Raises
    ------
    ValueError
        For a malformed list, quoting it.
    """
    text = os.environ.get("UIOFMU_SEEDS", "").strip() or default
    out = []
    try:
        for part in text.split(","):
            lo, dash, hi = part.strip().partition("-")
            out.extend(range(int(lo), int(hi) + 1) if dash else [int(lo)])
    except ValueError:
        raise ValueError(f"UIOFMU_SEEDS: expected seeds like '0,1,2' or '0-9', found {text!r}") from None
    return out


if pytest is not None:
    def pytest_generate_tests(metafunc):
        """Run a test that takes ``uiofmu_seed`` and does not parametrise it once per seed of ``UIOFMU_SEEDS``.

        Parameters
        ----------
        metafunc : pytest.Metafunc
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
        """
        return int(getattr(request, "param", 0))

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


__all__ = ["CONVERGENCE_TOL", "Fmus", "Run", "assert_bound_respected", "assert_converges", "assert_exact_functional",
           "assert_matches_runtime", "build_fmus", "certificate_problem", "packed_card", "run_observer",
           "seeds_from_environment"]
