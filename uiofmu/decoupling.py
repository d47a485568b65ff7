"""Exact unknown-input decoupling, shared by the families that use it.

For a sampled plant ``x+ = A x + B u + E d`` measured by ``y = C x``, the gain
``M = -E (CE)^+`` (Darouach et al. 1994; seed 000 eq. (5) with Y = 0) makes
``P = I + M C`` annihilate the unknown input: ``P E = 0`` whenever
``rank(CE) = rank(E)``. The modes of ``P A`` that no output injection can move are the
unobservable modes of ``(P A, C)``; they are the invariant zeros of ``(A, E, C)``.
"""

from __future__ import annotations

import math
from dataclasses import replace
from itertools import combinations, islice

import numpy as np

from .existence import Condition, complex_list, format_complex
from .feedthrough import feedthrough_pair, feedthrough_rank_condition, unit_scaled
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


def no_dhat_condition(plant) -> Condition:
    """Informational: a plant whose inputs feed through to ``y`` gets no ``dhat`` output."""
    keys = " and ".join(k for k, on in (("D", plant.feeds_u), ("F", plant.feeds_d)) if on)
    return Condition("no dhat with feedthrough", False, False,
                     f"y = C x + D u + F d with {keys} != 0: no dhat output (its formula reads y_(k+1) - C A xhat_k - "
                     "C B u_k, which the feedthrough changes)", {"D": plant.feeds_u, "F": plant.feeds_d})


def zeros_condition(A, E, C, continuous: bool, where: str = "", required: bool = True,
                    rank_rtol: float = RANK_RTOL, zero_margin: float = ZERO_MARGIN,
                    F=None) -> tuple[Condition, np.ndarray]:
    """The invariant zeros of ``(A, E, C)`` (of ``(A, E, C, F)`` with the feedthrough ``F`` of the unknown input)
    and whether they are stable (in unit scale of ``C`` and ``E``, :func:`in_unit_scale`, or
    :func:`uiofmu.feedthrough.unit_scaled`)."""
    C, E, F = in_unit_scale(C, E) + (None,) if F is None else unit_scaled(C, E, F)
    z = invariant_zeros(A, E, C, F, rank_rtol=rank_rtol)
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
                          zero_margin: float = ZERO_MARGIN, F=None) -> tuple[Condition, np.ndarray]:
    """Detectability of the decoupled pair ``((I + MC) A, C)``: its unmovable modes in |z| < 1 (in unit scale of
    ``C`` and ``E``, :func:`in_unit_scale`); with the feedthrough ``F`` of the unknown input, of the pair
    ``(A0, O)`` of :func:`uiofmu.feedthrough.feedthrough_pair` (in its unit scale)."""
    if F is None:
        C, E = in_unit_scale(C, E)
        return _fixed(unobservable_modes(projector(C, E) @ A, C, rank_rtol), where, zero_margin, "((I+MC)A, C)")
    C, E, F = unit_scaled(C, E, F)
    pair = feedthrough_pair(A, E, C, F, rank_rtol)
    return _fixed(unobservable_modes(pair.A0, pair.O, rank_rtol), where, zero_margin, "(A0, O)")


