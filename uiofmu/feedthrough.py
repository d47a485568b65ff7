"""Exact unknown-input decoupling of a plant whose unknown input feeds through to its output.

For the sampled plant ``x+ = A x + B u + E d + w`` measured by ``y = C x + D u + F d``, the observer::

    z+ = N z + L (y - D u) + G u + c,     xhat = z + H (y - D u)

has the error ``e = x - xhat = (I - HC) x - z - HF d``. It evolves as ``e+ = N e`` for every ``d`` exactly
when (with ``P = I - HC``, ``N = PA - KC``, ``L = K + NH``)::

    H F = 0,     P E = K F          i.e.   [H  K] S = [E  0],    S = [[CE, F], [F, 0]]

(``P A - N P - L C = 0`` holds by construction, ``G = P B``, ``c = P w``). The pair ``[H K]`` exists if and only if
the rows of ``[E 0]`` lie in the row space of ``S``, which is the rank condition

    rank [[CE, F], [F, 0]] = rank F + rank [E; F]

(the rows of ``CE`` are combinations of the rows of ``E``, so ``rank [S; [E 0]] = rank F + rank [E; F]``); with
``F = 0`` it is the classical ``rank(CE) = rank(E)``. Every solution is ``[H K] = [H0 K0] + Y (I - S S^+)`` with
``[H0 K0] = [E 0] S^+``, so that::

    N = A - H C A - K C = A0 - Y O,     A0 = A - H0 C A - K0 C,     O = (I - S S^+) [CA; C]

and the modes no ``Y`` moves (the fixed modes) are the unobservable modes of the pair ``(A0, O)``. ``D`` is a
known-input correction: it changes neither the conditions nor ``N``; the card's matrices absorb it as
``G = P B - L D`` and the direct term ``Xu = -H D`` of ``xhat``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .existence import Condition
from .structure import rank
from .runtime.tolerances import RANK_RTOL

__all__ = ["FeedthroughPair", "feedthrough_pair", "feedthrough_rank_condition", "unit_scaled"]


def unit_scaled(C: np.ndarray, E: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``C``, ``E`` and ``F`` in the units where each row of ``[C F]`` and each column of ``[E; F]`` has norm 1
    (zero ones left zero): the units of the outputs and of the unknown inputs change no rank."""
    C, E, F = (np.asarray(M, dtype=float) for M in (C, E, F))
    rows = np.linalg.norm(np.hstack([C, F]), axis=1)
    cols = np.linalg.norm(np.vstack([E, F]), axis=0) if E.size else np.zeros(E.shape[1])
    r = np.where(rows > 0, rows, 1.0)[:, None]
    c = np.where(cols > 0, cols, 1.0)[None, :]
    return C / r, E / c, F / r / c


def _stacked(C: np.ndarray, E: np.ndarray, F: np.ndarray) -> np.ndarray:
    """``S = [[CE, F], [F, 0]]``."""
    q = E.shape[1]
    return np.block([[C @ E, F], [F, np.zeros((F.shape[0], q))]])


def feedthrough_rank_condition(C: np.ndarray, E: np.ndarray, F: np.ndarray, where: str = "",
                               rank_rtol: float = RANK_RTOL) -> Condition:
    """``rank [[CE, F], [F, 0]] = rank F + rank [E; F]``: the unknown input that also feeds through to ``y``
    can be decoupled (decided in unit scale, :func:`unit_scaled`)."""
    C, E, F = unit_scaled(C, E, F)
    rs, rf, ref = rank(_stacked(C, E, F), rank_rtol), rank(F, rank_rtol), rank(np.vstack([E, F]), rank_rtol)
    holds = rs == rf + ref
    values = {"rank_S": rs, "rank_F": rf, "rank_EF": ref}
    if holds:
        msg = f"rank [[CE, F], [F, 0]] = {rs} = rank F + rank [E; F] = {rf} + {ref}{where}"
    else:
        msg = (f"rank [[CE, F], [F, 0]] = {rs} < rank F + rank [E; F] = {rf} + {ref} = {rf + ref}{where}: the "
               "unknown input, which also feeds through to y, cannot be decoupled")
    return Condition("rank [[CE, F], [F, 0]] = rank F + rank [E; F]", holds, True, msg, values)


@dataclass(frozen=True)
class FeedthroughPair:
    """The decoupled pair of a plant with ``F != 0`` and the particular solution it starts from.

    Attributes
    ----------
    A0 : (n, n) array
        ``A - H0 C A - K0 C``.
    O : (2p, n) array
        ``(I - S S^+) [CA; C]``: the output the free gain ``Y`` injects (``N = A0 - Y O``).
    H0, K0 : (n, p) arrays
        The least-norm solution of ``[H K] S = [E 0]``.
    Pi : (2p, 2p) array
        ``I - S S^+``: ``[H K] = [H0 K0] + Y Pi``.
    """

    A0: np.ndarray
    O: np.ndarray
    H0: np.ndarray
    K0: np.ndarray
    Pi: np.ndarray

    def gains(self, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(H, K)`` of the free gain ``Y`` (n x 2p)."""
        p = self.H0.shape[1]
        HK = np.hstack([self.H0, self.K0]) + Y @ self.Pi
        return HK[:, :p], HK[:, p:]


def feedthrough_pair(A: np.ndarray, E: np.ndarray, C: np.ndarray, F: np.ndarray,
                     rank_rtol: float = RANK_RTOL) -> FeedthroughPair:
    """The decoupled pair ``(A0, O)`` of the sampled plant ``(A, E, C, F)`` (see the module docstring).

    ``S^+`` and ``I - S S^+`` are those of the SVD of ``S`` with the rank rule of :func:`uiofmu.structure.rank`
    (so that a singular value at round-off is not inverted).
    """
    A, E, C, F = (np.asarray(M, dtype=float) for M in (A, E, C, F))
    n, p = A.shape[0], C.shape[0]
    S = _stacked(C, E, F)
    U, s, Vt = np.linalg.svd(S, full_matrices=True)
    r = int(np.sum(s > rank_rtol * max(1.0, s[0]))) if s.size else 0
    S_pinv = Vt[:r].T @ np.diag(1.0 / s[:r]) @ U[:, :r].T
    Pi = U[:, r:] @ U[:, r:].T
    HK0 = np.hstack([E, np.zeros((n, E.shape[1]))]) @ S_pinv
    H0, K0 = HK0[:, :p], HK0[:, p:]
    A0 = A - H0 @ C @ A - K0 @ C
    O = Pi @ np.vstack([C @ A, C])
    return FeedthroughPair(A0, O, H0, K0, Pi)
