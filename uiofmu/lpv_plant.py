"""LPV plants: discrete plants affine in a scheduling parameter theta, and where theta comes from.

A ``[plant]`` table with ``[[plant.scheduling]]`` is an LPV plant (seed 003)::

    x_{k+1} = A(theta_k) x_k + E(theta_k) d_k,     y_k = C(theta_k) x_k + D(theta_k) d_k
    A(theta) = A + sum_i theta^(i) A_i   (the same for E, C and D)

with one ``[[plant.scheduling]]`` table per component of theta, holding that component's parts
(``A``, ``E``, ``C``, ``D``; absent parts are zero). Every input is unknown: a known input ``B``
is refused (put its columns into ``E``). ``[plant.theta]`` says how the plant FMU produces theta:
``kind = "state"`` with ``theta_k = T x_k`` (an LPV plant whose theta is a function of its state
is a nonlinear plant written exactly), or ``kind = "input"`` (an input of the plant FMU).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .plant import check_entries, period
from .runtime.errors import ProblemError
from .runtime.matrices import as_matrix, freeze
from .table import Table

#: Most scheduling components.
MAX_THETA = 8
#: The parts a scheduling table may give.
PARTS = ("A", "E", "C", "D")
#: Where theta comes from.
THETA_KINDS = ("state", "input")


@dataclass(frozen=True)
class LpvPlant:
    """An LPV plant: the constant matrices, one set of parts per theta component, and theta's source.

    Attributes
    ----------
    A, E, C, D : numpy.ndarray
        The parts at theta = 0, shapes (n, n), (n, q), (p, n), (p, q).
    parts : tuple of dict
        Per component i, ``{"A": A_i, "E": E_i, "C": C_i, "D": D_i}`` (zeros where absent).
    theta : dict
        ``{"kind": "state", "T": (s, n) list}`` or ``{"kind": "input"}``.
    dt : float
    x0 : numpy.ndarray
    """

    A: np.ndarray
    E: np.ndarray
    C: np.ndarray
    D: np.ndarray
    parts: tuple
    theta: dict
    dt: float
    x0: np.ndarray

    time = "discrete"
    continuous = False

    n = property(lambda self: self.A.shape[0], doc="Number of states.")
    q = property(lambda self: self.E.shape[1], doc="Number of unknown inputs.")
    p = property(lambda self: self.C.shape[0], doc="Number of outputs.")
    s = property(lambda self: len(self.parts), doc="Number of scheduling components.")
    m = property(lambda self: 0, doc="Known inputs: none (every input of an LPV plant is unknown).")

    @property
    def B(self) -> np.ndarray:
        """No known input: an (n, 0) matrix."""
        return np.zeros((self.n, 0))

    @property
    def w(self) -> np.ndarray:
        """No affine term."""
        return np.zeros(self.n)

    def matrix(self, name: str, theta) -> np.ndarray:
        """``name(theta)`` (``"A"``, ``"E"``, ``"C"`` or ``"D"``) at one value of theta."""
        out = np.array(getattr(self, name), dtype=float)
        for value, part in zip(np.ravel(theta), self.parts):
            out = out + value * part[name]
        return out

    def to_data(self) -> dict:
        """The ``[plant]`` table as data (what the plant FMU runs)."""
        return {"time": "discrete", "dt": self.dt, "A": self.A.tolist(), "E": self.E.tolist(), "C": self.C.tolist(),
                "D": self.D.tolist(), "x0": self.x0.tolist(),
                "scheduling": [{k: v.tolist() for k, v in part.items()} for part in self.parts],
                "theta": {k: (v if k == "kind" else np.asarray(v).tolist()) for k, v in self.theta.items()}}


def parse_lpv(table) -> LpvPlant:
    """An :class:`LpvPlant` from the ``[plant]`` table (a :class:`uiofmu.problem.Table`) with
    ``[[plant.scheduling]]``; reads every key of the table.

    Raises
    ------
    ProblemError
        Naming the key: a continuous time, a known input, no or too many components, a part of
        the wrong shape, an entry above :data:`uiofmu.plant.MAX_ENTRY`, a period outside
        [:data:`uiofmu.plant.MIN_PERIOD`, :data:`uiofmu.plant.MAX_PERIOD`], an unknown key, a
        malformed ``[plant.theta]``.
    """

    time = table.choice("time", ("continuous", "discrete"))
    if time != "discrete":
        raise ProblemError(f'{table.key("time")}: an LPV plant is discrete (x_k+1 = A(theta_k) x_k + ...); '
                           f'found "{time}"')
    if table.has("B"):
        raise ProblemError(f"{table.key('B')}: every input of an LPV plant is unknown to the dead-beat functional "
                           "observer; put the known inputs' columns into plant.E")
    if table.has("w"):
        raise ProblemError(f"{table.key('w')}: an LPV plant has no affine term")
    A = as_matrix(table.get("A"), table.key("A"))
    n = A.shape[0]
    if A.shape[1] != n:
        raise ProblemError(f"{table.key('A')}: expected a square matrix, found {A.shape[0]}x{A.shape[1]}")
    E = as_matrix(table.get("E"), table.key("E"), rows=n)
    C = as_matrix(table.get("C"), table.key("C"), cols=n)
    D = as_matrix(table.get("D", np.zeros((C.shape[0], E.shape[1]))), table.key("D"), rows=C.shape[0],
                  cols=E.shape[1])
    dt = period(table.get("dt"), table.key("dt"))
    x0 = table.vector("x0", n, [0.0] * n)
    shapes = {"A": (n, n), "E": E.shape, "C": C.shape, "D": D.shape}
    raw = table.get("scheduling")
    if not isinstance(raw, list) or not 1 <= len(raw) <= MAX_THETA:
        found = f"{len(raw)} tables" if isinstance(raw, list) else type(raw).__name__
        raise ProblemError(f"{table.key('scheduling')}: expected 1 to {MAX_THETA} [[plant.scheduling]] tables (one "
                           f"per component of theta), found {found}")
    parts = []
    for i, entry in enumerate(raw):
        st = Table(entry, f"{table.key('scheduling')}[{i}]")
        part = {}
        for name in PARTS:
            value = st.get(name, None)
            rows, cols = shapes[name]
            part[name] = freeze(np.zeros(shapes[name]) if value is None else
                                as_matrix(value, st.key(name), rows=rows, cols=cols))
        check_entries({st.key(name): part[name] for name in PARTS})
        st.done(" (a scheduling table holds the parts A, E, C, D of one component of theta)")
        parts.append(part)
    tt = Table(table.get("theta", {"kind": "input"}), table.key("theta"))
    kind = tt.choice("kind", THETA_KINDS)
    theta = {"kind": kind}
    if kind == "state":
        theta["T"] = freeze(as_matrix(tt.get("T"), tt.key("T"), rows=len(parts), cols=n))
        check_entries({tt.key("T"): theta["T"]})
    tt.done()
    check_entries({table.key(key): M for key, M in (("A", A), ("E", E), ("C", C), ("D", D), ("x0", x0))})
    return LpvPlant(freeze(A), freeze(E), freeze(C), freeze(D), tuple(parts), theta, dt, freeze(np.asarray(x0)))
