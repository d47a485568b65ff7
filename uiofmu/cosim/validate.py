"""``uiofmu validate``: the static check of fmpy, then the FMU against the reference.

An observer FMU is run side by side with the reference runtime (:class:`uiofmu.runtime.observer.Runtime`)
on random inputs and a random sequence of the steps its schedule admits; a functional observer
(window kernel) against :class:`uiofmu.runtime.window.WindowRuntime` on random outputs and scheduling
values; a delayed observer (seed 001) against :class:`uiofmu.runtime.delayed.DelayedRuntime` on smooth
``y``, ``ydot``, ``u`` from a simulated plant with its design matrices and random aperiodic steps; a plant
FMU against the exact discretisation of its plant (scipy's matrix exponential) on random steps, a
switched one against :class:`uiofmu.runtime.switching.SwitchedPlantRuntime`, an LPV one against
:class:`uiofmu.runtime.lpv.LpvPlantRuntime` and one with unknown parameters against
:class:`uiofmu.runtime.parametric_plant.ParametricPlantRuntime`.

The relative difference divides by one scale for the whole run: the largest absolute
difference over every sample and every output channel, divided by
``max(1, largest |reference value| over every sample and every output channel)``. One
scale means the largest difference is judged against the size of the outputs over the run
(a difference at a sample where the outputs happen to be small is not inflated), and the
floor 1 makes outputs near zero compared absolutely.
"""

from __future__ import annotations

import numpy as np

from ..plant import Plant
from ..runtime.card import card_from_data
from ..runtime.errors import CardError, FmuError
from ..runtime.plant_kinds import data_kind
from .comparison import EQUALITY_RTOL, Validation, compare as _compare
from .fmi import Fmu, FmuCallError, check_archive, read_model_json
from .kernels import cosim_kernel, random_observer_run

#: A plant FMU uses its own matrix exponential; the reference uses scipy's.
PLANT_RTOL = 1e-9


def _observer(fmu: Fmu, spec: dict, report: Validation, steps: int, rng) -> None:
    from ..synthesis import recheck

    card = card_from_data(spec["card"])
    try:
        recheck(card)                       # an FMU from someone else: does its card prove what it claims?
    except CardError as exc:
        report.problems.append(f"its design card does not re-check: {exc}")
    cosim_kernel(card).validate(fmu, card, report, steps, rng)


def _switched_plant(fmu: Fmu, data: dict, report: Validation, steps: int, rng) -> None:
    """A switched plant FMU against :class:`~uiofmu.runtime.switching.SwitchedPlantRuntime`: states,
    outputs and modes (rule ``input``: random modes set on both)."""
    from ..runtime.switching import SwitchedPlantRuntime

    ref = SwitchedPlantRuntime(data)
    report.tolerance = PLANT_RTOL            # a C plant sums in its own order: round-off, amplified by the modes
    ref.x0 = rng.normal(size=ref.n)
    ref.reset()
    fmu.initialize(0.0, {"x0": ref.x0})
    t = 0.0
    for _ in range(steps):
        ref.u[:], ref.d[:] = 0.1 * rng.normal(size=ref.m), 0.1 * rng.normal(size=ref.q)
        fmu.set("u", ref.u)
        fmu.set("d", ref.d)
        if ref.rule == "input":
            ref.mode_in = int(rng.integers(1, ref.N + 1))
            fmu.set("mode", [ref.mode_in])
        _compare(report, np.concatenate([fmu.get("x"), fmu.get("y"), fmu.get("mode")]),
                 np.concatenate([ref.x, ref.y(), [ref.mode()]]))
        fmu.step(t, ref.dt)
        ref.step(ref.dt)
        t += ref.dt
    _compare(report, fmu.get("x"), ref.x)
    report.steps = steps


#: An LPV plant's validation restarts from a new initial state once its state leaves this bound.
LPV_BOUND = 1e3


