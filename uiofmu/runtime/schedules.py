"""How the runtime picks its matrices at each communication step.

A schedule is the only thing that differs between families at run time; the step itself
(:mod:`uiofmu.runtime.observer`) is the same for all. Kinds:

``constant``
    One set of matrices, designed for the period ``dt``. A step of another length follows
    ``step_policy``: ``"error"`` rejects it (the FMU answers fmi2Discard with a log line).
``interval``
    Matrices per pair (h_k, h_{k-1}) of design intervals (designs for a set of intervals): the step
    matrices ``N, L`` are indexed ``[i][j]``, ``G, c, Yx, Yu, Yc`` by ``[i]`` (the step
    taken), the output matrices ``Xz, Xy, Dy`` by ``[j]`` (the step before). A step h
    matches the interval H when ``|h - H| <= STEP_RTOL * H``; another step follows
    ``step_policy``: ``"error"`` rejects it, ``"nearest"`` uses the nearest interval (and
    leaves one notice, logged once by the FMU).
``mode``
    Matrices per pair (alpha_k, alpha_{k-1}) of modes of a switched plant (1..N), designed for
    the period ``dt``: indexed as for ``interval``, with ``i = alpha_k - 1`` (the mode of the step
    taken) and ``j = alpha_{k-1} - 1`` (the mode of the step before; ``mode_prev0`` at k = 0).
    A mode outside 1..N is refused (:class:`ModeRejected`), a step other than ``dt`` too.
``window``
    The window kernel's formula (:mod:`uiofmu.runtime.window`), designed for the period ``dt``: as
    ``constant`` for the steps it admits.
``continuous``
    A continuous-time kernel integrated inside the FMU (:mod:`uiofmu.runtime.delayed`): any step
    ``h > 0``; ``step`` is the default communication step.
``geometric``
    Matrices polynomial in ``a = alpha^k`` (the asymptotic-decoupling family): every matrix
    has a leading axis of coefficients, ``M(a) = M[0] + a M[1] + a^2 M[2] + ...``, evaluated
    with ``a = alpha**k`` computed afresh at each step (no drift; it underflows to exactly 0).
    A step other than ``dt`` follows ``step_policy``: ``"error"`` rejects it, ``"count"``
    (explicit opt-in) takes it as one step k whatever its length.

Every schedule answers ``step_matrices(k, h, h_prev, mode=None, mode_prev=None, theta=None)`` and
``output_matrices(k, h_prev, mode_prev=None, theta=None)``: the step counter, the step length, the
step before, and the scheduling inputs when the kernel has them (``mode``: the known mode of a
switched plant over the step, ``mode_prev`` the one of the step before; ``theta``: the window of
parameter values of an LPV plant, newest last). Only ``mode`` schedules read the modes.
"""

from __future__ import annotations

import numpy as np

from .errors import CardError
from .refusals import refusal
from .tolerances import STEP_RTOL

#: The policies a schedule may record for a step it was not designed for.
STEP_POLICIES = ("error", "nearest", "count")
#: The policies under which a schedule takes steps of any length (the nearest design interval; one step k).
ANY_STEP_POLICIES = ("nearest", "count")

#: Leading schedule axes of each matrix, per schedule kind.
AXES = {
    "constant": {},
    "interval": {"N": 2, "L": 2, "G": 1, "c": 1, "Yx": 1, "Yu": 1, "Yc": 1, "Xz": 1, "Xy": 1, "Dy": 1},
    "mode": {"N": 2, "L": 2, "G": 1, "c": 1, "Yx": 1, "Yu": 1, "Yc": 1, "Xz": 1, "Xy": 1, "Dy": 1},
    "window": {},
    "continuous": {},
    "geometric": {k: 1 for k in ("N", "L", "G", "c", "Yx", "Yu", "Yc", "Xz", "Xy", "Dy")},
}


class StepRejected(Exception):
    """A communication step the schedule cannot take (message says what was expected)."""


def mode_problem(mode, modes: int, what: str, whose: str) -> str | None:
    """Why ``mode`` is not one of ``modes`` modes (1..N), or None: the one check of a mode, for the
    observer's schedule and the switched plant alike (``what`` names the value, ``whose`` the plant)."""
    if isinstance(mode, (bool, np.bool_)) or not isinstance(mode, (int, np.integer)) or not 1 <= mode <= modes:
        return f"{what} = {mode!r} is not a mode of {whose} (expected an integer from 1 to {modes})"
    return None


class ModeRejected(ValueError):
    """A mode that is not one of the design's (an input error: the message names the mode and the range)."""


def schedule_axes(spec: dict) -> dict:
    """Number of leading schedule axes of each matrix for a schedule ``spec``."""
    kind = spec.get("kind") if isinstance(spec, dict) else None
    if kind not in AXES:
        raise CardError(f"design card schedule.kind: unknown kind {kind!r} (known: {', '.join(AXES)})")
    return AXES[kind]


def _policy(spec: dict) -> str:
    policy = spec.get("step_policy", "error")
    if policy not in STEP_POLICIES:
        raise CardError(f"design card schedule.step_policy: expected one of {STEP_POLICIES}, found {policy!r}")
    return policy


