"""State scaling of an LMI design: the same LMIs in better-conditioned coordinates.

A plant whose states differ in scale by orders of magnitude (a position in m next to a
current in mA) gives LMIs whose variables differ as much; CLARABEL's tolerance is relative to
the largest of them, so the small ones lose their digits. A diagonal change of coordinates
``x = T xs``, ``T = diag(t)``, fixes that without changing the problem: the design LMIs are
written for ``(T^-1 A T, T^-1 E, T^-1 B, C T)`` and their variables mapped back by congruence,

    X = T^-T Xs T^-1        (Lyapunov matrices)
    W = T^-T Ws             (products X K, whose gain K = T Ks maps back by itself)

which turns each LMI of the scaled coordinates into the same LMI of the plant's coordinates,
pre- and post-multiplied by ``diag(T^-T, ...)`` and its transpose: feasible in one set of
coordinates exactly when feasible in the other. Only the normalisation (``Xs >= I`` becomes
``X >= T^-T T^-1``) and the numbers the solver sees change, unless the family writes its normalisations in
the plant's coordinates (``Xs >= T' T``, :func:`plant_identity`; lti-uio does), so that the least overshoot
its LMIs find is the plant's. The card's matrices are always in
the plant's coordinates, and the certificate is re-checked there.

The change is the reduction :class:`StateScaling` (:mod:`uiofmu.reductions`): ``apply`` builds the
LMIs of the scaled plant, ``invert`` maps their point back, each variable as it declares
(:data:`~uiofmu.reductions.LYAPUNOV` by congruence, :data:`~uiofmu.reductions.PRODUCT` from the left,
:data:`~uiofmu.reductions.UPPER_BOUND` by ``eig_max(T^-T T^-1)``, scalars unchanged).

``t`` is the diagonal balancing of ``A`` (the scaling of LAPACK's ``gebal``, which MATLAB's
``balance`` uses): powers of two, so the scaling itself is exact in floating point, divided by
the largest so that 1 is the largest entry. A plant whose rows and columns are already
balanced gets ``t = 1`` and the design it had without scaling.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from .reductions import CongruenceData, DiagonalCongruence, Reduction, congruent, roles
from .threads import blas_module

#: The values of ``observer.scaling``: balance the states (default), or design as given.
SCALINGS = ("balance", "none")


def state_scaling(A, kind: str = "balance") -> np.ndarray:
    """The diagonal ``t`` of the state scaling ``x = diag(t) xs`` for a plant matrix ``A``.

    Parameters
    ----------
    A : (n, n) array
        The plant's state matrix (continuous or discrete).
    kind : {"balance", "none"}
        ``"none"`` gives ones.

    Returns
    -------
    (n,) numpy.ndarray
        Powers of two, the largest 1.
    """
    A = np.asarray(A, dtype=float)
    if kind == "none" or A.size == 0 or not np.all(np.isfinite(A)):
        return np.ones(A.shape[0])
    matrix_balance = blas_module("scipy.linalg").matrix_balance

    _, (t, _) = matrix_balance(A, permute=False, separate=True)
    return np.asarray(t, dtype=float) / float(np.max(t))


def scaled_step(sample, t):
    """A sampled plant (:class:`uiofmu.plant.Sampled`) in the scaled coordinates:
    ``T^-1 A T``, ``T^-1 B``, ``T^-1 E``, ``T^-1 w``."""
    t = np.asarray(t, dtype=float)
    return replace(sample, A=sample.A * t[None, :] / t[:, None], B=sample.B / t[:, None],
                   E=sample.E / t[:, None], w=sample.w / t)


def scaled_output(C, t):
    """``C T``: the output matrix in the scaled coordinates."""
    return np.asarray(C, dtype=float) * np.asarray(t, dtype=float)[None, :]


def plant_identity(t) -> np.ndarray:
    """The plant's identity in the scaled coordinates, ``T' I T = diag(t**2)``: a Lyapunov matrix ``Xs`` of the
    scaled coordinates satisfies ``Xs >= T' T`` exactly when its plant's ``X = T^-T Xs T^-1`` satisfies ``X >= I``.
    Normalisations written with it (``Xs >= T' T``, ``Xs <= mu T' T``) bound the plant's overshoot
    ``sqrt(eig_max(X) / eig_min(X))`` by ``sqrt(mu)``: the least ``mu`` is then the figure the card records
    (the square of its overshoot bound), which the problem determines, rather than the scaled coordinates'
    own, whose minimisers may differ in the plant's overshoot."""
    t = np.asarray(t, dtype=float)
    return np.diag(t * t)


def identity_spread(t) -> float:
    """Largest over smallest entry of :func:`plant_identity` (``max(t)^2 / min(t)^2``): the
    :attr:`~uiofmu.lmi.LmiSystem.figure_spread` of LMIs normalised with it."""
    t = np.asarray(t, dtype=float)
    return float((t.max() / t.min()) ** 2) if t.size else 1.0


@dataclass(frozen=True)
class PlantLmis:
    """A family's LMIs over a plant, the problem :class:`StateScaling` accepts.

    Attributes
    ----------
    make : callable
        ``make(steps, C) -> LmiSystem``: the LMIs of the sampled steps and the output matrix.
    steps : list of Sampled
        The plant over each step (:class:`uiofmu.plant.Sampled`), in the plant's coordinates.
    C : (p, n) array
    """

    make: Callable
    steps: list
    C: np.ndarray


@dataclass(frozen=True)
class StateScaling(Reduction):
    """The change of coordinates ``x = diag(t) xs`` of the LMIs of a plant (see the module docstring).

    Parameters
    ----------
    t : (n,) array
        The diagonal of ``T`` (:func:`state_scaling`).
    """

    t: np.ndarray

    def coordinates(self, steps, C) -> tuple:
        """The steps and the output matrix in the scaled coordinates: ``T^-1 A T``, ``T^-1 B``,
        ``T^-1 E``, ``T^-1 w`` and ``C T``."""
        return [scaled_step(s, self.t) for s in steps], scaled_output(C, self.t)

    def apply(self, problem: PlantLmis) -> tuple:
        """``(system, inverse_data)``: the LMIs of the scaled plant, and the congruence ``T^-1`` with the roles
        its variables declare."""
        system = problem.make(*self.coordinates(problem.steps, problem.C))
        return system, CongruenceData(DiagonalCongruence(np.asarray(self.t, dtype=float)), roles(system.variables))

    def invert(self, values: dict, inverse_data: CongruenceData) -> dict:
        """A point of the scaled coordinates in the plant's: ``T^-T Xs T^-1`` for a Lyapunov matrix,
        ``T^-T Ws`` for a product ``X K`` (whose gain ``K = T Ks`` maps back by itself)."""
        return congruent(values, inverse_data)


def to_data(t, kind: str) -> dict:
    """The card's record of the scaling used (``observer.scaling`` and the diagonal of ``T``)."""
    return {"kind": kind, "state": np.asarray(t, dtype=float).tolist(),
            "rule": "the LMIs were solved in the coordinates xs = diag(state)^-1 x; the matrices are "
                    "in the plant's coordinates"}


__all__ = ["PlantLmis", "SCALINGS", "StateScaling", "identity_spread", "plant_identity", "scaled_output", "scaled_step",
           "state_scaling", "to_data"]
