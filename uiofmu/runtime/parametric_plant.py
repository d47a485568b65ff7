"""Plants with unknown constant parameters at run time (numpy only): ``x' = A x + B u + D(C x) theta``.

The plant FMU integrates it with classical RK4 substeps of at most ``substep`` seconds between
communication points (inputs held), at most :data:`MAX_SUBSTEPS` of them per step (a longer step is
refused, naming the longest one taken), and outputs ``y = C x`` and its exact derivative
``ydot = C (A x + B u + D(y) theta)`` at the current point with the current input. ``theta`` is a
parameter of the FMU (campaigns vary it); an observer never reads it.
"""

from __future__ import annotations

import math

import numpy as np

from .state import StateReader
from .stepping import check_step, substeps

#: Most RK4 substeps of one communication step: a substep (four evaluations of the vector field)
#: takes 50-120 µs for a few states (measured on the seed 001 plant), so 20 000 are one to two
#: seconds of CPU; a longer step is refused (:class:`~.schedules.StepRejected`: fmi2Discard and a log
#: line, nothing changed) rather than left to run for hours.
MAX_SUBSTEPS = 20_000
#: Largest rate (1/s) of a plant (:func:`rate`): its substep is then 0.02 / rate = 2e-11 s and the
#: longest communication step it takes (:data:`MAX_SUBSTEPS` substeps) 0.4 µs; a faster plant cannot
#: be co-simulated at any practical step (rescale time).
MAX_RATE = 1e9
#: The substep as a fraction of the fastest time constant ``1 / rate``: 50 substeps per time constant.
SUBSTEP_FRACTION = 0.02


def rate(A, C, D0, Dy, theta) -> float:
    """The rate of ``x' = A x + B u + D(C x) theta`` that sets the substep (1/s):
    ``||A|| + sum |D_i| max |theta| ||C|| + sum |D0|`` (infinite when it overflows)."""
    with np.errstate(over="ignore", invalid="ignore"):
        value = float(np.linalg.norm(A, 2)) + float(np.abs(Dy).sum() * np.abs(theta).max(initial=0.0)
                                                    * np.linalg.norm(C, 2) + np.abs(D0).sum())
    return value if math.isfinite(value) else math.inf


class ParametricPlantRuntime:
    """A plant ``x' = A x + B u + D(y) theta`` stepped at communication points.

    Parameters
    ----------
    data : dict
        :meth:`uiofmu.parametric_plant.ParametricPlant.to_data`.
    substep : float, optional
        Longest RK4 substep (default ``SUBSTEP_FRACTION / max(1, rate)`` with :func:`rate`, fifty
        substeps per time constant of the fastest mode).
    """

    def __init__(self, data: dict, substep: float | None = None):
        self.A = np.array(data["A"], dtype=float)
        n = self.A.shape[0]
        self.B = np.array(data["B"], dtype=float).reshape(n, -1)
        self.C = np.array(data["C"], dtype=float)
        par = data["parameters"]
        self.theta0 = np.array(par["theta"], dtype=float)
        self.D0 = np.array(par["D0"], dtype=float)
        self.Dy = np.zeros((self.C.shape[0], n, self.theta0.size))
        for entry in par["Dy"]:
            self.Dy[entry["output"] - 1] = entry["D"]
        self.n, self.m, self.p, self.q = n, self.B.shape[1], self.C.shape[0], 0
        self.x0 = np.array(data.get("x0") or np.zeros(n), dtype=float)
        self.u, self.d = np.zeros(self.m), np.zeros(0)
        self.param_names = [f"theta[{i + 1}]" for i in range(self.theta0.size)]
        self.params = self.theta0.copy()
        self._substep = substep
        self.apply_parameters()
        self.reset()

    @property
    def theta(self) -> np.ndarray:
        """The parameters the plant simulates."""
        return self.params

    def apply_parameters(self) -> None:
        """The substep for the parameters set (``theta`` changes the plant's fastest mode); ``theta``
        itself is read at every evaluation."""
        scale = rate(self.A, self.C, self.D0, self.Dy, self.params)
        self.substep = float(self._substep or SUBSTEP_FRACTION / max(1.0, scale))

    def reset(self) -> None:
        """Back to ``x0``."""
        self.x = self.x0.copy()

    def f(self, x: np.ndarray) -> np.ndarray:
        """``x'`` at ``x`` with the held input."""
        y = self.C @ x
        return self.A @ x + self.B @ self.u + (self.D0 + np.tensordot(y, self.Dy, axes=1)) @ self.params

    def y(self) -> np.ndarray:
        """``C x``."""
        return self.C @ self.x

    def ydot(self) -> np.ndarray:
        """``C x'`` at the current point with the current input."""
        return self.C @ self.f(self.x)

    @property
    def max_step(self) -> float:
        """The longest communication step taken: :data:`MAX_SUBSTEPS` substeps."""
        return MAX_SUBSTEPS * self.substep

    def substeps(self, h: float) -> int:
        """The RK4 substeps of a step ``h`` (> 0): ``ceil(h / substep)``, at least 1.

        Raises
        ------
        StepRejected
            When that is more than :data:`MAX_SUBSTEPS` (naming ``h``, the substep and the longest step).
        """
        return substeps(h, self.substep, MAX_SUBSTEPS, "RK4 substeps of the plant")

    def step(self, h: float) -> None:
        """Advance by ``h`` (RK4 substeps, ``u`` held); see :meth:`substeps`."""
        check_step(h, {"u": self.u})
        steps = self.substeps(h)
        dt, x = h / steps, self.x
        for _ in range(steps):
            k1 = self.f(x)
            k2 = self.f(x + dt / 2 * k1)
            k3 = self.f(x + dt / 2 * k2)
            k4 = self.f(x + dt * k3)
            x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        self.x = x

    def get_state(self) -> dict:
        """JSON-ready state: ``x``, ``x0``, ``u``, ``d`` (empty) and ``params`` (theta)."""
        return {"x": self.x.tolist(), "x0": self.x0.tolist(), "u": self.u.tolist(), "d": [],
                "params": self.params.tolist()}

    def set_state(self, state: dict) -> None:
        """Restore :meth:`get_state` after checking every field (nothing changes otherwise)."""
        r = StateReader(state, ("x", "x0", "u", "d", "params"), "plant")
        new = {"x": r.vector("x", self.n), "x0": r.vector("x0", self.n), "u": r.vector("u", self.m, finite=False),
               "d": r.vector("d", 0), "params": r.vector("params", self.params.size)}
        self.x, self.x0 = new["x"], new["x0"]
        self.u[:] = new["u"]
        self.params[:] = new["params"]
        self.apply_parameters()
