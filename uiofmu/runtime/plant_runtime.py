"""Stepping a linear plant exactly between communication points (numpy only).

This is what runs inside a plant FMU: a continuous plant is advanced by the exact
zero-order-hold solution for any step ``h`` whose exponential is finite (the exponential of the
augmented matrix, inputs held over the step, by the algorithm of the C plant kernel:
:mod:`uiofmu.runtime.matrix_exponential`; one that overflows is refused); a discrete plant takes
steps of its own ``dt`` only. There are no substeps: the exponential takes at most about 1030
squarings (``log2`` of the largest double), whatever ``h``.
"""

from __future__ import annotations

import numpy as np

from .matrix_exponential import expm
from .refusals import refusal
from .stepping import check_step
from .schedules import StepRejected, matches
from .state import StateReader
from .tolerances import STEP_RTOL


class PlantRuntime:
    """A linear plant stepped at communication points.

    Parameters
    ----------
    data : dict
        The ``[plant]`` table as data: ``time``, ``A``, ``B``, ``E``, ``C``, ``w``, ``dt``, ``x0``, and the
        feedthrough ``D`` and ``F`` of ``y = C x + D u + F d`` where the plant has it.
    cache_size : int
        How many step lengths keep their discretisation (aperiodic masters reuse a few).
    """

    def __init__(self, data: dict, cache_size: int = 256):
        self.continuous = data["time"] == "continuous"
        self.A = np.array(data["A"], dtype=float)
        n = self.A.shape[0]
        self.C = np.array(data["C"], dtype=float)
        self.B = np.array(data.get("B", np.zeros((n, 0))), dtype=float).reshape(n, -1)
        self.E = np.array(data["E"], dtype=float).reshape(n, -1)
        self.w = np.array(data.get("w") or np.zeros(n), dtype=float)
        self.dt = data.get("dt")
        self.n, self.m, self.q, self.p = n, self.B.shape[1], self.E.shape[1], self.C.shape[0]
        self.x0 = np.array(data.get("x0") or np.zeros(n), dtype=float)
        self.D = np.array(data["D"], dtype=float).reshape(self.p, self.m) if data.get("D") else None
        self.F = np.array(data["F"], dtype=float).reshape(self.p, self.q) if data.get("F") else None
        self.u = np.zeros(self.m)
        self.d = np.zeros(self.q)
        self.param_names: list = []            # a linear plant has no physical parameters to set
        self.params = np.zeros(0)
        self._cache: dict = {}
        self._cache_size = cache_size
        self.reset()

    def apply_parameters(self) -> None:
        """Nothing to apply: the matrices are the parameters (kept for the FMU model's interface)."""

    def reset(self) -> None:
        """Back to the initial state ``x0``."""
        self.x = self.x0.copy()

    def matrices(self, h: float):
        """``(Ad, Bd, Ed, wd)`` for one step of length ``h``.

        Raises
        ------
        StepRejected
            A discrete plant given another step than its ``dt``, a continuous plant whose
            exponential over ``h`` overflows (naming ``h``).
        """
        if not self.continuous:
            if not matches(h, self.dt, STEP_RTOL):
                raise StepRejected(refusal("plant_off_period", dt=self.dt, h=h))
            return self.A, self.B, self.E, self.w
        hit = self._cache.get(h)
        if hit is None:
            n, k = self.n, self.m + self.q
            aug = np.zeros((n + k, n + k))
            aug[:n, :n] = self.A
            aug[:n, n:] = np.hstack([self.B, self.E])
            with np.errstate(over="ignore", invalid="ignore"):
                ex = expm(aug * h)
            if not np.all(np.isfinite(ex)):
                raise StepRejected(f"communication step h = {h!r} s: the plant's exact step exp([A B E] h) "
                                        f"overflows (|A| h up to {float(np.abs(self.A).max()) * h:.3g}); take "
                                        "shorter steps")
            hit = (ex[:n, :n], ex[:n, n:n + self.m], ex[:n, n + self.m:], np.zeros(n))
            if len(self._cache) >= self._cache_size:
                self._cache.pop(next(iter(self._cache)))
            self._cache[h] = hit
        return hit

    def y(self) -> np.ndarray:
        """Measured outputs ``C x + D u + F d`` (with the inputs currently set)."""
        y = self.C @ self.x
        if self.D is not None:
            y += self.D @ self.u
        if self.F is not None:
            y += self.F @ self.d
        return y

    def step(self, h: float) -> None:
        """Advance by ``h`` with ``u`` and ``d`` held."""
        check_step(h, {"u": self.u, "d": self.d})
        Ad, Bd, Ed, wd = self.matrices(h)
        self.x = Ad @ self.x + Bd @ self.u + Ed @ self.d + wd

    def get_state(self) -> dict:
        """JSON-ready state.

        Returns
        -------
        dict
            ``x``, ``x0``, ``u``, ``d`` as lists of Python floats and ``params`` (empty: a linear
            plant has no physical parameters).
        """
        return {"x": self.x.tolist(), "x0": self.x0.tolist(), "u": self.u.tolist(), "d": self.d.tolist(),
                "params": []}

    def set_state(self, state: dict) -> None:
        """Restore :meth:`get_state`, after checking every field (nothing changes otherwise).

        Parameters
        ----------
        state : dict
            Exactly the keys of :meth:`get_state`: ``x`` and ``x0`` (n finite numbers), ``u`` (m)
            and ``d`` (q) numbers (inputs may be non-finite, as through fmi2SetReal: the step
            refuses them), ``params`` an empty list.

        Raises
        ------
        StateRejected
            For a missing or unknown field, or one of the wrong type, length or value (named).
        """
        r = StateReader(state, ("x", "x0", "u", "d", "params"), "plant")
        new = {"x": r.vector("x", self.n), "x0": r.vector("x0", self.n), "u": r.vector("u", self.m, finite=False),
               "d": r.vector("d", self.q, finite=False), "params": r.vector("params", 0)}
        self.x, self.x0 = new["x"], new["x0"]
        self.u[:] = new["u"]
        self.d[:] = new["d"]
