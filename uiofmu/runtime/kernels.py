"""The runtime kernels: how an observer of a design card steps, one descriptor each.

A kernel (:class:`Kernel`) names the schedule kinds it steps, checks the matrices its card carries,
declares the card's ports, and gives the runtime class (the Python reference) and the FMU model that
wraps it, and the C kernel that packs it (or why there is none). ``affine``: ``z+ = N z + L y + G u + c``,
``xhat = Xz z + Xy y`` (``+ Xu u`` where the card has ``Xu``: a plant whose known input feeds through to
``y``) with the matrices its schedule picks (:mod:`uiofmu.runtime.observer`); a card with ``dims.nf`` (a
functional observer) outputs ``zhat = Xz z + Xy y`` of ``nf`` functionals ``Lf x`` instead. ``window``:
``gx = sum_t w_t(theta) F_t [y window]`` on the last outputs (:mod:`uiofmu.runtime.window`). ``delayed``: a
continuous-time delayed UIO integrated inside the FMU (:mod:`uiofmu.runtime.delayed`).

A schedule kind (:class:`ScheduleKind`) is what a card's ``schedule.kind`` may be: its keys, the step
policies it accepts and its own checks. Every other module asks these descriptors rather than compare a
kernel's or a schedule kind's name.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from .checks import (MAX_DIM, MAX_INTERVALS, MAX_MODES, MAX_POWER, MAX_WINDOW, any_array, integer, kind_of, number,
                     table, text)
from .delayed import DelayedRuntime
from .errors import CardError
from .matrices import as_array
from .observer import Runtime
from .observer_models import DelayedModel, FunctionalModel, ObserverModel
from .ports import delayed_ports, observer_ports, window_ports
from .schedules import AXES
from .window import WindowRuntime

#: Matrices of the affine runtime and their shapes in terms of the dims (before any schedule axes).
RUNTIME_SHAPES = {
    "N": ("nz", "nz"), "L": ("nz", "p"), "G": ("nz", "m"), "c": ("nz",),
    "Xz": ("ne", "nz"), "Xy": ("ne", "p"), "C": ("p", "n"),
    "Dy": ("q", "p"), "Yx": ("p", "n"), "Yu": ("p", "m"), "Yc": ("p",), "Xu": ("ne", "m"), "Zx": ("nz", "n"),
    "Lf": ("nf", "n"),
}
def estimate_size(dims: dict) -> int:
    """The size ``ne`` of the affine kernel's estimate (the rows of ``Xz``, ``Xy``, ``Xu``): ``dims.nf`` for a
    functional observer of order below ``n`` (``zhat`` estimates ``Lf x``), else ``n`` (``xhat``; a functional
    observer of order ``n`` estimates the state, and ``zhat = Lf xhat``)."""
    return dims["nf"] if zhat_only(dims) else dims["n"]


def zhat_only(dims: dict) -> bool:
    """Whether a card's observer estimates functionals only: ``dims.nf`` with an order ``nz`` below ``n``."""
    return "nf" in dims and dims["nz"] != dims["n"]
#: Matrices every affine card has; the ``Dy, Yx, Yu, Yc`` group is present when ``dhat`` is estimated.
CORE = ("N", "L", "G", "c", "Xz", "Xy", "C")
DHAT = ("Dy", "Yx", "Yu", "Yc")


# -- schedule kinds ----------------------------------------------------------------------------
def _check_geometric(spec: dict, rtol: float) -> None:
    if "alpha" not in spec:
        raise CardError("design card schedule.alpha: required for a geometric schedule")
    number(spec["alpha"], "schedule.alpha", low=0.0, high=1.0, open_low=True, open_high=True)


def _check_continuous(spec: dict, rtol: float) -> None:
    delays = spec.get("delays")
    if not isinstance(delays, list) or not 1 <= len(delays) <= 16:
        raise CardError(f"design card schedule.delays: expected a list of 1 to 16 delays, found {kind_of(delays)}")
    values = [number(t, f"schedule.delays[{i}]", low=0.0, open_low=True) for i, t in enumerate(delays)]
    if any(b <= a for a, b in zip(values, values[1:])):
        raise CardError(f"design card schedule.delays: expected increasing delays, found {values}")
    for key in ("max_substep", "step"):
        number(spec.get(key), f"schedule.{key}", low=0.0, open_low=True)
    number(spec.get("sigma_bound"), "schedule.sigma_bound", low=0.0)
    for key in ("valid_from", "gamma_bound"):            # from the premise's start, and its largest Gamma
        if key in spec:
            number(spec[key], f"schedule.{key}", low=0.0, open_low=key == "gamma_bound")


