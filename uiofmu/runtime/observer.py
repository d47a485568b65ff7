"""The reference runtime: the step semantics every observer FMU reproduces.

numpy only (no cvxpy): this module is what runs inside a pythonfmu observer. At the
communication point ``t_k`` the master sets ``y_k`` and ``u_k`` and reads the outputs::

    xhat_k = Xz z_k + Xy y_k [+ Xu u_k]   (xhat_0 is the initial estimate itself; Xu where the card has it)
    r_k    = y_k - C xhat_k
    dhat_k = Dy (y_k - Yx xhat_{k-1} - Yu u_{k-1} - Yc)     (0 at k = 0)

then ``step(h_k)`` advances::

    z_{k+1} = N z_k + L y_k + G u_k + c

with ``z_0 = xhat0 - Xy y_0 [- Xu u_0]``, or ``z_0 = Zx (xhat0 - Xy y_0)`` where the card has ``Zx`` (a
reduced-order observer, ``nz < n``).

A functional observer (``dims.nf``, matrices ``Lf`` and ``Zx``) starts at ``z_0 = Zx xhat0`` and estimates ``Lf x``
(``nf`` functionals): below order ``n`` instead of ``x``, as ``zhat_k = Xz z_k + Xy y_k`` (``zhat_0 = Lf xhat0``),
with no residual and no ``dhat`` (both read ``xhat``; :meth:`Runtime.xhat` returns ``zhat``); at order ``n``
besides ``x``, as ``zhat = Lf xhat`` (:meth:`Runtime.zhat`).

with the matrices the schedule picks for (k, h_k, h_{k-1}), and for a switched plant for the
modes (alpha_k, alpha_{k-1}): the input ``mode`` is the mode of the step about to be taken, and
the runtime keeps the previous one (``mode_prev``, ``mode_prev0`` before the first step). At the first step
``z_0 = xhat_0 - Xy y_0 [- Xu u_0]``, so the first output is the initial estimate and ``z`` takes over
from there. ``dhat_k`` estimates the unknown input held over ``[t_{k-1}, t_k)``.
"""

from __future__ import annotations

import numpy as np

from .schedules import ModeRejected, StepRejected, make_schedule
from .state import StateReader, StateRejected
from .stepping import RuntimeInputError, check_step




