"""The co-simulation side of the runtime kernels (:mod:`uiofmu.runtime.kernels`), one descriptor each: what a
run of an observer of the kernel records and measures, and how ``uiofmu validate`` drives its FMU against the
kernel's reference runtime.

A run records every output the observer declares, by name (``H``: one column block per output port); the
kernel's :attr:`CosimKernel.result` turns them, with the plant's ``x``, ``y``, ``u``, ``d``, into a
:class:`~uiofmu.cosim.result.CosimResult` and its metrics. The other modules of the co-simulation ask these
descriptors rather than compare a kernel's name.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..certificate import overshoot_text
from ..families import certified_bound
from ..runtime.delayed import DelayedRuntime
from ..runtime.observer import Runtime
from ..runtime.parametric_plant import ParametricPlantRuntime
from ..runtime.window import WindowRuntime
from .comparison import Validation, compare
from .fmi import Fmu
from .result import CosimResult, run_result
from .roundoff import roundoff_floor


# -- the results of a run ----------------------------------------------------------------------
def _affine_result(card, T, steps, X, Y, U, D, H, MODE, theta_true) -> CosimResult:
    """The run of an affine-kernel observer: the state error metrics, the certified bound where the card has
    one (:func:`uiofmu.families.certified_bound`), and the modes of a switched plant. A run whose error leaves
    the bound plus the fixed floor is checked again with the floor round-off carries
    (:func:`~uiofmu.cosim.roundoff.roundoff_floor`, in ``metrics["roundoff_floor"]``)."""
    if "zhat" in H:
        return _zhat_result(card, T, steps, X, Y, U, D, H, MODE)
    XH, R = H["xhat"], H["r"]
    DH = H.get("dhat", np.zeros((len(T), 0)))
    bound = certified_bound(card, X[0] - XH[0], D)
    text = None
    if bound is not None:
        text = card.data.get("bound", "")
        if card.data.get("overshoot_bound") is not None:
            text = (text.replace("overshoot_bound", overshoot_text(card.data))
                    .replace("decay_bound**k", f"{card.data['decay_bound']:.6g}^k"))

    def checked(leaks):
        return run_result(T, steps, X, XH, Y, U, D, R, DH, card=card, mode=MODE, bound=bound,
                          decay=card.data.get("decay_bound"), overshoot=card.data.get("overshoot_bound"),
                          bound_text=text, roundoff=leaks)

    result = checked(None)
    if result.metrics.get("bound_respected") is False:      # the fixed floor does not pass it: its leaks, carried
        leaks = roundoff_floor(card, steps, X, XH, Y, U, D, MODE)
        if leaks is not None:
            result = checked(leaks)
    return result


def _zhat_result(card, T, steps, X, Y, U, D, H, MODE) -> CosimResult:
    """The run of a functional affine observer (``dims.nf``): ``zhat`` against ``Lf x`` of the plant's state (the
    result's ``x`` and ``xhat``), with the certified bound ``overshoot_bound decay_bound^k ||x_0 - xhat0||``;
    ``H["xhat0"]`` is the initial estimate the observer ran from (the master reads its parameter)."""
    Lf = np.asarray(card.matrices["Lf"], dtype=float)
    xhat0 = np.asarray(H.get("xhat0", card.data["initial"]["xhat0"]), dtype=float)
    bound = certified_bound(card, X[0] - xhat0, D)
    text = (card.data.get("bound", "").replace("overshoot_bound", overshoot_text(card.data))
            .replace("decay_bound**k", f"{card.data['decay_bound']:.6g}^k"))
    empty = np.zeros((len(T), 0))
    result = run_result(T, steps, X @ Lf.T, H["zhat"], Y, U, D, empty, empty, card=card, mode=MODE, bound=bound,
                        decay=card.data.get("decay_bound"), overshoot=card.data.get("overshoot_bound"),
                        bound_text=text, roundoff=None)
    result.estimate = "zhat"
    return result


def _functional_result(card, T, steps, X, Y, U, D, H, MODE, theta_true) -> CosimResult:
    """The run of a functional observer (window kernel): ``gx`` against ``G x`` of the point
    ``delay`` steps back (NaN before there is one), and :func:`~uiofmu.cosim.metrics.functional_metrics`."""
    G = np.asarray(card.data["matrices"]["G"], dtype=float)
    delay, K1 = int(card.schedule["delay"]), len(T)
    true = np.full((K1, G.shape[0]), np.nan)
    true[delay:] = X[:K1 - delay] @ G.T
    empty = np.zeros((K1, 0))
    return run_result(T, steps, X, empty, Y, U, D, empty, empty, card=card, mode=MODE,
                      functional={"gx": H["gx"], "true": true, "valid": H["gx_valid"][:, 0]},
                      window=(delay, int(card.schedule["length"])), formula=card.data.get("formula", ""))


def _delayed_result(card, T, steps, X, Y, U, D, H, MODE, theta_true) -> CosimResult:
    """The run of a delayed observer (seed 001): the state error metrics,
    :func:`~uiofmu.cosim.metrics.delayed_metrics` (theta against the plant's true theta, validity), and no
    certified bound: the card's bound holds on its premise set only, which a run is not known to stay in."""
    empty = np.zeros((len(T), 0))
    theta = None if theta_true is None or theta_true.size != H["thetahat"].shape[1] else theta_true
    delayed = {"thetahat": H["thetahat"], "theta": theta, "sigma_min": H["sigma_min"][:, 0],
               "valid": H["valid"][:, 0], "sigma_bound": float(card.schedule["sigma_bound"])}
    return run_result(T, steps, X, H["xhat"], Y, U, D, H["r"], empty, card=card, delayed=delayed,
                      bound_text=card.data.get("bound", ""))


# -- the validation drivers --------------------------------------------------------------------
def _affine_observer(fmu: Fmu, card, report: Validation, steps: int, rng) -> None:
    """An affine-kernel observer FMU against :class:`~uiofmu.runtime.observer.Runtime`: ``xhat``, ``r`` and
    ``dhat`` at every point of :func:`random_observer_run`."""
    rt = Runtime(card)
    for _ in random_observer_run(fmu, rt, steps, rng):
        if rt.zhat_only:                               # zhat alone
            compare(report, np.asarray(fmu.get("zhat")), rt.xhat())
            continue
        if rt.functional:                              # order n: zhat = Lf xhat besides
            compare(report, np.asarray(fmu.get("zhat")), rt.zhat())
        got = np.concatenate([fmu.get("xhat"), fmu.get("r"), fmu.get("dhat")])
        ref = np.concatenate([rt.xhat(), rt.residual(), rt.dhat() if rt.has_dhat else []])
        compare(report, got, ref)
    report.steps = steps


def _window_observer(fmu: Fmu, card, report: Validation, steps: int, rng) -> None:
    """A functional observer FMU (window kernel) against :class:`~uiofmu.runtime.window.WindowRuntime`:
    ``gx`` and ``gx_valid`` at every point, on random outputs ``y`` and, when the FMU takes it, random
    scheduling values ``theta`` (a window observer steps at its ``dt`` only)."""
    rt = WindowRuntime(card)
    fmu.initialize(0.0)
    takes_theta, t = fmu.has("theta"), 0.0
    for k in range(steps + 1):
        y = rng.normal(size=rt.p) * 3
        fmu.set("y", y)
        rt.set_y(y)
        if takes_theta:
            theta = rng.normal(size=rt.s)
            fmu.set("theta", theta)
            rt.set_theta(theta)
        compare(report, np.concatenate([fmu.get("gx"), fmu.get("gx_valid")]),
                 np.concatenate([rt.gx(), [1.0 if rt.valid else 0.0]]))
        if k < steps:
            fmu.step(t, rt.dt)
            rt.step(rt.dt)
            t += rt.dt
    report.steps = steps


class _Sines:
    """A smooth random input: per channel a sum of three sines (amplitudes 5 to 20, 0.3 to 3 Hz)."""

    def __init__(self, m: int, rng):
        self.a = rng.uniform(5.0, 20.0, size=(3, m))
        self.w = 2 * np.pi * rng.uniform(0.3, 3.0, size=(3, m))
        self.phi = rng.uniform(0.0, 2 * np.pi, size=(3, m))

    def __call__(self, t: float) -> np.ndarray:
        return np.sum(self.a * np.sin(self.w * t + self.phi), axis=0)


def _delayed_plant_data(card) -> dict:
    """A plant for the delayed kernel's signals: the card's ``Abar, Bbar, Cbar, D0, Dy`` and the problem's
    true theta (ones where the card has none)."""
    mats = card.matrices
    n_theta = mats["D0"].shape[1]
    try:
        theta = [float(v) for v in card.data["problem"]["plant"]["parameters"]["theta"]]
    except (KeyError, TypeError, ValueError):
        theta = []
    theta = theta if len(theta) == n_theta else [1.0] * n_theta
    return {"time": "continuous", "A": mats["Abar"].tolist(), "B": mats["Bbar"].tolist(), "C": mats["Cbar"].tolist(),
            "parameters": {"theta": theta, "D0": mats["D0"].tolist(),
                           "Dy": [{"output": i + 1, "D": D.tolist()} for i, D in enumerate(mats["Dy"])]}}


def _delayed_observer(fmu: Fmu, card, report: Validation, steps: int, rng) -> None:
    """A delayed observer FMU against :class:`~uiofmu.runtime.delayed.DelayedRuntime`: ``xhat``,
    ``thetahat``, ``r``, ``sigma_min`` and ``valid`` at every point, fed the same ``y``, ``ydot`` (a
    :class:`~uiofmu.runtime.parametric_plant.ParametricPlantRuntime` of the card's matrices driven by a
    random sum of sines) and ``u``, from a random ``xhat0``, on random aperiodic steps (0.5 to 1.5 times a
    mean that is the card's default ``step``, or longer so that the run lasts 1.5 times the largest
    delay: the estimates become valid, and the delay buffer is read, inside the run)."""
    rt = DelayedRuntime(card)
    plant = ParametricPlantRuntime(_delayed_plant_data(card))
    u_of = _Sines(rt.m, rng)
    xhat0 = 0.5 * rng.normal(size=rt.n)
    rt.xhat0 = xhat0.copy()
    rt.reset()
    fmu.initialize(0.0, {"xhat0": xhat0})
    mean = max(float(card.schedule["step"]), 1.5 * rt.tau / steps)
    t = 0.0
    for k in range(steps + 1):
        plant.u[:] = u_of(t)
        y, ydot = plant.y(), plant.ydot()
        for name, value in (("y", y), ("ydot", ydot), ("u", plant.u)):
            fmu.set(name, value)
        rt.set_y(y)
        rt.set_ydot(ydot)
        rt.set_u(plant.u)
        got = np.concatenate([fmu.get(name) for name in ("xhat", "thetahat", "r", "sigma_min", "valid")])
        ref = np.concatenate([rt.xhat(), rt.theta(), rt.residual(), [rt.margin()], [1.0 if rt.valid else 0.0]])
        compare(report, got, ref)
        if k < steps:
            h = float(rng.uniform(0.5, 1.5) * mean)
            fmu.step(t, h)
            rt.step(h)
            plant.step(h)
            t += h
    report.steps = steps


def random_observer_run(fmu: Fmu, rt: Runtime, steps: int, rng):
    """Drive an affine-kernel observer FMU and its reference runtime side by side on random inputs and steps.

    Both start from one random ``xhat0``; at each of the ``steps + 1`` communication points both get the
    same random ``y`` and ``u`` (and, for a switched plant, a random mode), the generator yields, and
    then (but after the last point) both take the same random admissible step. The caller reads and
    compares the outputs of both at each yield: the run of :func:`validate`.

    Parameters
    ----------
    fmu : Fmu
        The observer FMU, not initialised.
    rt : Runtime
        The reference runtime of its card (reset here).
    steps : int
        The number of steps.
    rng : numpy.random.Generator
        The source of the random values, drawn in a fixed order.

    Yields
    ------
    int
        The index k of the communication point, 0 to ``steps``.
    """
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
        yield k
        if k < steps:
            h = float(choices[int(rng.integers(len(choices)))])
            fmu.step(t, h)
            rt.step(h)
            t += h


@dataclass(frozen=True)
class CosimKernel:
    """The co-simulation side of one runtime kernel.

    Attributes
    ----------
    name : str
        The kernel's name (a key of :data:`uiofmu.runtime.kernels.KERNELS`).
    estimate : str
        The output that estimates the plant (``xhat``, or the functional ``gx``).
    result : callable
        ``result(card, T, steps, X, Y, U, D, H, MODE, theta_true) -> CosimResult``: a run's result and metrics
        from its communication points ``T``, steps, the plant's ``X, Y, U, D``, the observer's outputs ``H`` by
        name, the modes (or None) and the plant's true theta (or None).
    validate : callable
        ``validate(fmu, card, report, steps, rng)``: drive an observer FMU against the kernel's runtime.
    ecospy_exact : bool
        Whether ecospy's run must equal our master's (a delayed observer gets ``ydot`` with the previous ``u``
        in ecospy, so its run only has to complete).
    random_run : bool
        Whether :func:`random_observer_run` drives its FMU (inputs ``y``, ``u`` and a mode; outputs ``xhat``,
        ``r``, ``dhat``), and so :mod:`uiofmu.testing`'s own loop for a card that fails its re-check.
    """

    name: str
    estimate: str
    result: Callable
    validate: Callable
    ecospy_exact: bool = True
    random_run: bool = False

    def estimate_of(self, result: CosimResult) -> np.ndarray:
        """The estimate's rows of a run (``xhat``, or the functional ``gx``)."""
        return result.xhat if self.estimate == "xhat" else result.functional[self.estimate]


#: The co-simulation side of each runtime kernel, by name.
COSIM_KERNELS = {k.name: k for k in (
    CosimKernel("affine", "xhat", _affine_result, _affine_observer, random_run=True),
    CosimKernel("window", "gx", _functional_result, _window_observer),
    CosimKernel("delayed", "xhat", _delayed_result, _delayed_observer, ecospy_exact=False),
)}


def cosim_kernel(card) -> CosimKernel:
    """The co-simulation side of a card's kernel."""
    return COSIM_KERNELS[card.kernel]


__all__ = ["COSIM_KERNELS", "CosimKernel", "cosim_kernel", "random_observer_run"]