def _check_window_schedule(spec: dict, rtol: float) -> None:
    length = integer(spec.get("length"), "schedule.length", 1, MAX_WINDOW)
    integer(spec.get("delay"), "schedule.delay", 0, length - 1)
    integer(spec.get("theta"), "schedule.theta", 0, MAX_DIM)
    if not isinstance(spec.get("uses_theta"), bool):
        raise CardError("design card schedule.uses_theta: expected true or false, found "
                        f"{kind_of(spec.get('uses_theta'))}")


def _check_mode(spec: dict, rtol: float) -> None:
    modes = integer(spec.get("modes"), "schedule.modes", 1, MAX_MODES)
    integer(spec.get("mode_prev0", 1), "schedule.mode_prev0", 1, modes)


def _check_interval(spec: dict, rtol: float) -> None:
    if "intervals" not in spec:
        raise CardError("design card schedule.intervals: required for an interval schedule")
    values = spec["intervals"]
    if not isinstance(values, list) or not 1 <= len(values) <= MAX_INTERVALS:
        raise CardError(f"design card schedule.intervals: expected a list of 1 to {MAX_INTERVALS} steps, "
                        f"found {kind_of(values)}" + (f" of {len(values)}" if isinstance(values, list) else ""))
    hs = [number(h, f"schedule.intervals[{i}]", low=0.0, open_low=True) for i, h in enumerate(values)]
    ordered = sorted(hs)
    for a, b in zip(ordered, ordered[1:]):
        if b - a <= 2 * rtol * b:
            raise CardError(f"design card schedule.intervals: {a!r} and {b!r} s are not distinct steps "
                            f"(step_rtol = {rtol:g})")
    h0 = number(spec.get("h_prev0", hs[0]), "schedule.h_prev0", low=0.0, open_low=True)
    if not any(abs(h0 - h) <= rtol * h for h in hs):
        raise CardError(f"design card schedule.h_prev0 = {h0!r} s is not one of the design intervals")


def _no_check(spec: dict, rtol: float) -> None:
    """A schedule kind with no checks beyond its keys, policy and period."""


def _period(spec: dict) -> tuple:
    """The one step of a periodic schedule: its ``dt``."""
    return (float(spec["dt"]),)


def _intervals(spec: dict) -> tuple:
    """The design intervals of an interval schedule."""
    return tuple(float(h) for h in spec["intervals"])


def _any_step(spec: dict) -> tuple:
    """Every step h > 0 (a kernel integrated inside the FMU): no step of its own."""
    return ()


@dataclass(frozen=True)
class ScheduleKind:
    """What a card's ``schedule.kind`` may be (see :mod:`uiofmu.runtime.schedules`).

    Attributes
    ----------
    name : str
        The value of ``schedule.kind``.
    keys : frozenset of str
        The keys its schedule may hold (``kind``, ``step_policy`` and ``step_rtol`` aside).
    policies : tuple of str
        The step policies it accepts (the first is the default).
    periodic : bool
        Whether its schedule holds the design period ``dt`` (equal to the card's ``dt``).
    check : callable
        ``check(spec, step_rtol)``: its own checks of the schedule's values (CardError naming the key).
    steps : callable
        ``steps(spec) -> tuple``: the step lengths a schedule of a (checked) card admits under the policy
        ``error``; empty when it admits every step h > 0 (:mod:`uiofmu.runtime.step_rules`).
    """

    name: str
    keys: frozenset
    policies: tuple
    periodic: bool
    check: Callable = _no_check
    steps: Callable = _period


#: The schedule kinds, in the order messages list them.
SCHEDULES = {s.name: s for s in (
    ScheduleKind("constant", frozenset({"dt"}), ("error",), True),
    ScheduleKind("interval", frozenset({"intervals", "h_prev0"}), ("error", "nearest"), False, _check_interval,
                 _intervals),
    ScheduleKind("geometric", frozenset({"alpha", "dt"}), ("error", "count"), True, _check_geometric),
    ScheduleKind("mode", frozenset({"dt", "modes", "mode_prev0"}), ("error",), True, _check_mode),
    ScheduleKind("window", frozenset({"dt", "length", "delay", "theta", "uses_theta"}), ("error",), True,
                 _check_window_schedule),
    ScheduleKind("continuous", frozenset({"delays", "max_substep", "sigma_bound", "step", "valid_from",
                                          "gamma_bound"}), ("error",), False, _check_continuous, _any_step),
)}


