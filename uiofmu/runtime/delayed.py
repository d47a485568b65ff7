"""The delayed kernel: a continuous-time delayed UIO integrated inside the FMU (seed 001; numpy only).

The plant ``x' = A x + B u + D(y) theta``, ``y = C x`` (:mod:`uiofmu.parametric_plant`) is augmented
with ``m`` delayed copies (paper (8)): ``xa = [x; x(t - tau_1); ...]``, ``ya``, ``ua`` likewise,
``Aa = I (x) A`` (block diagonal), ``Ca``, ``Ba`` block diagonal, ``Da = [D(y); D(y(t - tau_1)); ...]``.
With ``F = Ca Da`` of full column rank, (19)-(23)::

    H = -Da (F'F)^-1 F',   P = I + H Ca,   Gamma = Hdot Ca + P Aa,   P Da = 0
    Hdot = -Dadot W^-1 F' + Da W^-1 Wdot W^-1 F' - Da W^-1 Fdot'    (W = F'F, Fdot = Ca Dadot)

and the observer ``z' = (Gamma - K Ca) xhat + K ya + P Ba ua``, ``xhat = z - H ya`` gives
``e' = (Gamma - K Ca) e`` whatever theta. The parameters (34) come from the measured derivative:
``thetahat = F^+ (yadot - Ca Aa xhat - Ca Ba ua)``.

Between communication points the kernel integrates ``z`` with fixed RK4 substeps (at most
``max_substep`` long), the current outputs expanded to second order with their measured derivative
(:func:`hermite`), ``u`` held, and the delayed signals read from a time-stamped buffer of the past
communication points (cubic Hermite in ``y`` and ``ydot``, ``u`` held), so that aperiodic steps
need no resampling.

Validity: the estimates are valid where the card's certificate covers the signals: from the premise's
start (``valid_from``, at least ``max tau``: every delayed signal exists and the start-up transient the
premise leaves out is over), while the rank margin ``sigma_min(Ca Da)`` is at least the card's
``sigma_bound`` (the premise family's smallest margin) and ``||Gamma||`` at most its ``gamma_bound``
(the largest of the premise points certified). While invalid the kernel holds ``xhat`` and
``thetahat`` and does not integrate; it restarts from the held estimate (``z = xhat + H ya``) when
the signals return.
"""

from __future__ import annotations

import math

import numpy as np

from .schedules import StepRejected
from .state import StateReader
from .stepping import check_step, substeps


#: Most RK4 substeps one communication step may take (observer or prediction): about 2 s of CPU at
#: 0.2 ms a substep. A longer step is refused with the longest one accepted, never a hang.
MAX_SUBSTEPS = 10_000
#: The delay buffer keeps up to this many times the points that steps of the card's default ``step`` leave
#: over the longest delay (:func:`buffer_rows`): steps may average a sixteenth of the default step.
BUFFER_FACTOR = 16
#: Most points the delay buffer keeps, whatever the card (a C FMU's state holds them all).
MAX_BUFFER_ROWS = 262_144


def buffer_rows(delays, step: float) -> int:
    """The most past points the delay buffer keeps: ``16 (ceil(max tau / step) + 1)``, at most
    :data:`MAX_BUFFER_ROWS`. A step after which it would hold more is refused (the buffer keeps the points
    of the last ``max tau`` seconds: they are that many only when the steps are that short)."""
    per_delay = max(float(t) for t in delays) / float(step)
    return int(min(BUFFER_FACTOR * (math.ceil(min(per_delay, MAX_BUFFER_ROWS)) + 1), MAX_BUFFER_ROWS))


def augmented(M: np.ndarray, copies: int) -> np.ndarray:
    """``I_copies (x) M``: the block-diagonal matrix of ``copies`` copies of ``M``."""
    return np.kron(np.eye(copies), M)


def d_matrix(D0: np.ndarray, Dy: np.ndarray, y) -> np.ndarray:
    """``D(y) = D0 + sum_i y_i Dy[i]``."""
    return D0 + (np.asarray(y, dtype=float) @ Dy.reshape(Dy.shape[0], -1)).reshape(D0.shape)


