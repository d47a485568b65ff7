"""``uiofmu validate``: the static check of fmpy, then the FMU against the reference.

An observer FMU is run side by side with the reference runtime (:class:`uiofmu.runtime.observer.Runtime`)
on random inputs and a random sequence of the steps its schedule admits; a plant FMU against
the exact discretisation of its plant (scipy's matrix exponential) on random steps.

The relative difference divides by one scale for the whole run: the largest absolute
difference over every sample and every output channel, divided by
``max(1, largest |reference value| over every sample and every output channel)``. One
scale means the largest difference is judged against the size of the outputs over the run
(a difference at a sample where the outputs happen to be small is not inflated), and the
floor 1 makes outputs near zero compared absolutely.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..runtime.card import card_from_data
from ..runtime.errors import FmuError
from .fmi import Fmu, FmuCallError, read_model_json
from ..plant import Plant
from ..runtime.observer import Runtime

#: Largest accepted relative difference between an FMU and its reference.
EQUALITY_RTOL = 1e-12
#: A plant FMU uses its own matrix exponential; the reference uses scipy's.
PLANT_RTOL = 1e-9


@dataclass
class Validation:
    """The outcome of :func:`validate`.

    ``max_abs_diff`` is the largest absolute difference between FMU and reference over the
    run (every sample, every output channel); ``scale`` is ``max(1, largest |reference
    value|)`` over the same run; ``max_rel_diff = max_abs_diff / scale``, one scale for the
    whole run, is what ``tolerance`` bounds.
    """

    path: str
    kind: str
    problems: list = field(default_factory=list)
    steps: int = 0
    max_abs_diff: float = 0.0
    max_rel_diff: float = 0.0
    tolerance: float = EQUALITY_RTOL
    scale: float = 1.0

    @property
    def ok(self) -> bool:
        """No static problem and outputs within tolerance."""
        return not self.problems and self.max_rel_diff <= self.tolerance

    def to_data(self) -> dict:
        """JSON-ready form."""
        return {"path": self.path, "kind": self.kind, "problems": self.problems, "steps": self.steps,
                "max_abs_diff": self.max_abs_diff, "max_rel_diff": self.max_rel_diff, "scale": self.scale,
                "tolerance": self.tolerance, "ok": self.ok}


def _compare(report: Validation, got: np.ndarray, ref: np.ndarray) -> None:
    """Fold one sample into the run's largest difference and its one scale (see the module).

    A NaN difference counts as infinite (``max`` would drop it); the scale takes only finite
    reference values."""
    got, ref = np.asarray(got, dtype=float), np.asarray(ref, dtype=float)
    if ref.size:
        diff = np.abs(got - ref)
        report.max_abs_diff = max(report.max_abs_diff, float(np.where(np.isnan(diff), np.inf, diff).max()))
        finite = np.abs(ref[np.isfinite(ref)])
        report.scale = max(report.scale, float(finite.max()) if finite.size else 1.0)
    report.max_rel_diff = report.max_abs_diff / report.scale


def _observer(fmu: Fmu, spec: dict, report: Validation, steps: int, rng) -> None:
    card = card_from_data(spec["card"])
    rt = Runtime(card)
    choices = rt.schedule.admissible_steps()
    xhat0 = rng.normal(size=rt.n)
    rt.xhat0 = xhat0.copy()
    rt.reset()
    fmu.initialize(0.0, {"xhat0": xhat0})
    t = 0.0
    for k in range(steps + 1):
        y, u = rng.normal(size=rt.p) * 3, rng.normal(size=rt.m)
        fmu.set("y", y)
        fmu.set("u", u)
        rt.set_y(y)
        rt.set_u(u)
        if rt.modes:                                   # a switched plant's mode, at random
            mode = int(rng.integers(1, rt.modes + 1))
            fmu.set("mode", [mode])
            rt.set_mode(mode)
        got = np.concatenate([fmu.get("xhat"), fmu.get("r"), fmu.get("dhat")])
        ref = np.concatenate([rt.xhat(), rt.residual(), rt.dhat() if rt.has_dhat else []])
        _compare(report, got, ref)
        if k < steps:
            h = float(choices[int(rng.integers(len(choices)))])
            fmu.step(t, h)
            rt.step(h)
            t += h
    report.steps = steps


def _switched_plant(fmu: Fmu, data: dict, report: Validation, steps: int, rng) -> None:
    """A switched plant FMU against :class:`~uiofmu.runtime.switching.SwitchedPlantRuntime`: states,
    outputs and modes (rule ``input``: random modes set on both)."""
    from ..runtime.switching import SwitchedPlantRuntime

    ref = SwitchedPlantRuntime(data)
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


def _plant(fmu: Fmu, spec: dict, report: Validation, steps: int, rng) -> None:
    data = spec["plant"]
    if "modes" in data:
        return _switched_plant(fmu, data, report, steps, rng)
    plant = Plant.create(data["A"], data["C"], data["E"], data["B"] or None, time=data["time"],
                         dt=data.get("dt"), w=data.get("w"), x0=data["x0"])
    report.tolerance = PLANT_RTOL
    x = rng.normal(size=plant.n)
    fmu.initialize(0.0, {"x0": x})
    scale = 1.0 / max(float(np.abs(np.linalg.eigvals(plant.A)).max()), 1e-12)
    t = 0.0
    for _ in range(steps):
        u, d = rng.normal(size=plant.m), rng.normal(size=plant.q)
        fmu.set("u", u)
        fmu.set("d", d)
        _compare(report, np.concatenate([fmu.get("x"), fmu.get("y")]), np.concatenate([x, plant.C @ x]))
        h = plant.dt if not plant.continuous else float(rng.uniform(0.01, 1.0) * scale)
        s = plant.sampled(h)
        fmu.step(t, h)
        x = s.A @ x + s.B @ u + s.E @ d + s.w
        t += h
    _compare(report, fmu.get("x"), x)
    report.steps = steps


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