# -- the kernels' matrices ---------------------------------------------------------------------
def _check_affine(mats: dict, dims: dict, schedule: dict) -> dict:
    """Runtime matrices with their exact shapes (leading schedule axes included); every other matrix a finite
    numeric array."""
    kind = schedule["kind"]
    axes = AXES[kind]
    count = {"interval": len(schedule.get("intervals", ())), "mode": schedule.get("modes")}.get(kind)
    functional = "nf" in dims
    if "Lf" in mats and not functional:
        raise CardError("design card matrices.Lf: the functionals of a functional observer need dims.nf (their "
                        "number)")
    dims = {**dims, "ne": estimate_size(dims), "nf": dims.get("nf", 0)}
    out = {}
    for name, value in mats.items():
        key = f"design card matrices.{name}"
        text(name, "matrices key", 64)
        if name in RUNTIME_SHAPES:
            lead = (count,) * axes.get(name, 0)
            shape = lead + tuple(dims[d] for d in RUNTIME_SHAPES[name])
            arr = as_array(value, key, shape, CardError)
            if kind == "geometric" and name in axes and arr.shape[0] == 0:
                raise CardError(f"{key}: a geometric schedule needs at least one coefficient")
            out[name] = arr
        else:
            any_array(value, key)
    absent = [k for k in CORE if k not in out]
    if absent:
        raise CardError(f"design card matrices: missing {', '.join(absent)}")
    if "Xu" in out and kind != "constant":
        raise CardError(f"design card matrices.Xu: the direct term of u in xhat is for a constant schedule only, "
                        f"found a {kind} schedule")
    if "Zx" in out and kind != "constant":
        raise CardError(f"design card matrices.Zx: the first step's z_0 = Zx (xhat0 - Xy y_0) is for a constant "
                        f"schedule only, found a {kind} schedule")
    if "Zx" not in out and dims["nz"] != dims["n"]:
        raise CardError(f"design card dims.nz = {dims['nz']} differs from dims.n = {dims['n']}: the first step "
                        "sets z_0 = Zx (xhat0 - Xy y_0), and matrices.Zx is missing")
    if functional:
        _check_functional(out, dims, kind)
    partial = [k for k in DHAT if k in out]
    if partial and len(partial) != len(DHAT):
        raise CardError(f"design card matrices: dhat needs all of {', '.join(DHAT)}, found only {', '.join(partial)}")
    return out


def _check_functional(out: dict, dims: dict, kind: str) -> None:
    """A functional observer (``dims.nf``): a constant schedule, ``Lf`` and ``Zx`` (``z_0 = Zx xhat0``), and none
    of what reads ``xhat`` (``dhat``'s matrices, ``Xu``)."""
    if kind != "constant":
        raise CardError(f"design card dims.nf: a functional observer has a constant schedule, found a {kind} schedule")
    for name in ("Lf", "Zx"):
        if name not in out:
            raise CardError(f"design card matrices.{name}: required by a functional observer (dims.nf = "
                            f"{dims['nf']}): zhat_0 = Lf xhat0 and z_0 = Zx xhat0")
    extra = [k for k in (*DHAT, "Xu") if k in out]
    if extra:
        raise CardError(f"design card matrices.{extra[0]}: a functional observer (dims.nf = {dims['nf']}) estimates "
                        "no xhat, which dhat and the direct term Xu read")


def _check_window(mats: dict, dims: dict, schedule: dict) -> dict:
    """The window kernel's ``F`` (terms, d, p L) and ``Fexp`` (terms, L, s; integer powers 0..MAX_POWER)."""
    L, s = schedule["length"], schedule["theta"]
    for name in ("F", "Fexp"):
        if name not in mats:
            raise CardError(f"design card matrices.{name}: required by the window kernel")
    F = as_array(mats["F"], "design card matrices.F", (None, None, dims["p"] * L), CardError)
    if F.shape[0] == 0 or F.shape[1] == 0:
        raise CardError(f"design card matrices.F: expected at least one term and one row, found shape {F.shape}")
    exps = as_array(mats["Fexp"], "design card matrices.Fexp", (F.shape[0], L, s), CardError)
    if np.any(exps < 0) or np.any(exps > MAX_POWER) or np.any(exps != np.round(exps)):
        raise CardError(f"design card matrices.Fexp: expected integer powers from 0 to {MAX_POWER}")
    if not schedule["uses_theta"] and np.any(exps):
        raise CardError("design card matrices.Fexp: the formula uses theta but schedule.uses_theta is false")
    return {"F": F, "Fexp": exps}


def _check_delayed(mats: dict, dims: dict, schedule: dict) -> dict:
    """The delayed kernel's matrices: the plant's ``Abar, Bbar, Cbar, D0, Dy`` and the gain ``K`` of the
    augmented system (``len(delays) + 1`` copies)."""
    n, m, p = dims["n"], dims["m"], dims["p"]
    c = len(schedule["delays"]) + 1
    if dims["nz"] != n * c:
        raise CardError(f"design card dims.nz = {dims['nz']}: the delayed kernel has n (len(delays) + 1) = {n * c}")
    for name in ("Abar", "Bbar", "Cbar", "D0", "Dy", "K"):
        if name not in mats:
            raise CardError(f"design card matrices.{name}: required by the delayed kernel")
    D0 = as_array(mats["D0"], "design card matrices.D0", (n, None), CardError)
    shapes = {"Abar": (n, n), "Bbar": (n, m), "Cbar": (p, n), "D0": (n, D0.shape[1]),
              "Dy": (p, n, D0.shape[1]), "K": (n * c, p * c)}
    return {name: as_array(mats[name], f"design card matrices.{name}", shape, CardError)
            for name, shape in shapes.items()}


