"""Exact unknown-input decoupling, shared by the families that use it.

For a sampled plant ``x+ = A x + B u + E d`` measured by ``y = C x``, the gain
``M = -E (CE)^+`` (Darouach et al. 1994; seed 000 eq. (5) with Y = 0) makes
``P = I + M C`` annihilate the unknown input: ``P E = 0`` whenever
``rank(CE) = rank(E)``. The modes of ``P A`` that no output injection can move are the
unobservable modes of ``(P A, C)``; they are the invariant zeros of ``(A, E, C)``.
"""

from __future__ import annotations

import numpy as np

from .existence import Condition, complex_list, format_complex
from .structure import invariant_zeros, rank, unobservable_modes
from .tolerances import RANK_RTOL, ZERO_MARGIN


def decoupling_gain(C: np.ndarray, E: np.ndarray) -> np.ndarray:
    """``M = -E (CE)^+``, so that ``(I + M C) E = 0`` when ``rank(CE) = rank(E)``."""
    return -E @ np.linalg.pinv(C @ E)


def projector(C: np.ndarray, E: np.ndarray) -> np.ndarray:
    """``P = I + M C`` with :func:`decoupling_gain`."""
    return np.eye(C.shape[1]) + decoupling_gain(C, E) @ C


def rank_condition(C: np.ndarray, E: np.ndarray, where: str = "", rank_rtol: float = RANK_RTOL) -> Condition:
    """``rank(CE) = rank(E)``: the unknown input can be decoupled."""
    rce, re = rank(C @ E, rank_rtol), rank(E, rank_rtol)
    holds = rce == re
    msg = (f"rank(CE) = {rce} = rank(E){where}" if holds else
           f"rank(CE) = {rce} < rank(E) = {re}{where}: the unknown input cannot be decoupled")
    return Condition("rank(CE) = rank(E)", holds, True, msg, {"rank_CE": rce, "rank_E": re})


def identifiability_condition(C: np.ndarray, E: np.ndarray, where: str = "",
                              rank_rtol: float = RANK_RTOL) -> Condition:
    """``rank(CE) = q``: the unknown input can be estimated (``dhat``); informational."""
    rce, q = rank(C @ E, rank_rtol), E.shape[1]
    holds = rce == q
    msg = (f"rank(CE) = q = {q}{where}: dhat is estimated by inversion" if holds else
           f"rank(CE) = {rce} < q = {q}{where}: the unknown input is not identifiable, no dhat output")
    return Condition("rank(CE) = q", holds, False, msg, {"rank_CE": rce, "q": q})


def zeros_condition(A, E, C, continuous: bool, where: str = "", required: bool = True,
                    rank_rtol: float = RANK_RTOL, zero_margin: float = ZERO_MARGIN) -> tuple[Condition, np.ndarray]:
    """The invariant zeros of ``(A, E, C)`` and whether they are stable."""
    z = invariant_zeros(A, E, C, rank_rtol=rank_rtol)
    if continuous:
        holds = bool(np.all(z.real < -zero_margin))
        rule = "Re(z) < 0"
    else:
        holds = bool(np.all(np.abs(z) < 1 - zero_margin))
        rule = "|z| < 1"
    moduli = np.abs(z)
    msg = (f"invariant zeros{where}: {format_complex(z)}" + (f" (all {rule})" if holds and z.size else "")
           + ("" if holds else f": not all {rule} (largest modulus {moduli.max():.6g})"))
    return Condition("stable invariant zeros" if required else "invariant zeros (continuous time)", holds,
                     required, msg, {"zeros": complex_list(z), "moduli": moduli.tolist(),
                                     "real_parts": z.real.tolist()}), z


def fixed_modes_condition(A, E, C, where: str = "", rank_rtol: float = RANK_RTOL,
                          zero_margin: float = ZERO_MARGIN) -> tuple[Condition, np.ndarray]:
    """Detectability of the decoupled pair ``((I + MC) A, C)``: its unmovable modes in |z| < 1."""
    fixed = unobservable_modes(projector(C, E) @ A, C, rank_rtol)
    moduli = np.abs(fixed)
    holds = bool(np.all(moduli < 1 - zero_margin))
    largest = float(moduli.max()) if moduli.size else 0.0
    if not fixed.size:
        msg = f"the decoupled pair ((I+MC)A, C){where} is observable: every mode can be placed"
    elif holds:
        msg = f"fixed modes of ((I+MC)A, C){where}: {format_complex(fixed)} (largest modulus {largest:.6g} < 1)"
    else:
        msg = (f"the decoupled pair ((I+MC)A, C){where} is not detectable: fixed mode(s) "
               f"{format_complex(fixed[moduli >= 1 - zero_margin])} with modulus >= 1")
    return Condition("detectable decoupled pair", holds, True, msg,
                     {"fixed_modes": complex_list(fixed), "moduli": moduli.tolist(),
                      "largest_modulus": largest}), fixed
