"""Plants with unknown constant parameters entering through an output-dependent matrix (seed 001).

A ``[plant]`` table with ``[plant.parameters]`` is such a plant::

    x' = A x + B u + D(y) theta,   y = C x,   D(y) = D0 + sum_i y_i D_i,   theta' = 0

``[plant.parameters]`` holds the plant's true ``theta`` (what the plant FMU simulates; an observer
never reads it), an optional constant part ``D0`` and one ``[[plant.parameters.Dy]]`` table per
output that enters ``D(y)``: ``output`` (1-based) and its matrix ``D`` (n x n_theta). There is no
unknown input ``d`` besides theta. The plant is continuous and nonlinear (``D(C x) theta`` is
bilinear in x and theta); its FMU integrates it between communication points and outputs ``ydot``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .plant import check_entries
from .runtime.errors import ProblemError
from .runtime.matrices import as_matrix, as_vector, freeze
from .runtime.parametric_plant import MAX_RATE, SUBSTEP_FRACTION, rate
from .table import Table

#: Most unknown parameters.
MAX_THETA = 16


@dataclass(frozen=True)
class ParametricPlant:
    """A continuous plant with unknown constant parameters theta entering as ``D(y) theta``.

    Attributes
    ----------
    A, B, C : numpy.ndarray
        Shapes (n, n), (n, m), (p, n).
    D0 : numpy.ndarray
        The constant part of ``D(y)``, (n, n_theta).
    Dy : numpy.ndarray
        ``Dy[i]`` multiplies ``y_i`` in ``D(y)``, shape (p, n, n_theta) (zeros for outputs that do not enter).
    theta : numpy.ndarray
        The true parameters (simulated by the plant FMU, never read by an observer).
    x0 : numpy.ndarray
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D0: np.ndarray
    Dy: np.ndarray
    theta: np.ndarray
    x0: np.ndarray

    time = "continuous"
    continuous = True
    dt = None

    n = property(lambda self: self.A.shape[0], doc="Number of states.")
    m = property(lambda self: self.B.shape[1], doc="Number of known inputs.")
    p = property(lambda self: self.C.shape[0], doc="Number of outputs.")
    q = property(lambda self: 0, doc="Unknown inputs besides theta: none.")
    n_theta = property(lambda self: self.D0.shape[1], doc="Number of unknown parameters.")

    @property
    def E(self) -> np.ndarray:
        """No unknown input d: an (n, 0) matrix."""
        return np.zeros((self.n, 0))

    def D(self, y) -> np.ndarray:
        """``D(y) = D0 + sum_i y_i D_i``."""
        return self.D0 + np.tensordot(np.asarray(y, dtype=float), self.Dy, axes=1)

    def to_data(self) -> dict:
        """The ``[plant]`` table as data (what the plant FMU runs)."""
        return {"time": "continuous", "A": self.A.tolist(), "B": self.B.tolist(), "C": self.C.tolist(),
                "x0": self.x0.tolist(),
                "parameters": {"theta": self.theta.tolist(), "D0": self.D0.tolist(),
                               "Dy": [{"output": i + 1, "D": D.tolist()} for i, D in enumerate(self.Dy) if np.any(D)]}}


def parse_parametric(table) -> ParametricPlant:
    """A :class:`ParametricPlant` from the ``[plant]`` table with ``[plant.parameters]``; reads every key.

    Raises
    ------
    ProblemError
        Naming the key: a discrete plant, an unknown input ``E``, a malformed parameter table, an
        entry above :data:`uiofmu.plant.MAX_ENTRY`, a plant faster than
        :data:`uiofmu.runtime.parametric_plant.MAX_RATE`.
    """

    time = table.choice("time", ("continuous", "discrete"))
    if time != "continuous":
        raise ProblemError(f'{table.key("time")}: a plant with [plant.parameters] is continuous (seed 001); '
                           f'found "{time}"')
    for key in ("E", "w", "dt"):
        if table.has(key):
            raise ProblemError(f"{table.key(key)}: a plant with unknown parameters has no {key} (its unknown part is "
                               "D(y) theta)")
    A = as_matrix(table.get("A"), table.key("A"))
    n = A.shape[0]
    if A.shape[1] != n:
        raise ProblemError(f"{table.key('A')}: expected a square matrix, found {A.shape[0]}x{A.shape[1]}")
    C = as_matrix(table.get("C"), table.key("C"), cols=n)
    B = as_matrix(table.get("B", np.zeros((n, 0))), table.key("B"), rows=n)
    x0 = as_vector(table.get("x0", [0.0] * n), table.key("x0"), n)
    pt = Table(table.get("parameters"), table.key("parameters"))
    theta = as_vector(pt.get("theta"), pt.key("theta"))
    if not 1 <= theta.size <= MAX_THETA:
        raise ProblemError(f"{pt.key('theta')}: expected 1 to {MAX_THETA} parameters, found {theta.size}")
    D0 = as_matrix(pt.get("D0", np.zeros((n, theta.size))), pt.key("D0"), rows=n, cols=theta.size)
    Dy = np.zeros((C.shape[0], n, theta.size))
    entries = pt.get("Dy", [])
    if not isinstance(entries, list):
        raise ProblemError(f"{pt.key('Dy')}: expected [[plant.parameters.Dy]] tables, found {type(entries).__name__}")
    for j, entry in enumerate(entries):
        et = Table(entry, f"{pt.key('Dy')}[{j}]")
        out = et.get("output")
        if isinstance(out, bool) or not isinstance(out, int) or not 1 <= out <= C.shape[0]:
            raise ProblemError(f"{et.key('output')}: expected an output number from 1 to {C.shape[0]}, "
                               f"found {repr(out)[:40]}")
        if np.any(Dy[out - 1]):
            raise ProblemError(f"{et.key('output')}: output {out} is given twice")
        Dy[out - 1] = as_matrix(et.get("D"), et.key("D"), rows=n, cols=theta.size)
        et.done()
        check_entries({et.key("D"): Dy[out - 1]})
    pt.done(" (theta, D0 and the [[plant.parameters.Dy]] tables)")
    check_entries({table.key("A"): A, table.key("B"): B, table.key("C"): C, table.key("x0"): x0,
                   pt.key("theta"): theta, pt.key("D0"): D0})
    if not np.any(Dy) and not np.any(D0):
        raise ProblemError(f"{pt.key('Dy')}: D(y) is zero: theta does not enter the plant")
    fastest = rate(A, C, D0, Dy, theta)
    if not fastest <= MAX_RATE:
        raise ProblemError(f"{table.key('parameters')}: the plant's rate ||A|| + sum |D_i| max |theta| ||C|| + "
                           f"sum |D0| = {fastest:.3g} 1/s is out of range: at most {MAX_RATE:g} 1/s (its RK4 "
                           f"substep {SUBSTEP_FRACTION:g} / rate would be shorter than "
                           f"{SUBSTEP_FRACTION / MAX_RATE:g} s); rescale time or the parameters")
    return ParametricPlant(freeze(A), freeze(B), freeze(C), freeze(D0), freeze(Dy), freeze(theta), freeze(x0))