class ConstantSchedule:
    """One matrix set, designed for the period ``dt``."""

    def __init__(self, spec: dict, matrices: dict, step_rtol: float = STEP_RTOL):
        self.dt = float(spec["dt"])
        self.policy = _policy(spec)
        if self.policy != "error":
            raise CardError("design card schedule.step_policy: a constant schedule accepts only 'error'")
        self.matrices = matrices
        self.notices: list[str] = []
        self.step_rtol = step_rtol

    def step_matrices(self, k: int, h: float, h_prev: float, mode=None, mode_prev=None, theta=None) -> dict:
        """The matrices of step ``k`` of length ``h`` (raises :class:`StepRejected`)."""
        _period(self, h)
        return self.matrices

    def output_matrices(self, k: int, h_prev: float, mode_prev=None, theta=None) -> dict:
        """The output matrices at communication point ``k``."""
        return self.matrices

    def initial_h_prev(self) -> float:
        """The step assumed before the first one."""
        return self.dt

    def admissible_steps(self) -> list:
        """The step lengths this schedule accepts."""
        return [self.dt]


def pair_tables(matrices: dict, N: int, what: str) -> tuple[list, list]:
    """The step matrices ``[i][j]`` and the output matrices ``[j]`` of a schedule on pairs of
    indices (interval and mode schedules: :data:`AXES`), checked for ``N`` entries per axis."""
    axes = AXES["interval"]
    for name, value in matrices.items():
        if name in axes and value.shape[0] != N or (axes.get(name) == 2 and value.shape[1] != N):
            raise CardError(f"design card matrices.{name}: expected {N} entries per schedule axis "
                            f"for {N} {what}, found shape {value.shape}")
    fixed = {k: v for k, v in matrices.items() if k not in axes}
    out = [{**fixed, **{k: matrices[k][j] for k in ("Xz", "Xy", "Dy") if k in matrices}} for j in range(N)]
    step = [[{**fixed, **{k: matrices[k][i][j] for k in ("N", "L")},
              **{k: matrices[k][i] for k in ("G", "c", "Yx", "Yu", "Yc") if k in matrices}}
             for j in range(N)] for i in range(N)]
    return step, out


def matches(h: float, H: float, rtol: float) -> bool:
    """Whether the step ``h`` is the design step ``H``: ``|h - H| <= rtol * H`` (the one rule of every
    schedule, and of the check of a campaign's steps axis; a NaN matches nothing)."""
    return abs(h - H) <= rtol * H


def _period(schedule, h: float) -> None:
    """Refuse a step other than the schedule's period ``dt`` (:class:`StepRejected`)."""
    if not matches(h, schedule.dt, schedule.step_rtol):
        raise StepRejected(refusal("observer_off_period", dt=schedule.dt, h=h, policy=schedule.policy))


class IntervalSchedule:
    """Matrices per pair of design intervals (h_k, h_{k-1})."""

    def __init__(self, spec: dict, matrices: dict, step_rtol: float = STEP_RTOL):
        self.intervals = [float(h) for h in spec["intervals"]]
        self.policy = _policy(spec)
        self.h_prev0 = float(spec.get("h_prev0", self.intervals[0]))
        self.step_rtol = step_rtol
        self.notices: list[str] = []
        self._noticed = False
        self._step, self._out = pair_tables(matrices, len(self.intervals), "intervals")

    def index(self, h: float) -> int:
        """Index of the design interval of the step ``h`` (raises :class:`StepRejected`)."""
        best = min(range(len(self.intervals)), key=lambda i: abs(h - self.intervals[i]))
        H = self.intervals[best]
        if matches(h, H, self.step_rtol):
            return best
        listed = ", ".join(f"{v:g}" for v in self.intervals)
        if self.policy == "nearest":
            if not self._noticed:
                self._noticed = True
                self.notices.append(f"step h = {h!r} s is not a design interval ({listed} s); using the nearest, "
                                    f"{H:g} s, without a certificate (step_policy = 'nearest'; noted once)")
            return best
        raise StepRejected(refusal("not_a_design_interval", h=h, listed=listed, rtol=self.step_rtol))

    def step_matrices(self, k: int, h: float, h_prev: float, mode=None, mode_prev=None, theta=None) -> dict:
        """The matrices of the step (h_k, h_{k-1})."""
        return self._step[self.index(h)][self.index(h_prev)]

    def output_matrices(self, k: int, h_prev: float, mode_prev=None, theta=None) -> dict:
        """The output matrices after a step h_{k-1}."""
        return self._out[self.index(h_prev)]

    def initial_h_prev(self) -> float:
        """h_{-1}, the interval assumed before the first step."""
        return self.h_prev0

    def admissible_steps(self) -> list:
        """The design intervals."""
        return list(self.intervals)