def _lpv_plant(fmu: Fmu, data: dict, report: Validation, steps: int, rng) -> None:
    """An LPV plant FMU against :class:`~uiofmu.runtime.lpv.LpvPlantRuntime`: states, outputs and theta,
    with random unknown inputs and (kind ``input``) random scheduling values.

    An LPV plant may be unstable, and with theta from the state it is a nonlinear system that can
    leave every bound in a few steps (the paper's (17)): the run is cut into episodes, each from a
    small random initial state (fmi2Reset, then a new ``x0``), and an episode ends once the
    reference's state leaves :data:`LPV_BOUND`. The reference is the FMU's own arithmetic for a
    pythonfmu FMU; a C FMU may differ by round-off, hence the plant tolerance."""
    from ..runtime.lpv import LpvPlantRuntime

    ref = LpvPlantRuntime(data)
    report.tolerance = PLANT_RTOL
    done, first = 0, True
    while done < steps:
        if not first:
            fmu.reset()
        first = False
        ref.x0 = 0.1 * rng.normal(size=ref.n)
        ref.reset()
        fmu.initialize(0.0, {"x0": ref.x0})
        t = 0.0
        while done < steps:
            ref.d[:] = 0.1 * rng.normal(size=ref.q)
            fmu.set("d", ref.d)
            if ref.kind == "input":
                ref.theta_in[:] = rng.uniform(-1.0, 1.0, size=ref.s)
                fmu.set("theta", ref.theta_in)
            _compare(report, np.concatenate([fmu.get("x"), fmu.get("y"), fmu.get("theta")]),
                     np.concatenate([ref.x, ref.y(), ref.theta()]))
            fmu.step(t, ref.dt)
            ref.step(ref.dt)
            t += ref.dt
            done += 1
            if not np.abs(ref.x).max() <= LPV_BOUND:
                break
        _compare(report, fmu.get("x"), ref.x)
    report.steps = steps


def _parametric_plant(fmu: Fmu, data: dict, report: Validation, steps: int, rng) -> None:
    """A plant FMU with unknown parameters against :class:`~uiofmu.runtime.parametric_plant.ParametricPlantRuntime`:
    ``x``, ``y`` and ``ydot`` at every point, from a random ``x0`` and a random ``theta`` (0.5 to 1.5 times
    the plant's, set as the FMU's parameter), with random inputs held over random steps (0.2 to 2 times
    ten substeps)."""
    from ..runtime.parametric_plant import ParametricPlantRuntime

    ref = ParametricPlantRuntime(data)
    ref.x0 = 0.1 * rng.normal(size=ref.n)
    ref.params[:] = ref.theta0 * rng.uniform(0.5, 1.5, size=ref.params.size)
    ref.apply_parameters()                  # the substep of these parameters, as the FMU takes them
    ref.reset()
    fmu.initialize(0.0, {"x0": ref.x0, "theta": ref.params})
    t = 0.0
    for _ in range(steps):
        ref.u[:] = rng.normal(size=ref.m)
        fmu.set("u", ref.u)
        _compare(report, np.concatenate([fmu.get("x"), fmu.get("y"), fmu.get("ydot")]),
                 np.concatenate([ref.x, ref.y(), ref.ydot()]))
        h = float(rng.uniform(0.2, 2.0) * 10 * ref.substep)
        fmu.step(t, h)
        ref.step(h)
        t += h
    _compare(report, fmu.get("x"), ref.x)
    report.steps = steps


def _linear_plant(fmu: Fmu, data: dict, report: Validation, steps: int, rng) -> None:
    """A linear plant FMU against the exact discretisation of its plant (scipy's matrix exponential), on random
    inputs and (for a continuous plant) random steps."""
    plant = Plant.create(data["A"], data["C"], data["E"], data["B"] or None, time=data["time"],
                         dt=data.get("dt"), w=data.get("w"), x0=data["x0"], D=data.get("D"), F=data.get("F"))
    report.tolerance = PLANT_RTOL
    x = rng.normal(size=plant.n)
    fmu.initialize(0.0, {"x0": x})
    scale = 1.0 / max(float(np.abs(np.linalg.eigvals(plant.A)).max()), 1e-12)
    t = 0.0
    for _ in range(steps):
        u, d = rng.normal(size=plant.m), rng.normal(size=plant.q)
        fmu.set("u", u)
        fmu.set("d", d)
        y = plant.C @ x + plant.D @ u + plant.F @ d
        _compare(report, np.concatenate([fmu.get("x"), fmu.get("y")]), np.concatenate([x, y]))
        h = plant.dt if not plant.continuous else float(rng.uniform(0.01, 1.0) * scale)
        s = plant.sampled(h)
        fmu.step(t, h)
        x = s.A @ x + s.B @ u + s.E @ d + s.w
        t += h
    _compare(report, fmu.get("x"), x)
    report.steps = steps