def decoupling(Ca: np.ndarray, Da: np.ndarray, Dadot: np.ndarray):
    """``H``, ``Hdot`` (19) and its analytic derivative, and ``sigma_min(F)``, ``F = Ca Da``.

    Returns
    -------
    H, Hdot : numpy.ndarray or None
        None when ``F`` has not full column rank to working precision (``cond(F) > 1e6``).
    sigma : float
        The smallest singular value of ``F`` (the rank margin).
    """
    F = Ca @ Da
    W = F.T @ F
    eig = np.linalg.eigvalsh(W) if F.shape[0] >= F.shape[1] else np.zeros(1)
    sigma = float(np.sqrt(max(eig[0], 0.0)))
    if not eig[0] > 1e-12 * max(float(eig[-1]), 1e-300):            # cond(F) above 1e6: no inverse worth the name
        return None, None, sigma
    Wi = np.linalg.inv(W)
    Fd = Ca @ Dadot
    Wd = Fd.T @ F + F.T @ Fd
    H = -Da @ Wi @ F.T
    Hdot = -Dadot @ Wi @ F.T + Da @ Wi @ Wd @ Wi @ F.T - Da @ Wi @ Fd.T
    return H, Hdot, sigma


def gamma(Aa: np.ndarray, Ca: np.ndarray, H: np.ndarray, Hdot: np.ndarray) -> np.ndarray:
    """``Gamma = Pdot + P Aa`` (23), ``P = I + H Ca``, ``Pdot = Hdot Ca``."""
    return Hdot @ Ca + (np.eye(Aa.shape[0]) + H @ Ca) @ Aa


def stacked(D0, Dy, ys, ydots):
    """``Da`` and its time derivative for the current and delayed outputs ``ys``, ``ydots`` (copies, p)."""
    flat = Dy.reshape(Dy.shape[0], -1)
    n, nt = D0.shape
    Da = (np.asarray(ys) @ flat).reshape(-1, n, nt) + D0[None]
    Dadot = (np.asarray(ydots) @ flat).reshape(-1, n, nt)
    return Da.reshape(-1, nt), Dadot.reshape(-1, nt)


def hermite(times: np.ndarray, ys: np.ndarray, ydots: np.ndarray, s: float, left: np.ndarray | None = None) -> tuple:
    """``y(s)`` and ``ydot(s)`` from samples ``(times, ys, ydots)`` of a signal whose derivative jumps at
    the samples (a plant with a held input: ``ydot`` jumps by ``C B (u_k - u_k-1)``).

    ``ydots`` are the right limits (what the plant reports with the new input), ``left`` the left limits
    (default: the same). Between samples, the cubic Hermite polynomial with the right limit at the
    interval's start and the left limit at its end (its derivative for ``ydot``); after the last sample
    its second-order expansion, the second derivative from the last interval (``(left_k - right_k-1) / h``);
    before the first sample, the first sample. Held derivatives instead would make ``Pdot`` wrong to
    first order in the step (the error floor measured on seed 001's example)."""
    left = ydots if left is None else left
    last = len(times) - 1
    if s >= times[last]:
        d = s - times[last]
        if last == 0:
            return ys[last] + ydots[last] * d, ydots[last]
        ydd = (left[last] - ydots[last - 1]) / (times[last] - times[last - 1])
        return ys[last] + ydots[last] * d + 0.5 * ydd * d * d, ydots[last] + ydd * d
    if s <= times[0] or last == 0:
        return ys[0], ydots[0]
    j = int(np.searchsorted(times, s, side="right")) - 1
    h = times[j + 1] - times[j]
    x = (s - times[j]) / h
    ya, yb, da, db = ys[j], ys[j + 1], ydots[j] * h, left[j + 1] * h
    x2, x3 = x * x, x * x * x
    y = (2 * x3 - 3 * x2 + 1) * ya + (x3 - 2 * x2 + x) * da + (-2 * x3 + 3 * x2) * yb + (x3 - x2) * db
    yd = ((6 * x2 - 6 * x) * ya + (3 * x2 - 4 * x + 1) * da + (-6 * x2 + 6 * x) * yb + (3 * x2 - 2 * x) * db) / h
    return y, yd


