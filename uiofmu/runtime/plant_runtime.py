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
from .mismatch import mismatch_problem, perturb
from .refusals import refusal
from .stepping import check_step
from .schedules import StepRejected, matches
from .state import StateReader, StateRejected
from .tolerances import STEP_RTOL

#: The range of an FMI Integer (fmi2Integer is a C int).
INT_MIN, INT_MAX = -2 ** 31, 2 ** 31 - 1


class PlantRuntime:
    """A linear plant stepped at communication points.

    Parameters
    ----------
    data : dict
        The ``[plant]`` table as data: ``time``, ``A``, ``B``, ``E``, ``C``, ``w``, ``dt``, ``x0``, the
        feedthrough ``D`` and ``F`` of ``y = C x + D u + F d`` where the plant has it and, where the problem
        declares process noise, ``W`` (n x r): the input ``w_noise`` enters as ``W w_noise``, held over the
        step (a continuous plant samples it as it samples ``E``).
    cache_size : int
        How many step lengths keep their discretisation (aperiodic masters reuse a few).

    Notes
    -----
    ``mismatch`` and ``mismatch_seed`` (default 0: the design model) perturb ``A``, ``B``, ``E`` as
    :mod:`uiofmu.runtime.mismatch` says when :meth:`set_mismatch` applies them; the design's matrices are
    kept to start from.
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
        self.W = np.array(data.get("W") or np.zeros((n, 0)), dtype=float).reshape(n, -1)
        self.r = self.W.shape[1]
        self.w_noise = np.zeros(self.r)
        self.param_names: list = []            # a linear plant has no physical parameters to set
        self.params = np.zeros(0)
        self._cache: dict = {}
        self._cache_size = cache_size
        self.mismatch, self.mismatch_seed = 0.0, 0
        self._design = [(self.A, self.B, self.E)]
        self.reset()

    def blocks(self) -> list:
        """The matrices the mismatch perturbs: ``[(A, B, E)]`` (one block per mode)."""
        return [(self.A, self.B, self.E)]

    def _set_blocks(self, blocks: list) -> None:
        self.A, self.B, self.E = blocks[0]

    def set_mismatch(self, mismatch: float, seed: int) -> None:
        """Perturb the design's ``A``, ``B``, ``E`` by ``mismatch`` drawn from ``seed``
        (:func:`uiofmu.runtime.mismatch.perturb`; 0: the design's matrices) and forget the cached
        discretisations.

        Raises
        ------
        StepRejected
            For a mismatch that is not a finite number >= 0, or one that makes an entry overflow
            (nothing changes).
        """
        problem = mismatch_problem(mismatch)
        if problem:
            raise StepRejected(problem)
        blocks = perturb(self._design, float(mismatch), int(seed))
        if not all(np.all(np.isfinite(M)) for block in blocks for M in block):
            raise StepRejected(f"parameter mismatch = {mismatch!r}: a perturbed entry of A, B or E is not finite")
        self._set_blocks(blocks)
        self.mismatch, self.mismatch_seed = float(mismatch), int(seed)
        self._cache.clear()

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
            aug = np.zeros((n + k + self.r, n + k + self.r))
            aug[:n, :n] = self.A
            aug[:n, n:] = np.hstack([self.B, self.E, self.W])
            with np.errstate(over="ignore", invalid="ignore"):
                ex = expm(aug * h)
            if not np.all(np.isfinite(ex)):
                raise StepRejected(f"communication step h = {h!r} s: the plant's exact step exp([A B E] h) "
                                        f"overflows (|A| h up to {float(np.abs(self.A).max()) * h:.3g}); take "
                                        "shorter steps")
            hit = (ex[:n, :n], ex[:n, n:n + self.m], ex[:n, n + self.m:n + k], np.zeros(n), ex[:n, n + k:])
            if len(self._cache) >= self._cache_size:
                self._cache.pop(next(iter(self._cache)))
            self._cache[h] = hit
        return hit[:4]

    def noise_matrix(self, h: float) -> np.ndarray:
        """``W`` over one step of length ``h`` (after :meth:`matrices` of the same ``h``): a discrete plant's
        own, a continuous plant's sampled as ``E`` is."""
        return self._cache[h][4] if self.continuous else self.W

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
        check_step(h, {"u": self.u, "d": self.d, **({"w_noise": self.w_noise} if self.r else {})})
        Ad, Bd, Ed, wd = self.matrices(h)
        x = Ad @ self.x + Bd @ self.u + Ed @ self.d + wd
        self.x = x + self.noise_matrix(h) @ self.w_noise if self.r else x

    def get_state(self) -> dict:
        """JSON-ready state.

        Returns
        -------
        dict
            ``x``, ``x0``, ``u``, ``d`` as lists of Python floats, ``params`` (empty: a linear
            plant has no physical parameters), the ``mismatch`` and ``mismatch_seed`` applied and, with
            process noise, ``w_noise``.
        """
        return {"x": self.x.tolist(), "x0": self.x0.tolist(), "u": self.u.tolist(), "d": self.d.tolist(),
                "params": [], "mismatch": self.mismatch, "mismatch_seed": self.mismatch_seed,
                **({"w_noise": self.w_noise.tolist()} if self.r else {})}

    def set_state(self, state: dict) -> None:
        """Restore :meth:`get_state`, after checking every field (nothing changes otherwise).

        Parameters
        ----------
        state : dict
            Exactly the keys of :meth:`get_state`: ``x`` and ``x0`` (n finite numbers), ``u`` (m)
            and ``d`` (q) numbers (inputs may be non-finite, as through fmi2SetReal: the step
            refuses them), ``params`` an empty list, ``mismatch`` (finite, >= 0) and ``mismatch_seed``
            (an fmi2Integer): the perturbed matrices are computed again from them.

        Raises
        ------
        StateRejected
            For a missing or unknown field, or one of the wrong type, length or value (named).
        """
        r = StateReader(state, ("x", "x0", "u", "d", "params", "mismatch", "mismatch_seed")
                        + (("w_noise",) if self.r else ()), "plant")
        new = {"x": r.vector("x", self.n), "x0": r.vector("x0", self.n), "u": r.vector("u", self.m, finite=False),
               "d": r.vector("d", self.q, finite=False), "params": r.vector("params", 0),
               "mismatch": r.vector("mismatch", 1, value=[state["mismatch"]])[0],
               "mismatch_seed": r.integer("mismatch_seed", INT_MIN, INT_MAX),
               "w_noise": r.vector("w_noise", self.r, finite=False) if self.r else None}
        try:
            self.set_mismatch(new["mismatch"], new["mismatch_seed"])
        except StepRejected as exc:
            raise StateRejected(f"plant state field 'mismatch': {exc}") from None
        self.x, self.x0 = new["x"], new["x0"]
        self.u[:] = new["u"]
        self.d[:] = new["d"]
        if self.r:
            self.w_noise[:] = new["w_noise"]
