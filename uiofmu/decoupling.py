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
from .structure import invariant_zeros, pbh_margins, rank, unobservable_modes
from .runtime.tolerances import RANK_RTOL, WEAK_MARGIN, ZERO_MARGIN


def decoupling_gain(C: np.ndarray, E: np.ndarray) -> np.ndarray:
    """``M = -E (CE)^+``, so that ``(I + M C) E = 0`` when ``rank(CE) = rank(E)``."""
    return -E @ np.linalg.pinv(C @ E)


def projector(C: np.ndarray, E: np.ndarray) -> np.ndarray:
    """``P = I + M C`` with :func:`decoupling_gain`."""
    return np.eye(C.shape[1]) + decoupling_gain(C, E) @ C


def in_unit_scale(C: np.ndarray, E: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``C`` with rows and ``E`` with columns of unit norm (zero ones left zero): the units of the outputs and
    of the unknown inputs, which change no rank and no zero, are out of the rank decisions (an ``E`` of 1e-10,
    the same plant with ``d`` in other units, was found of rank 0)."""
    C, E = np.asarray(C, dtype=float), np.asarray(E, dtype=float)
    rows = np.linalg.norm(C, axis=1) if C.size else np.zeros(C.shape[0])
    cols = np.linalg.norm(E, axis=0) if E.size else np.zeros(E.shape[1])
    return C / np.where(rows > 0, rows, 1.0)[:, None], E / np.where(cols > 0, cols, 1.0)[None, :]


def rank_condition(C: np.ndarray, E: np.ndarray, where: str = "", rank_rtol: float = RANK_RTOL) -> Condition:
    """``rank(CE) = rank(E)``: the unknown input can be decoupled (decided in unit scale, :func:`in_unit_scale`)."""
    C, E = in_unit_scale(C, E)
    rce, re = rank(C @ E, rank_rtol), rank(E, rank_rtol)
    holds = rce == re
    msg = (f"rank(CE) = {rce} = rank(E){where}" if holds else
           f"rank(CE) = {rce} < rank(E) = {re}{where}: the unknown input cannot be decoupled")
    return Condition("rank(CE) = rank(E)", holds, True, msg, {"rank_CE": rce, "rank_E": re})


def identifiability_condition(C: np.ndarray, E: np.ndarray, where: str = "",
                              rank_rtol: float = RANK_RTOL) -> Condition:
    """``rank(CE) = q``: the unknown input can be estimated (``dhat``); informational (in unit scale)."""
    C, E = in_unit_scale(C, E)
    rce, q = rank(C @ E, rank_rtol), E.shape[1]
    holds = rce == q
    msg = (f"rank(CE) = q = {q}{where}: dhat is estimated by inversion" if holds else
           f"rank(CE) = {rce} < q = {q}{where}: the unknown input is not identifiable, no dhat output")
    return Condition("rank(CE) = q", holds, False, msg, {"rank_CE": rce, "q": q})


def zeros_condition(A, E, C, continuous: bool, where: str = "", required: bool = True,
                    rank_rtol: float = RANK_RTOL, zero_margin: float = ZERO_MARGIN) -> tuple[Condition, np.ndarray]:
    """The invariant zeros of ``(A, E, C)`` and whether they are stable (in unit scale of ``C`` and ``E``)."""
    C, E = in_unit_scale(C, E)
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
    """Detectability of the decoupled pair ``((I + MC) A, C)``: its unmovable modes in |z| < 1 (in unit scale of
    ``C`` and ``E``, :func:`in_unit_scale`)."""
    C, E = in_unit_scale(C, E)
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


def weak_modes_condition(A, E, C, where: str = "", rank_rtol: float = RANK_RTOL,
                         weak_margin: float = WEAK_MARGIN) -> Condition:
    """The placeable modes of ``((I + MC) A, C)`` and how well ``C`` sees them (informational).

    A mode whose PBH margin (:func:`uiofmu.structure.pbh_margins`) is below ``weak_margin``
    can be placed only with gains of the order of ``1 / margin``: the condition then does not
    hold, and its message names the mode and the margin (designs of such plants are the ones
    that fail numerically; a slower decay or rescaled units help).

    Parameters
    ----------
    A, E, C : arrays
        The sampled plant.
    where : str
        Appended to the message (``" at h = 0.01 s"``).
    rank_rtol : float
        Margins at or below this count as fixed modes (not placeable).
    weak_margin : float
        Smallest margin of a mode that is placeable with moderate gains.

    Returns
    -------
    Condition
    """
    modes, margins = pbh_margins(projector(C, E) @ A, C)
    placeable = (margins > rank_rtol) & (np.abs(modes) > 1e-6)     # a mode at 0 needs no gain to move it
    values = {"modes": complex_list(modes[placeable]), "pbh_margins": margins[placeable].tolist(),
              "weak_margin": weak_margin}
    if not placeable.any():
        return Condition("well observable modes", True, False, f"no placeable mode{where}", values)
    i = int(np.flatnonzero(placeable)[np.argmin(margins[placeable])])
    weakest, margin = modes[i], float(margins[i])
    values.update({"weakest_mode": complex_list([weakest])[0], "weakest_margin": margin})
    if margin >= weak_margin:
        return Condition("well observable modes", True, False,
                         f"the weakest placeable mode {format_complex([weakest]) or f'{weakest.real:.6g}'}{where} has "
                         f"PBH margin {margin:.3g} (gains of order {1 / margin:.3g} move it)", values)
    return Condition("well observable modes", False, False,
                     f"the mode {format_complex([weakest]) or f'{weakest.real:.6g}'} of ((I+MC)A, C){where} is "
                     f"placeable only with gains of order 1/margin = {1 / margin:.3g} "
                     f"(PBH margin {margin:.3g} < {weak_margin:g}): "
                     "designs may fail numerically or need very large gains; a slower decay or rescaled units help",
                     values)


def sampled_decoupling_conditions(plant, s, dt: float) -> tuple[list, np.ndarray, bool]:
    """The classical conditions on a plant sampled at ``dt`` (a discrete plant as it is).

    Returns
    -------
    conditions : list of Condition
        Continuous-time zeros (informational, continuous plants), ``rank(CE) = rank(E)``,
        ``rank(CE) = q``, and when the rank condition holds the sampled invariant zeros and the
        fixed modes of ``((I + MC) A, C)``.
    fixed : numpy.ndarray
        The fixed modes (empty when the rank condition fails).
    decouplable : bool
        Whether ``rank(CE) = rank(E)``.
    """
    where = f" (sampled at dt = {dt:g} s)" if plant.continuous else ""
    conds = []
    if plant.continuous:
        conds.append(zeros_condition(plant.A, plant.E, plant.C, True, required=False)[0])
    rank_c = rank_condition(plant.C, s.E, where)
    conds += [rank_c, identifiability_condition(plant.C, s.E, where)]
    fixed = np.zeros(0, dtype=complex)
    if rank_c.holds:
        conds.append(zeros_condition(s.A, s.E, plant.C, False, where)[0])
        fc, fixed = fixed_modes_condition(s.A, s.E, plant.C, where)
        conds.append(fc)
        conds.append(weak_modes_condition(s.A, s.E, plant.C, where))
    return conds, fixed, rank_c.holds


def detectable(conditions: list) -> bool:
    """Whether the conditions of :func:`sampled_decoupling_conditions` found a detectable decoupled pair."""
    return any(c.name == "detectable decoupled pair" and c.holds for c in conditions)


def parse_period(table, plant, family: str) -> float:
    """``observer.dt``: required for a continuous plant, refused for a discrete one (its dt is used)."""
    from .runtime.errors import ProblemError

    if plant.continuous:
        if not table.has("dt"):
            raise table.missing("dt", f"required for a continuous plant (the sampling period the {family} "
                                "observer is designed for)")
        return table.scalar("dt", low=0.0, open_low=True)
    if table.has("dt"):
        raise ProblemError(f"observer.dt: a discrete plant fixes the period (plant.dt = {plant.dt:g}); "
                           "remove observer.dt")
    return plant.dt
