"""LPV plants at run time (numpy only): ``x+ = A(theta) x + E(theta) d``, ``y = C(theta) x + D(theta) d``.

``theta_k`` is ``T x_k`` (kind ``state``: the plant is then the nonlinear system it describes,
exactly) or the plant FMU's input ``theta`` (kind ``input``). Every matrix is affine in theta:
``A(theta) = A + sum_i theta^(i) A_i`` (:mod:`uiofmu.lpv_plant`). A discrete plant: steps of ``dt`` only.
"""

from __future__ import annotations

import numpy as np

from .refusals import refusal
from .schedules import StepRejected, matches
from .state import StateReader
from .stepping import check_step
from .tolerances import STEP_RTOL


class LpvPlantRuntime:
    """An LPV plant stepped at communication points.

    Parameters
    ----------
    data : dict
        :meth:`uiofmu.lpv_plant.LpvPlant.to_data`: ``dt``, ``A``, ``E``, ``C``, ``D``, ``x0``,
        ``scheduling`` (parts per theta component) and ``theta`` (``kind``, and ``T`` for ``state``).
    """

    def __init__(self, data: dict):
        self.parts = {name: np.array([data[name]] + [part[name] for part in data["scheduling"]], dtype=float)
                      for name in ("A", "E", "C", "D")}
        self.dt = float(data["dt"])
        self.n, self.q = self.parts["E"].shape[1], self.parts["E"].shape[2]
        self.p, self.s, self.m = self.parts["C"].shape[1], len(data["scheduling"]), 0
        self.kind = data["theta"]["kind"]
        self.T = np.array(data["theta"].get("T", np.zeros((self.s, self.n))), dtype=float).reshape(self.s, self.n)
        self.x0 = np.array(data.get("x0") or np.zeros(self.n), dtype=float)
        self.u, self.d = np.zeros(0), np.zeros(self.q)
        self.theta_in = np.zeros(self.s)
        self.param_names: list = []
        self.params = np.zeros(0)
        self.reset()

    def apply_parameters(self) -> None:
        """Nothing to apply (kept for the FMU model's interface)."""

    def reset(self) -> None:
        """Back to the initial state ``x0``."""
        self.x = self.x0.copy()

    def theta(self) -> np.ndarray:
        """``theta_k``: ``T x_k`` or the input."""
        return self.T @ self.x if self.kind == "state" else self.theta_in

    def matrix(self, name: str) -> np.ndarray:
        """``name(theta_k)`` for ``"A"``, ``"E"``, ``"C"`` or ``"D"``."""
        parts = self.parts[name]
        return parts[0] + np.tensordot(self.theta(), parts[1:], axes=1)

    def y(self) -> np.ndarray:
        """``C(theta_k) x_k + D(theta_k) d_k``."""
        return self.matrix("C") @ self.x + self.matrix("D") @ self.d

    def step(self, h: float) -> None:
        """Advance by ``dt`` with ``d`` (and theta) held."""
        check_step(h, {"d": self.d, "theta": self.theta_in})
        if not matches(h, self.dt, STEP_RTOL):
            raise StepRejected(refusal("plant_off_period", dt=self.dt, h=h))
        self.x = self.matrix("A") @ self.x + self.matrix("E") @ self.d

    def get_state(self) -> dict:
        """JSON-ready state: ``x``, ``x0``, the inputs ``u`` (empty), ``d``, ``theta`` and ``params`` (empty)."""
        return {"x": self.x.tolist(), "x0": self.x0.tolist(), "u": [], "d": self.d.tolist(),
                "theta": self.theta_in.tolist(), "params": []}

    def set_state(self, state: dict) -> None:
        """Restore :meth:`get_state` after checking every field (nothing changes otherwise)."""
        r = StateReader(state, ("x", "x0", "u", "d", "theta", "params"), "plant")
        new = {"x": r.vector("x", self.n), "x0": r.vector("x0", self.n), "u": r.vector("u", 0),
               "d": r.vector("d", self.q, finite=False), "theta": r.vector("theta", self.s, finite=False),
               "params": r.vector("params", 0)}
        self.x, self.x0 = new["x"], new["x0"]
        self.d[:], self.theta_in[:] = new["d"], new["theta"]
