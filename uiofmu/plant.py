"""Linear plants: the typed, immutable model every family designs on.

A plant is either continuous, ``x' = A x + B u + E d`` (sampled at the communication points
with inputs held), or discrete, ``x+ = A x + B u + E d + w`` with period ``dt``; it is measured by
``y = C x + D u + F d`` (``D`` and ``F`` zero unless given: direct feedthrough of the known and the unknown
input).
:meth:`Plant.sampled` gives the exact zero-order-hold discretisation for any step ``h``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .runtime.errors import ProblemError
from .runtime.matrices import as_matrix, as_scalar, as_vector, freeze
from .threads import blas_module


#: Largest magnitude of a plant entry: products of a few such numbers stay finite in double precision.
MAX_ENTRY = 1e100
#: Shortest and longest period of a discrete plant, seconds (a nanosecond to about 32 years). A run of
#: up to ``cosim.steps.MAX_STEPS`` = 1e7 steps then ends before 1e16 s, where a double still resolves
#: the times ``k dt`` to 1e-8 of a step, and every count the tools form from a period (``t / dt``, the
#: default experiments' ``steps * dt``) stays finite; a subnormal or huge period (5e-324, 1e308)
#: overflows them.
MIN_PERIOD, MAX_PERIOD = 1e-9, 1e9


def period(value, key: str) -> float:
    """A discrete plant's period: a number > 0 within [:data:`MIN_PERIOD`, :data:`MAX_PERIOD`] seconds.

    Raises
    ------
    ProblemError
        Naming ``key``, the value and the range.
    """
    dt = as_scalar(value, key, low=0.0, open_low=True)
    if not MIN_PERIOD <= dt <= MAX_PERIOD:
        raise ProblemError(f"{key}: expected a period in [{MIN_PERIOD:g}, {MAX_PERIOD:g}] s, found {dt:g} (counts of "
                           "steps t / dt and stop times steps * dt must stay finite and exact): rescale time")
    return dt


def check_entries(matrices: dict) -> None:
    """Refuse an entry above :data:`MAX_ENTRY` in magnitude.

    Parameters
    ----------
    matrices : dict
        ``key -> array`` (``"plant.A" -> A``); the key names the entry in the message.

    Raises
    ------
    ProblemError
        Naming the first such entry (``plant.A[0][1]``), its value and the range.
    """
    for key, M in matrices.items():
        big = np.argwhere(np.abs(np.asarray(M, dtype=float)) > MAX_ENTRY)
        if big.size:
            at = "".join(f"[{i}]" for i in big[0])
            raise ProblemError(f"{key}{at}: {float(np.asarray(M)[tuple(big[0])]):g} is out of range: entries up to "
                               f"{MAX_ENTRY:g} in magnitude (products of such numbers overflow); rescale the units")


@dataclass(frozen=True)
class Sampled:
    """A plant over one step: ``x+ = A x + B u + E d + w`` (inputs held over the step)."""

    A: np.ndarray
    B: np.ndarray
    E: np.ndarray
    w: np.ndarray
    h: float


def discretize(A: np.ndarray, inputs: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation from the exponential of the augmented matrix.

    Parameters
    ----------
    A : (n, n) array
        Continuous state matrix.
    inputs : (n, k) array
        Input matrices side by side (e.g. ``[B E]``).
    h : float
        The step, > 0.

    Returns
    -------
    Ad : (n, n) array
        ``exp(A h)``.
    Gd : (n, k) array
        ``integral_0^h exp(A s) ds @ inputs``.
    """
    expm = blas_module("scipy.linalg").expm        # here, not at import: reading a card needs no scipy

    n, k = inputs.shape
    aug = np.zeros((n + k, n + k))
    aug[:n, :n] = A
    aug[:n, n:] = inputs
    with np.errstate(over="ignore", invalid="ignore"):
        scaled = aug * h
        ex = expm(scaled) if np.all(np.isfinite(scaled)) else scaled
    if not np.all(np.isfinite(ex)):
        raise ProblemError(f"sampling the plant over h = {h:g} s overflows (largest |A h| = "
                           f"{float(np.abs(A).max()) * h:.3g}): choose a shorter period or rescale time")
    return ex[:n, :n], ex[:n, n:]