class DelayedRuntime:
    """Steps one delayed-kernel observer described by a design card.

    Parameters
    ----------
    card : Card
        A checked design card of kernel ``delayed``.
    xhat0 : array_like, optional
        Initial estimate of the plant state (default the card's); the delayed copies start there too.
    """

    def __init__(self, card, xhat0=None):
        spec, mats = card.schedule, card.matrices
        self.card = card
        self.delays = [float(t) for t in spec["delays"]]
        self.tau = max(self.delays)
        self.max_substep = float(spec["max_substep"])
        self.sigma_bound = float(spec["sigma_bound"])
        self.valid_from = max(float(spec.get("valid_from", self.tau)), self.tau)
        self.gamma_bound = float(spec.get("gamma_bound", math.inf))
        self.rows_max = buffer_rows(self.delays, spec["step"])
        self.A, self.B, self.C = mats["Abar"], mats["Bbar"], mats["Cbar"]
        self.D0, self.Dy, self.K = mats["D0"], mats["Dy"], mats["K"]
        self.n, self.m, self.p = self.A.shape[0], self.B.shape[1], self.C.shape[0]
        self.n_theta = self.D0.shape[1]
        c = len(self.delays) + 1
        self.Aa, self.Ba, self.Ca = augmented(self.A, c), augmented(self.B, c), augmented(self.C, c)
        self.CB = self.C @ self.B
        default = card.data["initial"].get("xhat0", [0.0] * self.n)
        self.xhat0 = np.array(default if xhat0 is None else xhat0, dtype=float)
        self.y, self.ydot, self.u = np.zeros(self.p), np.zeros(self.p), np.zeros(self.m)
        self.notices: list[str] = []
        self.reset()

    # -- state ------------------------------------------------------------------------------------
    def reset(self) -> None:
        """Back to t = 0: estimate ``xhat0`` (and its delayed copies), empty buffer, not running."""
        self.t, self.k = 0.0, 0
        self.running = False
        self.xa = np.tile(self.xhat0, len(self.delays) + 1)
        self.z = np.zeros_like(self.xa)
        self.thetahat = np.zeros(self.n_theta)
        self.buffer = np.zeros((0, 1 + 2 * self.p + self.m))      # rows: t, y, ydot, u
        self._noted = False

    def get_state(self) -> dict:
        """JSON-ready state: time, counter, running flag, ``z``, held estimates, the buffer, inputs."""
        return {"t": self.t, "k": self.k, "running": self.running, "z": self.z.tolist(), "xa": self.xa.tolist(),
                "thetahat": self.thetahat.tolist(), "buffer": self.buffer.ravel().tolist(),
                "rows": int(self.buffer.shape[0]), "xhat0": self.xhat0.tolist(), "noted": self._noted,
                "y": self.y.tolist(), "ydot": self.ydot.tolist(), "u": self.u.tolist()}

    def set_state(self, state: dict) -> None:
        """Restore :meth:`get_state` after checking every field (nothing changes otherwise).

        Raises
        ------
        StateRejected
            For a missing, unknown or malformed field (named), a buffer whose times are not
            increasing or lie after ``t``.
        """
        from .state import StateRejected

        keys = ("t", "k", "running", "z", "xa", "thetahat", "buffer", "rows", "xhat0", "noted", "y", "ydot", "u")
        r = StateReader(state, keys, "observer")
        t, k, rows = r.number("t", 0.0), r.count("k"), r.count("rows")
        width = 1 + 2 * self.p + self.m
        buffer = r.vector("buffer", rows * width).reshape(rows, width)
        if rows and (np.any(np.diff(buffer[:, 0]) <= 0) or buffer[-1, 0] > t):
            raise StateRejected("observer state field 'buffer': its times must increase and not pass t")
        flags = {}
        for key in ("running", "noted"):
            if not isinstance(state[key], bool):
                raise StateRejected(f"observer state field {key!r}: expected true or false")
            flags[key] = state[key]
        na = self.xa.size
        new = {"z": r.vector("z", na), "xa": r.vector("xa", na), "thetahat": r.vector("thetahat", self.n_theta),
               "xhat0": r.vector("xhat0", self.n), "y": r.vector("y", self.p, finite=False),
               "ydot": r.vector("ydot", self.p, finite=False), "u": r.vector("u", self.m, finite=False)}
        self.t, self.k, self.buffer = t, k, buffer
        self.running, self._noted = flags["running"], flags["noted"]
        self.z, self.xa, self.thetahat, self.xhat0 = new["z"], new["xa"], new["thetahat"], new["xhat0"]
        self.y[:], self.ydot[:], self.u[:] = new["y"], new["ydot"], new["u"]

    # -- inputs -----------------------------------------------------------------------------------
    def set_y(self, y) -> None:
        """Measured outputs at the current communication point."""
        self.y[:] = y

    def set_ydot(self, ydot) -> None:
        """Their measured time derivative."""
        self.ydot[:] = ydot

    def set_u(self, u) -> None:
        """Known inputs (held over the step)."""
        self.u[:] = u

    # -- signals at any time ------------------------------------------------------------------------
    def _history(self, current) -> tuple:
        """The buffer and the current point ``(t, y, ydot, u)`` as arrays: times, outputs, derivatives, inputs."""
        b, p = self.buffer, self.p
        y0, yd0, u0 = current
        us = np.vstack([b[:, 1 + 2 * p:], u0])
        yds = np.vstack([b[:, 1 + p:1 + 2 * p], yd0])
        left = yds.copy()
        left[1:] -= (us[1:] - us[:-1]) @ self.CB.T          # the derivative before each input change
        return np.append(b[:, 0], self.t), np.vstack([b[:, 1:1 + p], y0]), yds, us, left

    def _now(self) -> tuple:
        """:meth:`_history` of the current inputs (cached until the state or an input changes)."""
        key = (self.k, self.t, self.y.tobytes(), self.ydot.tobytes(), self.u.tobytes(), self.buffer.shape[0])
        if getattr(self, "_cached", (None,))[0] != key:
            self._cached = (key, self._history((self.y, self.ydot, self.u)))
        return self._cached[1]

    def _augmented_at(self, s: float, hist) -> tuple:
        """``ya``, ``yadot``, ``ua`` at time ``s`` (current and delayed signals stacked): after the current
        point first-order held from it with its derivative, before it cubic Hermite between the buffer's
        points, ``u`` held."""
        times, ys, yds, us, left = hist
        out_y, out_yd, out_u = [], [], []
        for tau in [0.0] + self.delays:
            y, yd = hermite(times, ys, yds, s - tau, left)
            j = max(int(np.searchsorted(times, s - tau, side="right")) - 1, 0)
            out_y.append(y)
            out_yd.append(yd)
            out_u.append(us[j])
        return np.concatenate(out_y), np.concatenate(out_yd), np.concatenate(out_u)

    def _matrices(self, ya, yad):
        c = len(self.delays) + 1
        Da, Dadot = stacked(self.D0, self.Dy, ya.reshape(c, self.p), yad.reshape(c, self.p))
        H, Hdot, sigma = decoupling(self.Ca, Da, Dadot)
        return Da, H, Hdot, sigma

    def margin(self) -> float:
        """``sigma_min(Ca Da)`` at the current point (0 before every delayed signal exists)."""
        return self._signals()[0]

    def _signals(self) -> tuple:
        """``sigma_min(Ca Da)`` and ``||Gamma||_2`` at the current point (0 and inf before every delayed
        signal exists, or where the rank is lost)."""
        if self.t < self.tau:
            return 0.0, math.inf
        ya, yad, _ = self._augmented_at(self.t, self._now())
        _, H, Hdot, sigma = self._matrices(ya, yad)
        if H is None:
            return sigma, math.inf
        return sigma, float(np.linalg.norm(gamma(self.Aa, self.Ca, H, Hdot), 2))

    @property
    def valid(self) -> bool:
        """Whether the estimates are valid now: from ``valid_from``, margin at least ``sigma_bound`` and
        ``||Gamma||`` at most ``gamma_bound`` (the premise set the certificate covers)."""
        if self.t < self.valid_from:
            return False
        sigma, size = self._signals()
        return sigma >= self.sigma_bound and size <= self.gamma_bound

    # -- outputs ----------------------------------------------------------------------------------
    def xhat_augmented(self) -> np.ndarray:
        """The augmented estimate at the current point (held while invalid)."""
        if not self.running:
            return self.xa
        ya, yad, _ = self._augmented_at(self.t, self._now())
        H = self._matrices(ya, yad)[1]
        return self.xa if H is None else self.z - H @ ya

    def xhat(self) -> np.ndarray:
        """The estimate of the plant's state now."""
        return self.xhat_augmented()[:self.n]

    def theta(self) -> np.ndarray:
        """(34) with the measured derivatives, while valid; the last valid value otherwise."""
        if not (self.running and self.valid):
            return self.thetahat
        ya, yad, ua = self._augmented_at(self.t, self._now())
        Da = self._matrices(ya, yad)[0]
        F = self.Ca @ Da
        xa = self.xhat_augmented()
        return np.linalg.lstsq(F, yad - self.Ca @ (self.Aa @ xa + self.Ba @ ua), rcond=None)[0]

    def residual(self) -> np.ndarray:
        """``y - C xhat``."""
        return self.y - self.C @ self.xhat()

    # -- step -------------------------------------------------------------------------------------
    def _frozen(self, s: float, hist) -> tuple:
        """What the right-hand side needs at time ``s`` (it depends on ``s``, not on ``z``):
        ``N``, ``H ya`` and ``K ya + P Ba ua``, so that ``z' = N (z - H ya) + K ya + P Ba ua``."""
        ya, yad, ua = self._augmented_at(s, hist)
        _, H, Hdot, _ = self._matrices(ya, yad)
        if H is None:
            raise FloatingPointError("rank margin lost inside a step")
        N = gamma(self.Aa, self.Ca, H, Hdot) - self.K @ self.Ca
        P = np.eye(self.xa.size) + H @ self.Ca
        return N, H @ ya, self.K @ ya + P @ (self.Ba @ ua)

    def _predict(self, xa: np.ndarray, theta: np.ndarray, h: float, hist) -> np.ndarray:
        """The model's prediction over the step, ``xa' = Aa xa + Ba ua + Da(ya) thetahat`` (RK4, the signals
        as for the observer): what the estimate does while it is not valid."""
        steps = substeps(h, 1.0 / max(float(np.linalg.norm(self.Aa, 2)), 1e-300), MAX_SUBSTEPS,
                         "RK4 substeps of the model's prediction")
        dt = h / steps

        def f(s, x):
            ya, yad, ua = self._augmented_at(s, hist)
            Da = self._matrices(ya, yad)[0]
            return self.Aa @ x + self.Ba @ ua + Da @ theta

        for i in range(steps):
            s = self.t + i * dt
            k1 = f(s, xa)
            k2 = f(s + dt / 2, xa + dt / 2 * k1)
            k3 = f(s + dt / 2, xa + dt / 2 * k2)
            xa = xa + dt / 6 * (k1 + 2 * k2 + 2 * k3 + f(s + dt, xa + dt * k3))
        return xa

    def step(self, h: float) -> None:
        """Advance from ``t`` to ``t + h``: integrate the observer while valid; while not valid (start-up,
        rank margin below the premise bound) predict the estimate with the model and the held
        ``thetahat``, and restart the observer from it (``z = xhat + H ya``) when the margin returns.

        Raises
        ------
        RuntimeInputError
            A non-finite input or a step h <= 0 (nothing changes).
        StepRejected
            A step needing more than :data:`MAX_SUBSTEPS` substeps, a step after which the delay buffer would
            hold more than :func:`buffer_rows` points, or inputs (or a restored buffer) so large that the
            step's arithmetic overflows (nothing changes).
        """
        check_step(h, {"y": self.y, "ydot": self.ydot, "u": self.u}, self.k)
        try:
            with np.errstate(over="ignore", invalid="ignore"):      # judged by the finiteness of the result
                self._advance(float(h))
        except np.linalg.LinAlgError as exc:
            raise StepRejected(self._overflow(f"LinAlgError: {str(exc)[:80]}")) from None

    def _overflow(self, what: str) -> str:
        return (f"step {self.k} at t = {self.t:.6g} s: the observer's arithmetic overflows on these inputs and its "
                f"buffer of past outputs ({what}); nothing changed")

    def _advance(self, h: float) -> None:
        """:meth:`step` after its checks (assigns the new state only at its end)."""
        if not math.isfinite(self.t + h):
            raise StepRejected(f"t + h = {self.t + h!r} is not a time")
        times = np.append(self.buffer[:, 0], self.t)
        keep = np.flatnonzero(times <= self.t + h - self.tau)
        rows = times.size - (int(keep[-1]) if keep.size else 0)
        if rows > self.rows_max:
            raise StepRejected(f"step {self.k} at t = {self.t:.6g} s: the delay buffer would hold {rows} points, more "
                               f"than the {self.rows_max} it keeps (steps must average at least "
                               f"{self.tau / self.rows_max:.3g} s over the longest delay, {self.tau:.6g} s); nothing "
                               "changed")
        valid = self.valid
        xa_now = self.xhat_augmented()
        theta_now = self.theta()
        current = (self.y.copy(), self.ydot.copy(), self.u.copy())
        t0 = self.t
        z = self.z
        hist = self._now()
        notices = []                               # kept only if the step is taken
        steps = substeps(h, self.max_substep, MAX_SUBSTEPS, "RK4 substeps of the observer") if valid else None
        if steps and not self.running:             # start, or restart from the predicted estimate
            ya, yad, _ = self._augmented_at(t0, hist)
            z = xa_now + self._matrices(ya, yad)[1] @ ya
        running = bool(steps)
        if not steps and t0 >= self.tau:
            xa_now = self._predict(xa_now, theta_now, h, hist)
        if steps:
            dt = h / steps
            try:
                start = self._frozen(t0, hist)
                for i in range(steps):
                    s = t0 + i * dt
                    mid, end = self._frozen(s + dt / 2, hist), self._frozen(s + dt, hist)

                    def f(at, z):
                        return at[0] @ (z - at[1]) + at[2]

                    k1 = f(start, z)
                    k2 = f(mid, z + dt / 2 * k1)
                    k3 = f(mid, z + dt / 2 * k2)
                    k4 = f(end, z + dt * k3)
                    z = z + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
                    start = end
            except FloatingPointError:
                z, running = self.z, False
                notices.append(f"t = {t0:.6g} s: the rank margin vanished inside the step; the estimates are "
                               "held from here")
        if not all(np.all(np.isfinite(v)) for v in (xa_now, theta_now, z)):
            raise StepRejected(self._overflow("the new estimate is not finite"))
        self.notices += notices
        if not valid and not self._noted and t0 >= self.valid_from:
            self._noted = True
            sigma, size = self._signals()
            why = (f"rank margin sigma_min(C D_y) = {sigma:.3g} below the premise bound {self.sigma_bound:.3g}"
                   if sigma < self.sigma_bound else
                   f"||Gamma|| = {size:.3g} above the largest of the premise points certified, {self.gamma_bound:.3g}")
            self.notices.append(f"t = {t0:.6g} s: {why}: the estimates are not certified while it is, thetahat is "
                                "held (noted once)")
        row = np.concatenate([[t0], current[0], current[1], current[2]])
        buf = np.vstack([self.buffer, row[None]])
        keep = np.flatnonzero(buf[:, 0] <= t0 + h - self.tau)
        self.buffer = buf[keep[-1]:] if keep.size else buf
        self.xa, self.thetahat, self.z, self.running = xa_now, theta_now, z, running
        self.t, self.k = t0 + h, self.k + 1
