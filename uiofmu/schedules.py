"""How the runtime picks its matrices at each communication step.

A schedule is the only thing that differs between families at run time; the step itself
(:mod:`uiofmu.runtime`) is the same for all. Kinds:

``constant``
    One set of matrices, designed for the period ``dt``. A step of another length follows
    ``step_policy``: ``"error"`` rejects it (the FMU answers fmi2Discard with a log line).
"""

from __future__ import annotations

from .errors import CardError
from .tolerances import STEP_RTOL

#: The policies a schedule may record for a step it was not designed for.
STEP_POLICIES = ("error",)


class StepRejected(Exception):
    """A communication step the schedule cannot take (message says what was expected)."""


def schedule_axes(spec: dict) -> dict:
    """Number of leading schedule axes of each matrix for a schedule ``spec``."""
    kind = spec.get("kind") if isinstance(spec, dict) else None
    if kind == "constant":
        return {}
    raise CardError(f"design card schedule.kind: unknown kind {kind!r} (known: constant)")


class ConstantSchedule:
    """One matrix set, designed for the period ``dt``."""

    def __init__(self, spec: dict, matrices: dict, step_rtol: float = STEP_RTOL):
        self.dt = float(spec["dt"])
        self.policy = spec.get("step_policy", "error")
        if self.policy not in STEP_POLICIES:
            raise CardError(f"design card schedule.step_policy: expected one of {STEP_POLICIES}, found {self.policy!r}")
        self.matrices = matrices
        self.step_rtol = step_rtol

    def step_matrices(self, k: int, h: float, h_prev: float) -> dict:
        """The matrices of step ``k`` of length ``h`` (raises :class:`StepRejected`)."""
        if abs(h - self.dt) > self.step_rtol * self.dt:
            raise StepRejected(f"this observer was designed for steps of dt = {self.dt!r} s and received "
                               f"h = {h!r} s (step_policy = {self.policy!r})")
        return self.matrices

    def output_matrices(self, k: int, h_prev: float) -> dict:
        """The output matrices at communication point ``k``."""
        return self.matrices

    def initial_h_prev(self) -> float:
        """The step assumed before the first one."""
        return self.dt

    def admissible_steps(self) -> list:
        """The step lengths this schedule accepts."""
        return [self.dt]


def make_schedule(spec: dict, matrices: dict):
    """The schedule object of a card's ``schedule`` entry."""
    schedule_axes(spec)
    return ConstantSchedule(spec, matrices)