#: The validation driver of each kind of plant FMU whose data is ``model.json``'s ``plant``
#: (:data:`uiofmu.runtime.plant_kinds.PLANT_KINDS`).
PLANT_DRIVERS = {"linear": _linear_plant, "switched": _switched_plant, "lpv": _lpv_plant,
                 "parametric": _parametric_plant}


def _plant(fmu: Fmu, spec: dict, report: Validation, steps: int, rng) -> None:
    data = spec["plant"]
    PLANT_DRIVERS[data_kind(data).name](fmu, data, report, steps, rng)


def _mujoco(fmu: Fmu, spec: dict, report: Validation, steps: int, rng) -> None:
    """A MuJoCo plant FMU against MuJoCo driven directly with the same steps (identical)."""
    from pathlib import Path

    from ..runtime.mujoco_runtime import MujocoRuntime

    ref = MujocoRuntime(spec["mujoco"], Path(fmu.resources))
    report.tolerance = 0.0
    x0 = ref.x0 + rng.normal(size=ref.n) * 0.01
    ref.x0 = x0.copy()
    ref.reset()
    fmu.initialize(0.0, {"x0": x0})
    t = 0.0
    for _ in range(steps):
        u, d = rng.normal(size=ref.m) * 100, rng.normal(size=ref.q) * 100
        fmu.set("u", u)
        fmu.set("d", d)
        ref.u[:], ref.d[:] = u, d
        h = float(rng.uniform(0.2, 20.0) * ref.dt)
        fmu.step(t, h)
        ref.step(h)
        t += h
        _compare(report, np.concatenate([fmu.get("x"), fmu.get("y")]), np.concatenate([ref.x, ref.y()]))
    report.steps = steps


def validate(path, steps: int = 200, seed: int = 0) -> Validation:
    """Validate an FMU built by uiofmu.

    Parameters
    ----------
    path : str or Path
        The FMU.
    steps : int
        Length of the random step sequence.
    seed : int
        Seed of the random inputs and steps.

    Returns
    -------
    Validation
        ``problems`` lists what fmpy's ``validate_fmu`` found and any refused call;
        ``max_rel_diff`` is the run's largest absolute difference divided by one scale for the
        whole run, ``max(1, largest |reference value|)`` over every sample and channel.
    """
    from fmpy.validation import validate_fmu

    spec = read_model_json(path)
    kinds = {"observer": ("card", _observer), "plant": ("plant", _plant), "mujoco": ("mujoco", _mujoco)}
    kind = spec.get("kind")
    if not isinstance(kind, str) or kind not in kinds or kinds[kind][0] not in spec:
        raise FmuError(f"{path}: resources/model.json is not a uiofmu model (kind {repr(kind)[:40]}; expected one of "
                       f"{', '.join(kinds)} with its {'/'.join(k for k, _ in kinds.values())} entry)")
    report = Validation(str(path), kind)
    check_archive(path, own=True)            # fmpy parses every name with a grammar: bounded first
    report.problems = list(validate_fmu(str(path)))
    if report.problems:
        return report
    rng = np.random.default_rng(seed)
    with Fmu(path, "validation") as fmu:
        try:
            kinds[kind][1](fmu, spec, report, steps, rng)
        except FmuCallError as exc:
            report.problems.append(f"{exc} ({'; '.join(exc.messages)})")
    return report


__all__ = ["EQUALITY_RTOL", "PLANT_RTOL", "Validation", "random_observer_run", "validate"]