class GeometricSchedule:
    """Matrices polynomial in ``a = alpha^k``, designed for the period ``dt``."""

    def __init__(self, spec: dict, matrices: dict, step_rtol: float = STEP_RTOL):
        self.alpha = float(spec["alpha"])
        self.dt = float(spec["dt"])
        self.policy = _policy(spec)
        if self.policy == "nearest":
            raise CardError("design card schedule.step_policy: a geometric schedule accepts 'error' or 'count'")
        self.step_rtol = step_rtol
        self.notices: list[str] = []
        axes = AXES["geometric"]
        self.coeffs = {k: v for k, v in matrices.items() if k in axes}
        self._buf = {k: np.empty(v.shape[1:]) for k, v in self.coeffs.items()}
        self._buf.update({k: v for k, v in matrices.items() if k not in axes})
        self._k = None

    def a(self, k: int) -> float:
        """``alpha**k``, exact for every k (0.0 once it underflows)."""
        return self.alpha ** k

    def _evaluate(self, k: int) -> dict:
        if self._k != k:
            a = self.a(k)
            for name, c in self.coeffs.items():
                out = self._buf[name]
                out[...] = c[-1]
                for j in range(len(c) - 2, -1, -1):     # Horner
                    out *= a
                    out += c[j]
            self._k = k
        return self._buf

    def step_matrices(self, k: int, h: float, h_prev: float, mode=None, mode_prev=None, theta=None) -> dict:
        """The matrices of step k (raises :class:`StepRejected` for a step other than dt)."""
        if self.policy == "error":
            _period(self, h)
        return self._evaluate(k)

    def output_matrices(self, k: int, h_prev: float, mode_prev=None, theta=None) -> dict:
        """The output matrices at communication point k."""
        return self._evaluate(k)

    def initial_h_prev(self) -> float:
        """The step assumed before the first one."""
        return self.dt

    def admissible_steps(self) -> list:
        """The design period."""
        return [self.dt]


class ContinuousSchedule:
    """A continuous-time kernel: every step is admissible; ``step`` is the default one."""

    def __init__(self, spec: dict, matrices: dict, step_rtol: float = STEP_RTOL):
        self.dt = float(spec["step"])
        self.policy = _policy(spec)
        self.notices: list[str] = []

    def initial_h_prev(self) -> float:
        """The default step."""
        return self.dt

    def admissible_steps(self) -> list:
        """The default communication step (any other is admissible too)."""
        return [self.dt]


class ModeSchedule:
    """Matrices per pair of modes (alpha_k, alpha_{k-1}) of a switched plant, period ``dt``."""

    def __init__(self, spec: dict, matrices: dict, step_rtol: float = STEP_RTOL):
        self.dt = float(spec["dt"])
        self.modes = int(spec["modes"])
        self.mode_prev0 = int(spec.get("mode_prev0", 1))
        self.policy = _policy(spec)
        if self.policy != "error":
            raise CardError("design card schedule.step_policy: a mode schedule accepts only 'error'")
        self.step_rtol = step_rtol
        self.notices: list[str] = []
        self._step, self._out = pair_tables(matrices, self.modes, "modes")

    def index(self, mode, what: str = "mode") -> int:
        """``mode - 1`` for a mode 1..N (raises :class:`ModeRejected` naming the mode and the range)."""
        problem = mode_problem(mode, self.modes, what, "this observer's plant")
        if problem:
            raise ModeRejected(problem)
        return int(mode) - 1

    def step_matrices(self, k: int, h: float, h_prev: float, mode=None, mode_prev=None, theta=None) -> dict:
        """The matrices of the step in mode ``mode`` after one in ``mode_prev``."""
        i, j = self.index(mode), self.index(mode_prev, "mode_prev")
        _period(self, h)
        return self._step[i][j]

    def output_matrices(self, k: int, h_prev: float, mode_prev=None, theta=None) -> dict:
        """The output matrices after a step in mode ``mode_prev``."""
        return self._out[self.index(mode_prev, "mode_prev")]

    def initial_h_prev(self) -> float:
        """The step assumed before the first one."""
        return self.dt

    def admissible_steps(self) -> list:
        """The design period."""
        return [self.dt]


SCHEDULES = {"constant": ConstantSchedule, "interval": IntervalSchedule, "geometric": GeometricSchedule,
             "mode": ModeSchedule, "window": ConstantSchedule, "continuous": ContinuousSchedule}


def make_schedule(spec: dict, matrices: dict):
    """The schedule object of a card's ``schedule`` entry."""
    schedule_axes(spec)
    return SCHEDULES[spec["kind"]](spec, matrices)


def takes_steps(schedule, low: float, high: float) -> bool:
    """Whether ``schedule`` takes every step from ``low`` to ``high`` s: a continuous kernel and the
    policies ``nearest`` and ``count`` take any step; the others only those that :func:`matches` one of
    :meth:`admissible_steps` (as :func:`_period` and ``IntervalSchedule.index`` decide)."""
    if isinstance(schedule, ContinuousSchedule) or schedule.policy in ANY_STEP_POLICIES:
        return True
    return any(matches(low, H, schedule.step_rtol) and matches(high, H, schedule.step_rtol)
               for H in schedule.admissible_steps())