def _fixed(fixed: np.ndarray, where: str, zero_margin: float, pair: str) -> tuple[Condition, np.ndarray]:
    """The detectability condition of the fixed modes of a decoupled ``pair`` (named in the message)."""
    moduli = np.abs(fixed)
    holds = bool(np.all(moduli < 1 - zero_margin))
    largest = float(moduli.max()) if moduli.size else 0.0
    if not fixed.size:
        msg = f"the decoupled pair {pair}{where} is observable: every mode can be placed"
    elif holds:
        msg = f"fixed modes of {pair}{where}: {format_complex(fixed)} (largest modulus {largest:.6g} < 1)"
    else:
        msg = (f"the decoupled pair {pair}{where} is not detectable: fixed mode(s) "
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


#: Most pairs of measured states :func:`measurement_hint` tries, after the single ones.
MAX_ROW_PAIRS = 300
#: Most sampled systems whose decoupling conditions :func:`measurement_hint`, and again :func:`period_hint`,
#: recompute (under a second each for a dozen states).
MAX_HINT_SYSTEMS = 500
#: The other sampling periods :func:`period_hint` tries, as multiples of the given one.
PERIOD_FACTORS = (0.25, 0.5, 2.0, 4.0)


def decoupling_verdict(A, E, C, target: str, where: str = "") -> tuple[Condition, bool]:
    """The conditions of exact decoupling of the sampled plant ``(A, E, C)``: the one named ``target`` (the rank
    condition when the rank fails first) and whether all of them hold (rank, stable zeros, detectable pair)."""
    conds = [rank_condition(C, E, where)]
    if conds[0].holds:
        conds += [zeros_condition(A, E, C, False, where)[0], fixed_modes_condition(A, E, C, where)[0]]
    named = [c for c in conds if c.name == target]
    return (named or conds)[0], all(c.holds for c in conds)


def _measured(rows) -> str:
    return " and ".join(f"x[{i + 1}]" for i in rows)


def _added(rows) -> str:
    return ("the row " if len(rows) == 1 else "the rows ") + ", ".join(f"e_{i + 1}'" for i in rows)


def measurement_hint(C: np.ndarray, verdict, max_pairs: int = MAX_ROW_PAIRS, cost: int = 1,
                     budget: int = MAX_HINT_SYSTEMS) -> str:
    """Which measured states, added to ``C`` as unit rows, make a failing condition hold.

    The single states ``C`` does not already measure are tried, then (when none makes every condition hold)
    up to ``max_pairs`` pairs of them, as long as the systems recomputed stay within ``budget``.

    Parameters
    ----------
    C : (p, n) array
    verdict : callable
        ``verdict(C2) -> (Condition, bool)``: the failing condition recomputed with the output matrix ``C2``,
        and whether every condition of the family's exact decoupling holds with it.
    max_pairs : int
        Most pairs of states tried.
    cost : int
        The sampled systems one call of ``verdict`` recomputes (one per sampling interval).
    budget : int
        Most sampled systems recomputed in all (:data:`MAX_HINT_SYSTEMS`).

    Returns
    -------
    str
        The hint (empty when ``C`` already measures every state): the states whose measurement makes every
        condition hold, else those that make the failing one hold, else that none of those tried helps.
    """
    n = C.shape[1]
    unit = np.eye(n)
    measures = rank(in_unit_scale(C, np.zeros((n, 0)))[0])
    new = [i for i in range(n) if rank(in_unit_scale(np.vstack([C, unit[i:i + 1]]), np.zeros((n, 0)))[0]) > measures]
    if not new:
        return ""
    trials = max(1, budget // max(cost, 1))
    singles = [(i,) for i in new][:trials]
    pairs = list(islice(combinations(new, 2), min(max_pairs, trials - len(singles))))
    partial = None
    for group in (singles, pairs):
        fits = []
        for rows in group:
            cond, every = verdict(np.vstack([C, unit[list(rows)]]))
            if every:
                fits.append((rows, cond))
            elif cond.holds and partial is None:
                partial = (rows, cond)
        if fits:
            return _measurement_text(fits)
    if partial:
        rows, cond = partial
        return (f"measuring {_measured(rows)} (adding {_added(rows)} to C): {cond.message}, but other conditions of "
                f"exact decoupling still fail (with each of the {len(singles)} state(s) and {len(pairs)} pair(s) "
                "tried)")
    return (f"no added measurement of one state (of the {len(singles)} tried) nor of a pair (of the {len(pairs)} "
            "tried) makes it hold")


def _measurement_text(fits: list) -> str:
    """The hint of the measurements ``(rows, condition)`` that make every condition hold (the first, and up to
    three others)."""
    rows, cond = fits[0]
    others = (", " if len(rows) == 1 else "; ").join(_measured(r) for r, _ in fits[1:4])
    more = f" (so does measuring {others}{', ...' if len(fits) > 4 else ''})" if others else ""
    return (f"measuring {_measured(rows)} (adding {_added(rows)} to C): {cond.message}, and every condition of exact "
            f"decoupling holds{more}")


def period_hint(periods, verdict, what: str = "dt", factors=PERIOD_FACTORS, budget: int = MAX_HINT_SYSTEMS) -> str:
    """Which other sampling makes the conditions of exact decoupling hold: ``periods`` times each of ``factors``
    (nothing is tried when that is more than ``budget`` sampled systems).

    Parameters
    ----------
    periods : sequence of float
        The sampling period(s) as given (s).
    verdict : callable
        ``verdict(periods2) -> bool``: whether every condition of exact decoupling holds when sampled at those.
    what : str
        The key that sets them, for the message.
    factors : sequence of float
        The multiples tried.
    budget : int
        Most sampled systems recomputed (:data:`MAX_HINT_SYSTEMS`).

    Returns
    -------
    str
        The periods that work, or that none of those tried does (empty when nothing is tried).
    """
    if not 0 < len(periods) * len(factors) <= budget:
        return ""
    good = [[f * h for h in periods] for f in factors if verdict([f * h for h in periods])]
    listed = (lambda hs: f"{hs[0]:g}") if len(periods) == 1 else (lambda hs: f"[{', '.join(f'{h:g}' for h in hs)}]")
    shown = " or ".join(listed(hs) for hs in good)
    tried = ", ".join(f"{f:g}" for f in factors)
    if good:
        return (f"sampling at {what} = {shown} s: every condition of exact decoupling holds there (tried {tried} "
                "times the given periods)")
    return f"no sampling at {tried} times the given {what} makes every condition of exact decoupling hold"


def either(*hints: str) -> str:
    """The non-empty hints joined by ``; or ``, those that found something first."""
    return "; or ".join(sorted((h for h in hints if h), key=lambda h: h.startswith("no ")))


def with_hint(conds: list, hint) -> list:
    """``conds`` with ``hint(condition)`` (a callable, called only then) on the first failing required condition,
    unless it has one."""
    failing = [i for i, c in enumerate(conds) if c.required and not c.holds]
    if not failing or conds[failing[0]].hint:
        return conds
    i = failing[0]
    return conds[:i] + [replace(conds[i], hint=hint(conds[i]))] + conds[i + 1:]


def short_below(x: float) -> float:
    """A number of three significant digits strictly below ``x > 0`` (the nearest one)."""
    return _short(x, -1)


def short_above(x: float) -> float:
    """A number of three significant digits strictly above ``x > 0`` (the nearest one)."""
    return _short(x, 1)


def _short(x: float, side: int) -> float:
    scale = 10.0 ** (2 - math.floor(math.log10(x)))
    k = math.floor(x * scale) if side < 0 else math.ceil(x * scale)
    if (k / scale - x) * side <= 0:                  # x has three digits itself
        k += side
    if k < 100:                                      # below a power of ten: 9.99 of the decade under it
        scale, k = 10 * scale, 999
    return float(f"{k / scale:.3g}")


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
    F = plant.F if getattr(plant, "feeds_d", False) else None
    conds = []
    if plant.continuous:
        conds.append(zeros_condition(plant.A, plant.E, plant.C, True, required=False, F=F)[0])
    if F is None:
        rank_c = rank_condition(plant.C, s.E, where)
    else:
        rank_c = feedthrough_rank_condition(plant.C, s.E, F, where)
    conds += [rank_c, no_dhat_condition(plant) if getattr(plant, "feedthrough", False) else
              identifiability_condition(plant.C, s.E, where)]
    fixed = np.zeros(0, dtype=complex)
    if rank_c.holds:
        conds.append(zeros_condition(s.A, s.E, plant.C, False, where, F=F)[0])
        fc, fixed = fixed_modes_condition(s.A, s.E, plant.C, where, F=F)
        conds.append(fc)
        if F is None:
            conds.append(weak_modes_condition(s.A, s.E, plant.C, where))
    if F is not None:                    # the hints recompute the conditions without feedthrough
        return conds, fixed, rank_c.holds

    def hint(failed: Condition) -> str:
        measure = measurement_hint(plant.C, lambda C2: decoupling_verdict(s.A, s.E, C2, failed.name, where))
        if not plant.continuous:
            return measure
        resampled = period_hint([dt], lambda hs: decoupling_verdict(plant.sampled(hs[0]).A, plant.sampled(hs[0]).E,
                                                                    plant.C, failed.name)[1], "observer.dt")
        return either(resampled, measure)

    return with_hint(conds, hint), fixed, rank_c.holds


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
