"""Which communication steps an FMU takes, as its FMI wrapping sees them (numpy-free; both backends).

The model decides a step it was designed for (:func:`uiofmu.runtime.schedules.matches`); around it, every
FMU of uiofmu applies the same :class:`StepRule`, from its ``model.json`` alone:

- ``canHandleVariableCommunicationStepSize`` is true only where more than one step length is admissible
  (:attr:`StepRule.variable`): a schedule of several design intervals, a policy that takes any step
  (``nearest``, ``count``), a kernel or plant integrated inside the FMU; a schedule of one period under the
  policy ``error`` and a discrete plant declare false;
- a step within :data:`~uiofmu.runtime.tolerances.STEP_ULPS` units in the last place of the current time t of
  an admissible step H is that step, where those ulps are at most :data:`~uiofmu.runtime.tolerances.STEP_ULPS_LIMIT`
  of H (:meth:`StepRule.take`; within STEP_RTOL of it, the model itself decides so);
- a step of at most :data:`~uiofmu.runtime.tolerances.TINY_STEP_RTOL` of the smallest admissible step is
  rounding (OMSimulator closes the gap to its stop time with h = 1.4e-12 s): it is accepted and leaves the state
  unchanged. A model that takes every step h > 0 has no such threshold: it takes a short step as any other.

The C backend compiles the same rule into its FMU (``UiofmuSteps`` in ``c/fmi2_plumbing.h``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .kernels import SCHEDULES, card_kernel
from .plant_kinds import PLANT_FMU, fmu_kind
from .schedules import ANY_STEP_POLICIES
from .tolerances import STEP_ULPS, STEP_ULPS_LIMIT, TINY_STEP_RTOL


@dataclass(frozen=True)
class StepRule:
    """The steps an FMU takes.

    Attributes
    ----------
    steps : tuple of float
        The admissible step lengths; empty when every step h > 0 is.
    variable : bool
        Whether more than one step length is admissible (``canHandleVariableCommunicationStepSize``).
    """

    steps: tuple
    variable: bool

    @property
    def tiny(self) -> float:
        """The longest step that is rounding (accepted, the state unchanged): :data:`TINY_STEP_RTOL` of the
        smallest admissible step; 0.0 when every step is admissible."""
        return TINY_STEP_RTOL * min(self.steps) if self.steps else 0.0

    def take(self, t: float, h: float):
        """The step the model takes for a master's step ``h`` from ``t``.

        Parameters
        ----------
        t : float
            The current communication point.
        h : float
            The master's step.

        Returns
        -------
        float or None
            None for a step of at most :attr:`tiny` (h > 0: accepted, nothing to compute); the admissible step H
            that ``h`` is within :data:`STEP_ULPS` ulps of ``t`` of (when those are at most :data:`STEP_ULPS_LIMIT`
            of H); else ``h`` itself (the model decides).
        """
        if 0.0 < h <= self.tiny:
            return None
        if self.steps and math.isfinite(t) and math.isfinite(h):
            slack = STEP_ULPS * math.ulp(abs(t))
            for H in self.steps:
                if abs(h - H) <= slack <= STEP_ULPS_LIMIT * H:
                    return H
        return h


def _rule(steps: tuple, any_length: bool) -> StepRule:
    return StepRule(tuple(steps), any_length or len(steps) != 1)


def step_rule(spec: dict) -> StepRule:
    """The :class:`StepRule` of an FMU's ``model.json`` (a checked card's or plant's).

    An observer's from its schedule kind (:attr:`uiofmu.runtime.kernels.ScheduleKind.steps`) and step policy; a
    plant's from its kind (:attr:`uiofmu.runtime.plant_kinds.PlantKind.steps`).
    """
    kind = fmu_kind(spec)
    if kind is None:
        card = spec["card"]
        card_kernel(card)                                  # a card of a known kernel
        schedule = card["schedule"]
        steps = SCHEDULES[schedule["kind"]].steps(schedule)
        return _rule(steps, not steps or schedule.get("step_policy", "error") in ANY_STEP_POLICIES)
    data = spec["plant"] if kind.fmu_kind == PLANT_FMU else spec[kind.key]
    steps = kind.steps(data)
    return _rule(steps, not steps)


__all__ = ["StepRule", "step_rule"]