@dataclass(frozen=True)
class Plant:
    """A linear plant with known input ``u`` (B), unknown input ``d`` (E) and output ``y = C x``.

    Build one with :meth:`Plant.create`, which checks every shape.

    Attributes
    ----------
    time : {"continuous", "discrete"}
    A, B, E, C : numpy.ndarray
        Read-only, shapes (n, n), (n, m), (n, q), (p, n).
    w : numpy.ndarray
        Constant affine term (discrete plants; zeros otherwise), shape (n,).
    dt : float or None
        Period of a discrete plant.
    x0 : numpy.ndarray
        Initial state (default zeros).
    W : numpy.ndarray
        Process-noise input matrix, shape (n, r) (``x+ = ... + W w_k`` or ``x' = ... + W w``; r = 0: none
        declared). The noise is no input of the design; it is what the card's ``noise.gain_w`` is about.
    D, F : numpy.ndarray
        Direct feedthrough of the known input (p, m) and of the unknown input (p, q) into
        ``y = C x + D u + F d`` (zeros unless given).
    """

    time: str
    A: np.ndarray
    B: np.ndarray
    E: np.ndarray
    C: np.ndarray
    w: np.ndarray
    dt: float | None
    x0: np.ndarray
    W: np.ndarray = None
    D: np.ndarray = None
    F: np.ndarray = None
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def n(self) -> int:
        """Number of states."""
        return self.A.shape[0]

    @property
    def m(self) -> int:
        """Number of known inputs."""
        return self.B.shape[1]

    @property
    def q(self) -> int:
        """Number of unknown inputs."""
        return self.E.shape[1]

    @property
    def p(self) -> int:
        """Number of measured outputs."""
        return self.C.shape[0]

    @property
    def r(self) -> int:
        """Number of process-noise inputs (columns of ``W``; 0 when none is declared)."""
        return 0 if self.W is None else self.W.shape[1]

    @property
    def feeds_u(self) -> bool:
        """Whether the known input feeds through to ``y`` (``D != 0``)."""
        return self.D is not None and bool(np.any(self.D))

    @property
    def feeds_d(self) -> bool:
        """Whether the unknown input feeds through to ``y`` (``F != 0``)."""
        return self.F is not None and bool(np.any(self.F))

    @property
    def feedthrough(self) -> bool:
        """Whether any input feeds through to ``y`` (``D != 0`` or ``F != 0``)."""
        return self.feeds_u or self.feeds_d

    @property
    def continuous(self) -> bool:
        """True for a continuous-time plant."""
        return self.time == "continuous"

    @classmethod
    def create(cls, A, C, E, B=None, *, time: str = "discrete", dt: float | None = None,
               w=None, x0=None, W=None, D=None, F=None, prefix: str = "plant") -> "Plant":
        """Check and normalise a plant.

        Parameters
        ----------
        A, C, E : array_like
            State, output and unknown-input matrices.
        B : array_like, optional
            Known-input matrix; omitted means no known input (m = 0).
        time : {"continuous", "discrete"}
            Time domain.
        dt : float, optional
            Period, required for a discrete plant, not allowed for a continuous one.
        w : array_like, optional
            Constant affine term of a discrete plant (default zeros).
        x0 : array_like, optional
            Initial state (default zeros).
        W : array_like, optional
            Process-noise input matrix, n rows (default none).
        D, F : array_like, optional
            Feedthrough of the known input (p x m) and of the unknown input (p x q) into ``y`` (default zeros).
        prefix : str
            Key prefix used in error messages (``"plant"`` gives ``plant.A``).

        Returns
        -------
        Plant

        Raises
        ------
        ProblemError
            Naming the key and the expected against the found shape or value.
        """
        if time not in ("continuous", "discrete"):
            raise ProblemError(f'{prefix}.time: expected "continuous" or "discrete", found {time!r}')
        A = as_matrix(A, f"{prefix}.A")
        n = A.shape[0]
        if A.shape[1] != n or n == 0:
            raise ProblemError(f"{prefix}.A: expected a square non-empty matrix, found {A.shape[0]}x{A.shape[1]}")
        C = as_matrix(C, f"{prefix}.C", cols=n)
        E = as_matrix(E, f"{prefix}.E", rows=n)
        B = freeze(np.zeros((n, 0))) if B is None else as_matrix(B, f"{prefix}.B", rows=n)
        if C.shape[0] == 0:
            raise ProblemError(f"{prefix}.C: expected at least one output row, found none")
        if time == "discrete":
            if dt is None:
                raise ProblemError(f"{prefix}.dt: required for a discrete plant (seconds per step)")
            dt = period(dt, f"{prefix}.dt")
        elif dt is not None:
            raise ProblemError(f"{prefix}.dt: only discrete plants have a period; a continuous plant is sampled "
                               "at the communication points")
        if w is not None and time == "continuous":
            raise ProblemError(f"{prefix}.w: the affine term is defined for discrete plants only")
        w = freeze(np.zeros(n)) if w is None else as_vector(w, f"{prefix}.w", size=n)
        x0 = freeze(np.zeros(n)) if x0 is None else as_vector(x0, f"{prefix}.x0", size=n)
        W = freeze(np.zeros((n, 0))) if W is None else as_matrix(W, f"{prefix}.W", rows=n)
        p = C.shape[0]
        D = freeze(np.zeros((p, B.shape[1]))) if D is None else as_matrix(D, f"{prefix}.D", rows=p, cols=B.shape[1])
        F = freeze(np.zeros((p, E.shape[1]))) if F is None else as_matrix(F, f"{prefix}.F", rows=p, cols=E.shape[1])
        check_entries({f"{prefix}.{key}": M for key, M in (("A", A), ("B", B), ("E", E), ("C", C), ("w", w),
                                                            ("x0", x0), ("W", W), ("D", D), ("F", F))})
        return cls(time=time, A=A, B=B, E=E, C=C, w=w, dt=dt, x0=x0, W=W, D=D, F=F)

    def sampled(self, h: float | None = None) -> Sampled:
        """The plant over one step of length ``h``.

        Parameters
        ----------
        h : float, optional
            Step length. A discrete plant has only its own ``dt`` (the default); a continuous
            plant is discretised exactly with inputs held (``h`` required).

        Returns
        -------
        Sampled
        """
        if not self.continuous:
            if h is not None and not abs(h - self.dt) <= 1e-12 * abs(self.dt):     # np.isclose's rule, for scalars
                raise ProblemError(f"a discrete plant steps at dt = {self.dt:g} s only, not h = {h:g} s")
            return Sampled(self.A, self.B, self.E, self.w, self.dt)
        if h is None or not h > 0:
            raise ProblemError(f"sampling a continuous plant needs a step h > 0, found {h}")
        key = float(h)
        if key not in self._cache:
            Ad, G = discretize(self.A, np.hstack([self.B, self.E]), key)
            self._cache[key] = Sampled(freeze(Ad), freeze(G[:, :self.m]), freeze(G[:, self.m:]),
                                       freeze(np.zeros(self.n)), key)
        return self._cache[key]

    def sampled_noise(self, h: float | None = None) -> np.ndarray:
        """``W`` over one step of length ``h``: a discrete plant's own, a continuous plant's sampled as ``E`` is
        (the noise held over the step; ``integral_0^h e^(A s) ds W``)."""
        W = np.zeros((self.n, 0)) if self.W is None else self.W
        if not self.continuous or not W.shape[1]:
            return np.asarray(W)
        return discretize(self.A, W, float(h))[1]

    def to_data(self) -> dict:
        """The plant as the ``[plant]`` table of a problem file (plain lists)."""
        data = {"time": self.time, "A": self.A.tolist(), "B": self.B.tolist(), "E": self.E.tolist(),
                "C": self.C.tolist(), "x0": self.x0.tolist()}
        if self.r:
            data["W"] = self.W.tolist()
        if self.feeds_u:
            data["D"] = self.D.tolist()
        if self.feeds_d:
            data["F"] = self.F.tolist()
        if not self.continuous:
            data["dt"] = self.dt
            data["w"] = self.w.tolist()
        return data


def plant_from_statespace(sys, E, x0=None) -> Plant:
    """A :class:`Plant` from a python-control ``StateSpace`` and the unknown-input matrix.

    Parameters
    ----------
    sys : control.StateSpace
        The plant with known inputs ``u``; its ``D`` is the feedthrough ``y = C x + D u``. ``sys.dt`` of
        0 (or None) means continuous time, a positive value a discrete plant of that period.
    E : array_like
        The unknown-input matrix, shape (n, q).
    x0 : array_like, optional
        Initial state.

    Returns
    -------
    Plant
    """
    D = np.asarray(sys.D, dtype=float)
    dt = getattr(sys, "dt", 0) or 0
    if dt is True:
        raise ProblemError("statespace.dt: a discrete plant needs a numeric period, found dt=True")
    time = "discrete" if dt else "continuous"
    B = np.asarray(sys.B, dtype=float)
    return Plant.create(np.asarray(sys.A, dtype=float), np.asarray(sys.C, dtype=float), E,
                        B if B.size else None, time=time, dt=float(dt) if dt else None, x0=x0,
                        D=D if B.size and np.any(D != 0) else None, prefix="statespace")