# -- the kernels' ports ------------------------------------------------------------------------
def _affine_ports(data: dict, matrices: dict) -> list:
    feeds_y = bool(np.any(np.asarray(matrices["Xy"]) != 0))
    feeds_u = "Xu" in matrices and bool(np.any(np.asarray(matrices["Xu"]) != 0))
    return observer_ports(data["dims"], data["schedule"]["kind"], "Dy" in matrices, feeds_y, feeds_u)


def _window_ports(data: dict, matrices: dict) -> list:
    spec = data["schedule"]
    return window_ports(data["dims"]["p"], matrices["F"].shape[1], spec["theta"] if spec["uses_theta"] else 0)


def _delayed_ports(data: dict, matrices: dict) -> list:
    d = data["dims"]
    return delayed_ports(d["n"], d["m"], d["p"], matrices["D0"].shape[1])


@dataclass(frozen=True)
class Kernel:
    """One runtime kernel.

    Attributes
    ----------
    name : str
        The value of a card's ``kernel``.
    schedules : tuple of str
        The schedule kinds (:data:`SCHEDULES`) it steps.
    matrices : tuple of str or None
        The matrices its own check reads (every other matrix of the card: any finite array); None when
        its check reads the runtime shapes (:data:`RUNTIME_SHAPES`) of the schedule's axes.
    check : callable
        ``check(matrices, dims, schedule) -> dict``: the matrices it runs on, checked (CardError).
    declare : callable
        ``declare(data, matrices) -> list of PortSpec``: the ports of a card (:mod:`uiofmu.runtime.ports`).
    runtime : type
        The Python reference runtime, built from a :class:`~uiofmu.runtime.card.Card`.
    model : type
        Its FMU model (:mod:`uiofmu.runtime.observer_models`), built from a card.
    c_kernel : str or None
        Its key in :data:`uiofmu.fmu.c_backend.C_KERNELS`; None when the C backend has none.
    python_only : str or None
        Why the C backend has no kernel for it (None when it has one).
    estimates_x : bool
        Whether it estimates the whole state (outputs ``xhat``); else a functional ``gx`` of it.
    """

    name: str
    schedules: tuple
    matrices: tuple | None
    check: Callable
    declare: Callable
    runtime: type
    model: type
    c_kernel: str | None
    python_only: str | None = None
    estimates_x: bool = True

    def steps(self, schedule_kind: str) -> bool:
        """Whether it steps a schedule of kind ``schedule_kind``."""
        return schedule_kind in self.schedules

    def check_matrices(self, mats, dims: dict, schedule: dict) -> dict:
        """A card's ``matrices`` checked: its own matrices by :attr:`check`, every other one a finite numeric array
        with a printable name (CardError naming the first that is not)."""
        mats = table(mats, "matrices")
        if self.matrices is not None:
            for name, value in mats.items():
                text(name, "matrices key", 64)
                if name not in self.matrices:
                    any_array(value, f"design card matrices.{name}")
        return self.check(mats, dims, schedule)


#: The kernels, by name (the first is a card's default).
KERNELS = {k.name: k for k in (
    Kernel("affine", ("constant", "interval", "geometric", "mode"), None, _check_affine, _affine_ports, Runtime,
           ObserverModel, "affine"),
    Kernel("window", ("window",), ("F", "Fexp"), _check_window, _window_ports, WindowRuntime, FunctionalModel,
           "window", estimates_x=False),
    Kernel("delayed", ("continuous",), ("Abar", "Bbar", "Cbar", "D0", "Dy", "K"), _check_delayed, _delayed_ports,
           DelayedRuntime, DelayedModel, "delayed"),
)}
#: The kernel of a card without a ``kernel`` key.
DEFAULT = next(iter(KERNELS))


def kernel_named(name: str) -> Kernel:
    """The kernel of a card's ``kernel`` value (a checked card's; KeyError for an unknown name)."""
    return KERNELS[name]


def card_kernel(data: dict) -> Kernel:
    """The kernel of a card document (its ``kernel``, :data:`DEFAULT` when absent)."""
    return KERNELS[data.get("kernel", DEFAULT)]


__all__ = ["CORE", "DEFAULT", "DHAT", "KERNELS", "Kernel", "RUNTIME_SHAPES", "SCHEDULES", "ScheduleKind",
           "card_kernel", "estimate_size", "kernel_named", "zhat_only"]