class Runtime:
    """Steps one observer described by a design card.

    Parameters
    ----------
    card : Card
        A checked design card.
    xhat0 : array_like, optional
        Initial estimate (default: the card's ``initial.xhat0``).
    h_prev0 : float, optional
        The step assumed before the first one, h_{-1} (interval schedules; default: the card's).
    mode_prev0 : int, optional
        The mode assumed before the first step, alpha_{-1} (mode schedules; default: the card's).

    Examples
    --------
    >>> rt = Runtime(card)                     # doctest: +SKIP
    >>> rt.set_y([1.0]); rt.set_u([0.0])       # doctest: +SKIP
    >>> xhat = rt.xhat(); rt.step(0.1)         # doctest: +SKIP
    """

    def __init__(self, card, xhat0=None, h_prev0=None, mode_prev0=None):
        self.card = card
        d = card.dims
        self.n, self.m, self.p, self.q, self.nz = d["n"], d["m"], d["p"], d["q"], d["nz"]
        self.functional = "nf" in d            # zhat estimates Lf x
        self.zhat_only = self.functional and self.nz != self.n      # zhat = Xz z + Xy y (else Lf xhat)
        self.ne = d["nf"] if self.zhat_only else self.n
        self.schedule = make_schedule(card.schedule, card.matrices)
        self.has_dhat = card.has_dhat
        default = card.data["initial"].get("xhat0", [0.0] * self.n)
        self.xhat0 = np.array(default if xhat0 is None else xhat0, dtype=float)
        self.h_prev0 = float(self.schedule.initial_h_prev() if h_prev0 is None else h_prev0)
        self.modes = getattr(self.schedule, "modes", 0)
        self.mode_prev0 = (getattr(self.schedule, "mode_prev0", 0) if mode_prev0 is None else mode_prev0)
        if self.modes:
            self.schedule.index(self.mode_prev0, "mode_prev0")
        self.mode = self.mode_prev0
        self.y = np.zeros(self.p)
        self.u = np.zeros(self.m)
        self._xhat = np.empty(self.ne)
        self._r = np.empty(self.p)
        self._dhat = np.zeros(self.q)
        self._tmp = np.empty(self.nz)
        self._tz = np.empty(self.nz)
        self._tn = np.empty(self.ne)
        self._tp = np.empty(self.p)
        self.reset()

    # -- state -------------------------------------------------------------------------
    def reset(self) -> None:
        """Back to k = 0 with the current initial estimate."""
        self.k = 0
        self.z = np.zeros(self.nz)
        self.pred = np.zeros(self.p)          # Yx xhat_{k-1} + Yu u_{k-1} + Yc
        self.h_prev = self.h_prev0
        self.mode_prev = self.mode_prev0

    def _keys(self) -> tuple:
        keys = ("k", "z", "pred", "h_prev", "xhat0", "h_prev0", "y", "u")
        return keys + ("mode", "mode_prev", "mode_prev0") if self.modes else keys

    def get_state(self) -> dict:
        """Everything that defines the future outputs, as plain lists (JSON-ready).

        Returns
        -------
        dict
            ``k``, ``z``, ``pred``, ``h_prev``, ``xhat0``, ``h_prev0``, ``y``, ``u`` (and for a mode
            schedule the integers ``mode``, ``mode_prev``, ``mode_prev0``); floats are Python floats,
            so a JSON round trip (``repr`` of each float) restores them exactly.
        """
        state = {"k": self.k, "z": self.z.tolist(), "pred": self.pred.tolist(), "h_prev": self.h_prev,
                 "xhat0": self.xhat0.tolist(), "h_prev0": self.h_prev0, "y": self.y.tolist(), "u": self.u.tolist()}
        if self.modes:
            state.update(mode=int(self.mode), mode_prev=int(self.mode_prev), mode_prev0=int(self.mode_prev0))
        return state

    def set_state(self, state: dict) -> None:
        """Restore what :meth:`get_state` returned, after checking every field.

        Nothing changes unless the whole state is valid: a state may come from an importer
        (deserialised bytes, another FMU's state), so each field is checked before use.

        Parameters
        ----------
        state : dict
            Exactly the keys of :meth:`get_state`: ``k`` a non-negative integer (at most 2**53);
            ``z`` (nz), ``pred`` (p) and ``xhat0`` (n) finite numbers; ``h_prev`` and ``h_prev0``
            finite steps > 0 and, for an interval schedule with ``step_policy = "error"`` (which
            looks its matrices up by the previous step), design intervals; ``y`` (p) and ``u``
            (m) numbers, which may be non-finite like any input set through fmi2SetReal (the
            step refuses them); for a mode schedule ``mode_prev`` and ``mode_prev0`` modes 1..N
            and ``mode`` any Integer (an input: the step refuses a bad one).

        Raises
        ------
        StateRejected
            For a state that is not a dict, a missing or unknown field, or a field of the wrong
            type, length or range; the message names the field.
        """
        r = StateReader(state, self._keys(), "observer")

        def step_length(key):
            h = r.number(key, 0.0, open_low=True)
            if hasattr(self.schedule, "intervals") and self.schedule.policy == "error":
                try:
                    self.schedule.index(h)
                except StepRejected as exc:
                    raise StateRejected(f"observer state field {key!r}: {exc}") from None
            return h

        k = r.count("k")
        modes = ({"mode": r.integer("mode", -2 ** 31, 2 ** 31 - 1), "mode_prev": r.integer("mode_prev", 1, self.modes),
                  "mode_prev0": r.integer("mode_prev0", 1, self.modes)} if self.modes else {})
        new = {"z": r.vector("z", self.nz), "pred": r.vector("pred", self.p), "xhat0": r.vector("xhat0", self.n),
               "y": r.vector("y", self.p, finite=False), "u": r.vector("u", self.m, finite=False),
               "h_prev": step_length("h_prev"), "h_prev0": step_length("h_prev0")}
        self.k = k
        self.z, self.pred, self.xhat0 = new["z"], new["pred"], new["xhat0"]
        self.h_prev, self.h_prev0 = new["h_prev"], new["h_prev0"]
        for key, value in modes.items():
            setattr(self, key, value)
        self.y[:] = new["y"]
        self.u[:] = new["u"]

    # -- inputs ------------------------------------------------------------------------
    def set_y(self, y) -> None:
        """Measured outputs at the current communication point."""
        self.y[:] = y

    def set_u(self, u) -> None:
        """Known inputs at the current communication point."""
        self.u[:] = u

    def set_mode(self, mode) -> None:
        """The mode of the step from the current communication point (switched plants; checked by
        :meth:`step`)."""
        self.mode = mode

    # -- outputs -----------------------------------------------------------------------
    def xhat(self) -> np.ndarray:
        """The state estimate at the current communication point (a view; copy to keep); a functional
        observer's ``zhat``."""
        if self.k == 0:
            if self.zhat_only:
                np.dot(self.card.matrices["Lf"], self.xhat0, out=self._xhat)
            else:
                self._xhat[:] = self.xhat0
            return self._xhat
        mats = self.schedule.output_matrices(self.k, self.h_prev, self.mode_prev)
        np.dot(mats["Xz"], self.z, out=self._xhat)
        self._xhat += np.dot(mats["Xy"], self.y, out=self._tn)
        if "Xu" in mats:
            self._xhat += np.dot(mats["Xu"], self.u, out=self._tn)
        return self._xhat

    def zhat(self) -> np.ndarray:
        """A functional observer's estimate of ``Lf x``: ``Lf xhat`` at order ``n``, else :meth:`xhat`."""
        return self.xhat() if self.zhat_only else self.card.matrices["Lf"] @ self.xhat()

    def residual(self) -> np.ndarray:
        """``r = y - C xhat``."""
        np.dot(self.card.matrices["C"], self.xhat(), out=self._r)
        np.subtract(self.y, self._r, out=self._r)
        return self._r

    def dhat(self) -> np.ndarray:
        """Estimate of the unknown input over the last step (zeros at k = 0 or without dhat)."""
        if self.has_dhat and self.k > 0:
            mats = self.schedule.output_matrices(self.k, self.h_prev, self.mode_prev)
            np.subtract(self.y, self.pred, out=self._tp)
            np.dot(mats["Dy"], self._tp, out=self._dhat)
        return self._dhat

    # -- step --------------------------------------------------------------------------
    def step(self, h: float) -> None:
        """Advance from ``t_k`` to ``t_k + h`` with the inputs currently set.

        Raises
        ------
        RuntimeInputError
            A non-finite input, a step h <= 0 or a mode that is not one of the plant's (nothing
            changes).
        StepRejected
            A step the schedule was not designed for (nothing changes).
        """
        check_step(h, {"y": self.y, "u": self.u}, self.k)
        try:
            mats = self.schedule.step_matrices(self.k, float(h), self.h_prev, self.mode, self.mode_prev)
        except ModeRejected as exc:
            raise RuntimeInputError(f"input {exc} at step k = {self.k}") from None
        xhat = self.xhat()
        if self.k == 0 and self.functional:      # z_0 = Zx xhat0 (Zx = T: z estimates T x)
            self.z = self.card.matrices["Zx"] @ self.xhat0
        elif self.k == 0:
            out = self.schedule.output_matrices(0, self.h_prev, self.mode_prev)
            self.z = self.xhat0 - out["Xy"] @ self.y
            if "Xu" in out:
                self.z -= out["Xu"] @ self.u
            if "Zx" in self.card.matrices:     # a reduced-order observer: z_0 = Zx (xhat0 - Xy y_0)
                self.z = self.card.matrices["Zx"] @ self.z
        if self.has_dhat:
            np.dot(mats["Yx"], xhat, out=self.pred)
            self.pred += np.dot(mats["Yu"], self.u, out=self._tp)
            self.pred += mats["Yc"]
        np.dot(mats["N"], self.z, out=self._tmp)
        self._tmp += np.dot(mats["L"], self.y, out=self._tz)
        self._tmp += np.dot(mats["G"], self.u, out=self._tz)
        self._tmp += mats["c"]
        self.z, self._tmp = self._tmp, self.z
        self.h_prev = float(h)
        self.mode_prev = self.mode
        self.k += 1


__all__ = ["Runtime", "RuntimeInputError", "StepRejected"]

