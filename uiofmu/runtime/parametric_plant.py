"""Plants with unknown constant parameters at run time (numpy only): ``x' = A x + B u + D(C x) theta``.

The plant FMU integrates it with classical RK4 substeps of at most ``substep`` seconds between
communication points (inputs held), and outputs ``y = C x`` and its exact derivative
``ydot = C (A x + B u + D(y) theta)`` at the current point with the current input. ``theta`` is a
parameter of the FMU (campaigns vary it); an observer never reads it.
"""

from __future__ import annotations

import math

import numpy as np

from .state import StateReader
from .stepping import check_step


class ParametricPlantRuntime:
    """A plant ``x' = A x + B u + D(y) theta`` stepped at communication points.

    Parameters
    ----------
    data : dict
        :meth:`uiofmu.parametric_plant.ParametricPlant.to_data`.
    substep : float, optional
        Longest RK4 substep (default ``0.02 / max(1, ||A|| + ||D|| |theta| ||C||)``, a few hundred
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
        scale = float(np.linalg.norm(self.A, 2)) + float(np.abs(self.Dy).sum() * np.abs(self.theta0).max()
                                                       * np.linalg.norm(self.C, 2) + np.abs(self.D0).sum())
        self.substep = float(substep or 0.02 / max(1.0, scale))
        self.reset()

    @property
    def theta(self) -> np.ndarray:
        """The parameters the plant simulates."""
        return self.params

    def apply_parameters(self) -> None:
        """Nothing to precompute: ``theta`` is read at every evaluation."""

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

    def step(self, h: float) -> None:
        """Advance by ``h`` (RK4 substeps, ``u`` held)."""
        check_step(h, {"u": self.u})
        steps = max(1, int(math.ceil(h / self.substep - 1e-9)))
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
