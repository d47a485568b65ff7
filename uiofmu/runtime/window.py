"""The window kernel: a functional ``G x`` read off a finite window of outputs (numpy only).

A dead-beat functional observer (seed 003) is a formula on the last ``L`` outputs and
scheduling values, exact whatever the unknown input::

    gx_k = G x_{k - delay} = sum_t w_t(theta window) F_t [y_{k-L+1}; ...; y_k]
    w_t  = prod_{l, i} theta_{k-L+1+l}^(i) ** Fexp[t, l, i]

At the communication point ``t_k`` the master sets ``y_k`` (and ``theta_k``) and reads ``gx``
and ``gx_valid`` (1 once the window holds ``L`` outputs, 0 before, when ``gx`` is 0); ``step``
pushes them into the window, a ring buffer of the last ``L - 1`` points. There is no recursion
and no internal state to drift: the output at every point is the formula on the data.
"""

from __future__ import annotations

import numpy as np

from .state import StateReader
from .stepping import check_step
from .tolerances import STEP_RTOL


class WindowRuntime:
    """Steps one window-kernel observer described by a design card.

    Parameters
    ----------
    card : Card
        A checked design card of kernel ``window``.
    """

    def __init__(self, card):
        self.card = card
        spec = card.schedule
        self.dt = float(spec["dt"])
        self.policy, self.step_rtol = "error", float(spec.get("step_rtol", STEP_RTOL))
        self.L, self.delay, self.s = int(spec["length"]), int(spec["delay"]), int(spec["theta"])
        self.p = card.dims["p"]
        self.d = card.matrices["F"].shape[1]
        self.F = card.matrices["F"]                        # (T, d, p L)
        self.exp = card.matrices["Fexp"].astype(int)        # (T, L, s)
        self.y = np.zeros(self.p)
        self.theta = np.zeros(self.s)
        self._gx = np.zeros(self.d)
        self.reset()

    def reset(self) -> None:
        """Back to k = 0 with an empty window."""
        self.k = 0
        self.ys = np.zeros((self.L - 1, self.p))
        self.thetas = np.zeros((self.L - 1, self.s))

    @property
    def valid(self) -> bool:
        """Whether the window is full (``gx`` is ``G x`` from here on)."""
        return self.k >= self.L - 1

    def set_y(self, y) -> None:
        """Measured outputs at the current communication point."""
        self.y[:] = y

    def set_theta(self, theta) -> None:
        """The scheduling parameter at the current communication point."""
        self.theta[:] = theta

    def gx(self) -> np.ndarray:
        """``G x_{k - delay}`` once the window is full, zeros before (a view; copy to keep)."""
        if not self.valid:
            self._gx[:] = 0.0
            return self._gx
        ys = np.concatenate([self.ys.ravel(), self.y]) if self.L > 1 else self.y.copy()
        thetas = np.vstack([self.thetas, self.theta[None]])
        weights = np.prod(thetas[None] ** self.exp, axis=(1, 2))          # 0 ** 0 = 1
        np.dot(np.tensordot(weights, self.F, axes=1), ys, out=self._gx)
        return self._gx

    def step(self, h: float) -> None:
        """Push the current outputs (and theta) into the window and advance to ``t_k + h``.

        Raises
        ------
        RuntimeInputError
            A non-finite input or a step h <= 0 (nothing changes).
        StepRejected
            A step other than ``dt`` (nothing changes).
        """
        from .schedules import _period

        check_step(h, {"y": self.y, "theta": self.theta}, self.k)
        _period(self, float(h))
        if self.L > 1:
            self.ys = np.vstack([self.ys[1:], self.y[None]])
            self.thetas = np.vstack([self.thetas[1:], self.theta[None]])
        self.k += 1

    def get_state(self) -> dict:
        """JSON-ready state: ``k``, the window (``ys``, ``thetas``, oldest first) and the inputs."""
        return {"k": self.k, "ys": self.ys.ravel().tolist(), "thetas": self.thetas.ravel().tolist(),
                "y": self.y.tolist(), "theta": self.theta.tolist()}

    def set_state(self, state: dict) -> None:
        """Restore :meth:`get_state` after checking every field (nothing changes otherwise).

        Raises
        ------
        StateRejected
            For a missing, unknown or malformed field (named).
        """
        r = StateReader(state, ("k", "ys", "thetas", "y", "theta"), "observer")
        k = r.count("k")
        ys = r.vector("ys", (self.L - 1) * self.p).reshape(self.L - 1, self.p)
        thetas = r.vector("thetas", (self.L - 1) * self.s).reshape(self.L - 1, self.s)
        y, theta = r.vector("y", self.p, finite=False), r.vector("theta", self.s, finite=False)
        self.k, self.ys, self.thetas = k, ys, thetas
        self.y[:], self.theta[:] = y, theta
