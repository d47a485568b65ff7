"""Sampled-data UIO under time-varying sampling (Etienne, Langueh, Hetel, ECC 2023; seed 004).

A continuous plant ``x' = A x + B u + E d``, ``y = C x`` is sampled with intervals ``h_k``
from a finite set ``{H_1..H_N}`` (inputs held). With ``A_i, B_i, E_i`` its exact sampling at
``H_i`` (exponential of the augmented matrix), the observer (paper (6), with the known input)::

    xhat_k  = z_k + K_j y_k                          j: index of h_{k-1}
    z_{k+1} = L_ij z_k + P_ij y_k + G_i u_k          i: index of h_k

gives ``e_{k+1} = L_ij e_k`` when (12) ``L_ij = (I - K_i C) A_i + L_ij K_j C - P_ij C`` and
(13) ``(I - K_i C) E_i = 0``, with ``G_i = (I - K_i C) B_i``. Corollary 2's LMIs, with
``Pl_i`` the Lyapunov matrices::

    (16)  Pl_i E_i - S_i C E_i = 0                                  (E_i scaled to unit norm)
    (15)  [[Pl_i, Pl_i A_i - S_i C A_i - Q_ij C], [*, (1 - alpha) Pl_j]] > 0    for all i, j
          I <= Pl_i <= mu I   (normalisation; mu minimised: the overshoot bound is sqrt(mu))

solved in the balanced coordinates of :mod:`uiofmu.scaling` (``observer.scaling``), and the
gains ``K_i = Pl_i^{-1} S_i``, ``L_ij = (I - K_i C) A_i - Pl_i^{-1} Q_ij C``,
``P_ij = Pl_i^{-1} Q_ij + L_ij K_j``. The paper prints (19) with ``- L_ij K_j``, which
violates (12) (residual 1.5 on the building); the ``+`` sign is the one that satisfies it.
``K_i`` is then moved onto the affine set ``K C E_i = E_i`` (a change of the order of the
solver tolerance) so that (13) and (12) hold to round-off; the re-check runs on those stored
matrices. With ``V_k = e_k' Pl(h_{k-1}) e_k``, ``||e_k|| <= M delta^k ||e_0||`` for every
sequence of intervals, ``delta = sqrt(1 - alpha)``, ``M = sqrt(max eig Pl / min eig Pl)``;
the bound holds from k = 0 because ``z_0 = xhat_0 - K(h_{-1}) y_0`` with a stated ``h_{-1}``.

No exactly-decoupling observer converges faster than the sampled invariant zeros: a mode at
``z(H_i)`` of ``(A_i, E_i, C)`` stays in every ``L_ij``, so ``delta > max |z(H_i)|``, i.e.
``alpha < 1 - max |z|^2``. :func:`check` says so before any solve. With as many outputs as
unknown inputs (``p = q``) there is more: ``K_i`` is forced, ``ker C`` is invariant under every
``L_ij`` whatever its other gains, and the error there evolves by fixed maps ``F_i``
(:func:`fixed_error_maps`); when a repeated sequence of intervals multiplies it by 1 or more per
sample, no exactly-decoupling observer converges for every sequence, and :func:`check` says which.
Corollary 2 reduces exactly to ``ker C`` there (:class:`KerC`, :func:`_reduced_lmis`), written in increment form
(the decrease ``(1 - alpha) P_j - F_i' P_i F_i`` as an explicit block, which near the limit the Schur
form loses in the solver's cancellation) and recentred on a refused point when its Lyapunov
matrices are too ill-conditioned for the solver's tolerance; :func:`check` proves that no
certificate exists when the largest margin of those LMIs (:func:`best_margin`) is negative.

Noise (``y_k = C x_k + v_k``): ``gain_y`` and, where the card has dhat, ``gain_dhat_y`` hold for every sequence of
design intervals (:func:`noise_of`). dhat after the interval ``h_k`` reads the next sample, so its error
``Dy_i (C A_i e_k + v_(k+1))`` is a system one step ahead with the state ``(eps, v_prev)``, certified by the
poly-quadratic bounded real lemma as ``gain_y`` is (:func:`uiofmu.noise.pair_dhat_error_system`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..runtime.card import DHAT, MAX_INTERVALS
from ..certificate import (
    Check,
    certificate,
    decay_check,
    identity_check,
    figure_digits,
    overshoot,
    overshoot_check,
    positive_check,
    rounding_floor,
)
from ..gains import cap_lmis, two_norms
from ..decoupling import (
    decoupling_verdict,
    either,
    fixed_modes_condition,
    identifiability_condition,
    measurement_hint,
    period_hint,
    rank_condition,
    short_below,
    weak_modes_condition,
    with_hint,
    zeros_condition,
)
from ..consistency import Determined, computed_values, dhat_record, eigen_rtol, spectrum
from ..runtime.errors import InfeasibleError, ProblemError
from ..certificate import UNDETERMINED
from ..structure import kernel_maps, product_radius
from ..existence import Condition, Existence, complex_list, from_pairs
from ..lmi import Lmi, LmiSystem, tune
from ..reductions import UPPER_BOUND, Recentring, Reduction, matrix, scalar, symmetric
from ..scaling import SCALINGS, PlantLmis, StateScaling, state_scaling
from ..scaling import to_data as scaling_data
from ..runtime.schedules import STEP_POLICIES
from ..runtime.tolerances import (
    IDENTITY_RTOL,
    LMI_MARGIN,
    ROUNDING_FACTOR,
    MARGIN_PROOF_RTOL,
    SEARCH_TOL,
    STEP_RTOL,
    VERIFY_FRACTION,
    ZERO_MARGIN,
)
from ..noise import (NOISE_METHOD, NOISE_OBJECTIVES, certified, least_noise_design, pair_checks, pair_error_system,
                     pair_noise_gain, pair_noise_lmis, pair_section)
from . import Analysis, DesignResult

NAME = "sampled-data"

#: What a sampled-data card's noise section says of the gains it has not.
NO_W = "gain_w: the problem declares no process noise"


@dataclass(frozen=True)
class Options:
    """Options of the sampled-data UIO.

    Attributes
    ----------
    intervals : tuple of float
        The design sampling intervals (s), increasing.
    alpha : float or "max"
        Decay parameter of (15): the error contracts by ``sqrt(1 - alpha)`` per sample.
    xhat0 : numpy.ndarray or None
        Initial estimate.
    h_prev0 : float
        The interval assumed before the first sample, h_{-1} (default the first interval).
    step_policy : {"error", "nearest"}
        What the runtime does with a step that is not a design interval.
    scaling : {"balance", "none"}
        The coordinates the LMIs are solved in (:mod:`uiofmu.scaling`).
    gain_cap : float or None
        Bound on ``||K_i||_2`` and ``||Pl_i^-1 Q_ij||_2`` (:mod:`uiofmu.gains`), None for none.
    noise : {"default", "min"}
        ``"min"``: the gains ``Pl_i^-1 Q_ij`` that minimise ``gain_y`` at the decay (see the module).
    noise_gain : float or None
        The fastest decay whose least-noise design has a certified ``gain_y`` of at most this.
    """

    intervals: tuple
    alpha: object
    xhat0: np.ndarray | None
    h_prev0: float
    step_policy: str
    scaling: str = "balance"
    gain_cap: float | None = None
    noise: str = "default"
    noise_gain: float | None = None

    @property
    def decay(self):
        """The decay asked for: ``"max"``, or ``sqrt(1 - alpha)`` (:mod:`uiofmu.tradeoff` reads it)."""
        return self.alpha if self.alpha == "max" else float(np.sqrt(1.0 - self.alpha))

    @property
    def step(self) -> float:
        """The communication step a co-simulation takes by default: the first design interval."""
        return self.intervals[0]


def _intervals(table) -> tuple:
    key = table.key("intervals")
    if not table.has("intervals"):
        raise table.missing("intervals", "required: the sampling intervals in seconds this observer is designed "
                            "for, a list (intervals = [0.01] for one period) or a range (intervals = {min = 0.01, "
                            "max = 0.05, count = 5})" + ("; observer.dt is not a key of this family"
                                                         if table.has("dt") else ""))
    value = table.get("intervals")
    if isinstance(value, dict):
        sub = type(table)(value, key)
        lo = sub.scalar("min", low=0.0, open_low=True)
        hi = sub.scalar("max", low=0.0, open_low=True)
        count = sub.get("count")
        sub.done()
        if isinstance(count, bool) or not isinstance(count, int) or not 1 <= count <= MAX_INTERVALS:
            raise ProblemError(f"{key}.count: expected an integer from 1 to {MAX_INTERVALS}, found {repr(count)[:40]}")
        if hi < lo or (count == 1 and hi != lo):
            raise ProblemError(f"{key}: expected min <= max (and min = max for count = 1), found {lo:g}, {hi:g}")
        values = np.linspace(lo, hi, count)
    elif isinstance(value, list):
        values = np.array(table.vector("intervals"))
    else:
        raise ProblemError(f"{key}: expected a list of intervals in s or a table {{min, max, count}}, "
                           f"found {type(value).__name__}")
    if values.size > MAX_INTERVALS:
        raise ProblemError(f"{key}: at most {MAX_INTERVALS} intervals, found {values.size}")
    if values.size == 0 or np.any(values <= 0):
        raise ProblemError(f"{key}: expected positive intervals, found {values.tolist()}")
    values = np.sort(values)
    close = np.flatnonzero(np.diff(values) <= 2 * STEP_RTOL * values[1:])
    if close.size:
        raise ProblemError(f"{key}: intervals {values[close[0]]:g} and {values[close[0] + 1]:g} coincide "
                           f"within the step tolerance {STEP_RTOL:g}")
    return tuple(float(v) for v in values)


def parse_options(table, plant) -> Options:
    """Read ``intervals``, ``alpha``, ``xhat0``, ``h_prev0``, ``step_policy``, ``scaling`` and ``gain_cap``."""
    if not plant.continuous:
        raise ProblemError(f'observer.family: "{NAME}" samples a continuous plant; plant.time is "discrete" '
                           '(use "lti-uio" for a discrete plant)')
    intervals = _intervals(table)
    alpha = table.tunable("alpha", "max", low=0.0, high=1.0, open_low=True, open_high=True)
    xhat0 = table.vector("xhat0", plant.n, None)
    h_prev0 = table.scalar("h_prev0", intervals[0], low=0.0, open_low=True)
    if min(abs(h_prev0 - h) / h for h in intervals) > STEP_RTOL:
        raise ProblemError(f"observer.h_prev0: {h_prev0:g} s is not one of the intervals "
                           f"{', '.join(f'{h:g}' for h in intervals)} s")
    policy = table.choice("step_policy", STEP_POLICIES, "error")
    noise = table.choice("noise", NOISE_OBJECTIVES, "default")
    noise_gain = table.scalar("noise_gain", None, low=0.0, open_low=True)
    if noise_gain is not None and alpha != "max":
        raise ProblemError(f"observer.noise_gain = {noise_gain:g} asks for the fastest decay whose certified gain_y "
                           f"is at most {noise_gain:g}: leave observer.alpha unset (or \"max\"), found {alpha!r}")
    return Options(intervals, alpha, xhat0, h_prev0, policy, table.choice("scaling", SCALINGS, "balance"),
                   table.scalar("gain_cap", None, low=0.0, open_low=True), noise, noise_gain)


def _per_interval(conds: list[Condition], name: str, intervals) -> Condition:
    """One condition from one per interval: holds when all hold; the message of the worst."""
    failed = [c for c in conds if not c.holds]
    lead = failed[0] if failed else conds[0]
    others = len(conds) - 1
    msg = lead.message if failed or not others else f"{lead.message}; likewise at the other {others} interval(s)"
    return Condition(name, not failed, conds[0].required, msg,
                     {"per_interval": [{"h": h, **c.values} for h, c in zip(intervals, conds)]})


def _analysis(problem, solver: bool = True):
    plant, opts = problem.plant, problem.options
    samples = [plant.sampled(h) for h in opts.intervals]
    zc, _ = zeros_condition(plant.A, plant.E, plant.C, True, required=False)
    conds = [zc]
    ranks = [rank_condition(plant.C, s.E, f" at h = {h:g} s") for h, s in zip(opts.intervals, samples)]
    conds.append(_per_interval(ranks, "rank(C E(h)) = rank(E(h))", opts.intervals))
    conds.append(_per_interval([identifiability_condition(plant.C, s.E, f" at h = {h:g} s")
                                for h, s in zip(opts.intervals, samples)], "rank(C E(h)) = q", opts.intervals))
    zmax, zarg = 0.0, opts.intervals[0]
    floor = 0.0
    if all(c.holds for c in ranks):
        zeros = [zeros_condition(s.A, s.E, plant.C, False, f" at h = {h:g} s")
                 for h, s in zip(opts.intervals, samples)]
        fixed = [fixed_modes_condition(s.A, s.E, plant.C, f" at h = {h:g} s")
                 for h, s in zip(opts.intervals, samples)]
        conds.append(_per_interval([z[0] for z in zeros], "stable sampled invariant zeros", opts.intervals))
        conds.append(_per_interval([f[0] for f in fixed], "detectable decoupled pairs", opts.intervals))
        conds.append(_per_interval([weak_modes_condition(s.A, s.E, plant.C, f" at h = {h:g} s")
                                    for h, s in zip(opts.intervals, samples)], "well observable modes", opts.intervals))
        for h, (_, modes) in zip(opts.intervals, fixed):
            if modes.size and np.abs(modes).max() > zmax:
                zmax, zarg = float(np.abs(modes).max()), h
        if len(samples) > 1 and plant.p == plant.q and existence_of(conds, "rank(C E(h)) = q"):
            switching = _switching_condition(samples, plant.C, opts)
            conds.append(switching)
            floor = max(floor, switching.values["switching_radius"])
            if switching.holds and floor < 1.0 and plant.n > plant.p:
                certified = _certificate_condition(samples, plant.C, opts, 1.0 - floor * floor, solver)
                conds += [certified] if certified is not None else []
        limit = 1.0 - zmax * zmax
        info = {"largest_zero_modulus": zmax, "at_interval": zarg, "alpha_limit": limit}
        if opts.alpha == "max":
            conds.append(Condition(
                "decay limited by sampled zeros", limit > 0, False,
                "no sampled invariant zero limits the decay (alpha < 1)" if not zmax > 0 else
                (f"the sampled invariant zero {zmax:.6g} (h = {zarg:g} s) limits any exactly-decoupling observer "
                 f"to a decay above {zmax:.6g} per sample, i.e. alpha < 1 - {zmax:.6g}^2 = {limit:.6g}") if limit > 0
                else f"the sampled invariant zero {zmax:.6g} (h = {zarg:g} s) leaves no alpha > 0", info))
        else:
            delta = float(np.sqrt(1 - opts.alpha))
            ok = delta > zmax + ZERO_MARGIN
            conds.append(Condition(
                "decay above sampled zeros", ok, True,
                (f"requested decay sqrt(1 - alpha) = {delta:.6g} > largest sampled invariant zero {zmax:.6g} "
                 f"(h = {zarg:g} s)") if ok else
                (f"requested decay sqrt(1 - alpha) = {delta:.6g} (alpha = {opts.alpha:g}) <= largest sampled "
                 f"invariant zero {zmax:.6g} (h = {zarg:g} s): no exactly-decoupling observer converges faster; "
                 f"alpha must be < 1 - {zmax:.6g}^2 = {limit:.6g} (or \"max\")"), {**info, "decay": delta}))
    conds = with_hint(conds, lambda failed: _hint(plant, opts.intervals, max(zmax, floor), failed))
    return Existence(NAME, tuple(conds)), samples, max(zmax, floor)


#: The per-interval conditions of exact decoupling, by their name here and in :mod:`uiofmu.decoupling`.
DECOUPLING = {"rank(C E(h)) = rank(E(h))": "rank(CE) = rank(E)",
              "stable sampled invariant zeros": "stable invariant zeros",
              "detectable decoupled pairs": "detectable decoupled pair"}


def _verdict(plant, intervals, C, target: str) -> tuple[Condition, bool]:
    """:func:`uiofmu.decoupling.decoupling_verdict` at every interval: the ``target`` condition over the
    intervals (as :func:`_per_interval` states it) and whether every condition holds at every interval."""
    verdicts = [decoupling_verdict(plant.sampled(h).A, plant.sampled(h).E, C, DECOUPLING[target], f" at h = {h:g} s")
                for h in intervals]
    return _per_interval([c for c, _ in verdicts], target, intervals), all(every for _, every in verdicts)


def _hint(plant, intervals, bound: float, failed: Condition) -> str:
    """What would make the failing condition hold: a measured state or other intervals for exact decoupling,
    an alpha below the limit that the decay ``bound`` per sample (the sampled zeros, the fixed error under
    switching) sets for a decay it forbids."""
    if failed.name in ("decay above sampled zeros", "fixed error under switching"):
        limit = 1.0 - (bound + ZERO_MARGIN) ** 2
        return (f"alpha = {short_below(limit):g}: alpha < {limit:.6g} clears the sampled zeros and the fixed error "
                "under switching" if limit > 0 else "")
    if failed.name not in DECOUPLING:
        return ""
    target = DECOUPLING[failed.name]
    scaled = period_hint(intervals, lambda hs: all(decoupling_verdict(plant.sampled(h).A, plant.sampled(h).E, plant.C,
                                                                      target)[1] for h in hs), "observer.intervals")
    measure = measurement_hint(plant.C, lambda C2: _verdict(plant, intervals, C2, failed.name), cost=len(intervals))
    return either(scaled, measure)


def existence_of(conds, name: str) -> bool:
    """Whether the condition ``name`` is among ``conds`` and holds."""
    return any(c.name == name and c.holds for c in conds)


#: Most interval sequences whose products :func:`_switching_condition` tries (per length).
MAX_PRODUCTS = 4096


def fixed_error_maps(samples, C) -> list:
    """With as many outputs as unknown inputs (``p = q``), exact decoupling leaves no freedom on
    ``ker C``: ``K_i = E_i (C E_i)^-1``, ``C (I - K_i C) A_i = 0``, and the error there evolves
    by ``F_i = N' (I - K_i C) A_i N`` (``N`` an orthonormal basis of ``ker C``) whatever the other
    gains, over every sequence of intervals. Returns the ``F_i``."""
    n = C.shape[1]
    return kernel_maps([(np.eye(n) - s.E @ np.linalg.solve(C @ s.E, C)) @ s.A for s in samples], C)


def _reduced_lmis(F, recentre: bool = True) -> LmiSystem:
    """Corollary 2 on ``ker C`` when ``p = q`` (:func:`fixed_error_maps`): Lyapunov matrices
    ``P_i`` with ``F_i' P_i F_i < (1 - alpha) P_j`` for all ``i, j``, ``I <= P_i <= mu I``.

    Exact for ``p = q``: every certificate of (15)-(16), restricted to ``ker C``, is one of these,
    and each of these gives one of (15)-(16) (:meth:`KerC.invert`). Infeasible here
    means that no observer of this family can be certified for the intervals.

    Each pair is written in increment form, the Schur form ``[[P_i, P_i F_i], [*, (1 - alpha) P_j]]``
    after the congruence ``[[I, -I], [0, I]]`` (:func:`_increment_lmi`), with ``G_i = I - F_i``
    computed once in double precision: the same LMI, but the decrease ``(1 - alpha) P_j - F_i' P_i F_i``,
    which near the limit is a tiny difference of two large matrices, becomes an explicit block
    instead of the solver's cancellation. With ``recentre``, a point the re-check refuses is
    solved again in the coordinates where its mean Lyapunov matrix is the identity
    (:func:`_recentring`).
    """
    N, m = len(F), F[0].shape[0]
    G = [np.eye(m) - f for f in F]

    def build(v, prm, ops):
        out = []
        for i in range(N):
            P = v[f"P{i}"]
            out.append(Lmi(f"P_{i + 1} >= I", P - ops.eye(m), strict=False))
            out.append(Lmi(f"P_{i + 1} <= mu I", v["mu"] * ops.eye(m) - P, strict=False))
            Y = P @ G[i]
            for j in range(N):
                out.append(Lmi(f"(15) on ker C i={i + 1} j={j + 1}",
                               _increment_lmi(P, Y, prm["c"] * v[f"P{j}"], ops)))
        return out

    variables = {"mu": scalar(UPPER_BOUND), **{f"P{i}": symmetric(m) for i in range(N)}}
    return LmiSystem(f"{NAME} (15) on ker C", variables, {"c": 0.99}, build, objective=lambda v: v["mu"],
                     homogeneous=True, recentre=_recentring(F, variables).frame if recentre else None,
                     structure=list(F))


#: Most recentrings of :func:`best_margin` (it stops earlier once its coordinates settle).
MARGIN_RECENTRINGS = 12


def best_margin(F, c: float) -> tuple:
    """The largest margin of Corollary 2 on ``ker C`` (``p = q``) at ``c = 1 - alpha``: ``max t``
    with every increment LMI of :func:`_reduced_lmis` ``>= t I``, every ``P_i >= t I`` and
    ``sum_i trace P_i = 1``, relative to the mean eigenvalue ``1 / (N m)`` of the ``P_i``.

    Unlike the design LMIs, this problem is bounded and always feasible (``t`` may be negative),
    so CLARABEL answers it where the design LMIs sit on the edge of feasibility, and certificates
    exist exactly when its ``t > 0`` (the LMIs are homogeneous; the sign does not depend on the
    coordinates). Near the edge its optimal ``P_i`` are ill-conditioned and ``t`` is lost in
    the solver's tolerance, so it is solved again in the coordinates where the mean of the last
    ``P_i`` is the identity (as :func:`_recentring`), until they settle (``eig_max / eig_min``
    of that mean below 1.01) or after :data:`MARGIN_RECENTRINGS` solves.

    Returns
    -------
    (float or None, str, int)
        ``N m t`` at the last solve (None when CLARABEL returned no point), CLARABEL's status
        there, and the number of solves.
    """
    N, m = len(F), F[0].shape[0]
    basis = np.eye(m)

    def system(maps):
        G = [np.eye(m) - f for f in maps]

        def build(v, prm, ops):
            t = v["t"]
            out = [Lmi("sum_i trace P_i = 1", sum(basis[k:k + 1] @ v[f"P{i}"] @ basis[:, k:k + 1]
                                              for i in range(N) for k in range(m)) - np.ones((1, 1)),
                       equality=True)]
            for i in range(N):
                P = v[f"P{i}"]
                out.append(Lmi(f"P_{i + 1} >= t I", P - t * ops.eye(m), strict=False))
                for j in range(N):
                    out.append(Lmi(f"(15) on ker C i={i + 1} j={j + 1} >= t I",
                                   _increment_lmi(P, P @ G[i], prm["c"] * v[f"P{j}"], ops) - t * ops.eye(2 * m),
                                   strict=False))
            return out

        variables = {"t": ("scalar",), **{f"P{i}": ("symmetric", m) for i in range(N)}}
        return LmiSystem(f"{NAME} best margin on ker C", variables, {"c": 0.99}, build,
                         objective=lambda v: -1.0 * v["t"], structure=list(maps))

    maps, t, status = list(F), None, ""
    for k in range(1, MARGIN_RECENTRINGS + 1):
        sol = system(maps).solve(c=c)
        status = sol.status
        if not sol.values:
            return t if k > 1 else None, status, k
        t = float(sol.values["t"]) * N * m
        w, V = np.linalg.eigh(sum(0.5 * (sol.values[f"P{i}"] + sol.values[f"P{i}"].T) for i in range(N)) / N)
        if not np.all(np.isfinite(w)) or w[-1] <= 0 or w[-1] < 1.01 * w[0]:
            return t, status, k
        w = np.maximum(w, 1e-12 * w[-1])
        R, Ri = (V * np.sqrt(w)) @ V.T, (V / np.sqrt(w)) @ V.T
        maps = [R @ f @ Ri for f in maps]
    return t, status, MARGIN_RECENTRINGS


def _recentring(F, variables: dict) -> Recentring:
    """The LMIs of :func:`_reduced_lmis` in the coordinates ``xi = P0^(1/2) e`` of ``ker C``, ``P0``
    the mean of a point's ``P_i`` scaled to ``eig_min(P0) = 1`` (:class:`uiofmu.reductions.Recentring`):
    maps ``P0^(1/2) F_i P0^(-1/2)``, whose Lyapunov matrices near that point are near the identity, so
    that the solver's relative tolerance resolves all of their directions (a point of
    :func:`_reduced_lmis` may need ``mu`` of 1e4 in the plant's coordinates where these need 2). Its
    points map back to ``P_i = P0^(1/2) Pt_i P0^(1/2)`` and ``mu = mut eig_max(P0)``, which satisfy
    every LMI there with at least the margin they had here (``P0 >= I``).
    """
    return Recentring(lambda R, Ri: _reduced_lmis([R @ f @ Ri for f in F], recentre=False), variables)


def _increment_lmi(P, Y, Pj, ops):
    """``[[P, -Y], [-Y', Pj - P + Y + Y']]``: the Schur form ``[[P, P F], [F' P, Pj]]`` of
    ``Pj - F' P F > 0`` with ``Y = P (I - F)``, after the congruence ``[[I, -I], [0, I]]``.

    Positive definite exactly when the Schur form is (same Schur complement ``Pj - F' P F``), and
    the right block is the decrease itself up to ``Y' P^-1 Y``: where ``F`` has an eigenvalue near
    the unit circle that block is small and explicit, so an interior-point solver resolves it to its
    relative tolerance instead of losing it in the cancellation ``Pj - F' P F``.
    """
    return ops.bmat([[P, -Y], [-Y.T, Pj - P + Y + Y.T]])


class KerC(Reduction):
    """Corollary 2 on ``ker C`` when ``p = q`` (:func:`_reduced_lmis`), a reduction exact there.

    :meth:`apply` takes ``(samples, C)`` to the LMIs of the fixed error maps (:func:`fixed_error_maps`);
    :meth:`invert` lifts their point to the variables of (15)-(16).
    """

    def apply(self, problem: tuple) -> tuple:
        """``(system, inverse_data)`` of ``problem = (samples, C)``: :func:`_reduced_lmis` of the fixed error
        maps, and ``(samples, C)``."""
        samples, C = problem
        return _reduced_lmis(fixed_error_maps(samples, C)), (samples, C)

    def invert(self, values: dict, inverse_data: tuple) -> dict:
        """The variables of (15)-(16) from a point of :func:`_reduced_lmis` (``p = q``).

        ``Pl_i = N P_i N' + R R'`` (``N``, ``R`` orthonormal bases of ``ker C`` and its complement),
        ``S_i = Pl_i K_i`` with the forced ``K_i = E_i (C E_i)^-1``, and ``Q_ij = Pl_i Abar_i C^+``
        with ``Abar_i = (I - K_i C) A_i``: then ``L_ij = Abar_i (I - C^+ C) = N F_i N'`` and
        ``(1 - alpha) Pl_j - L_ij' Pl_i L_ij = N ((1 - alpha) P_j - F_i' P_i F_i) N' + (1 - alpha) R R'``.
        """
        samples, C = inverse_data
        p, n = C.shape
        _, _, vt = np.linalg.svd(C)
        basis, rest, Cp = vt[p:].T, vt[:p].T, np.linalg.pinv(C)
        out = {"mu": values["mu"]}
        for i, s in enumerate(samples):
            K = s.E @ np.linalg.solve(C @ s.E, np.eye(p))
            Pl = basis @ values[f"P{i}"] @ basis.T + rest @ rest.T
            out[f"Pl{i}"] = 0.5 * (Pl + Pl.T)
            out[f"S{i}"] = out[f"Pl{i}"] @ K
            Q = out[f"Pl{i}"] @ ((np.eye(n) - K @ C) @ s.A) @ Cp
            for j in range(len(samples)):
                out[f"Q{i}_{j}"] = Q
        return out


def _certificate_condition(samples, C, opts, limit: float, solver: bool = True) -> Condition | None:
    """Whether Corollary 2 can certify any observer for the intervals (``p = q``): its LMIs on
    ``ker C`` (:func:`_reduced_lmis`, exact there) at the slowest decay the search would try.
    Only CLARABEL's proof of infeasibility fails the condition; a numerical failure leaves it
    to the design. Without ``solver`` the condition is None unless no solve decides it (a scalar error
    on ker C)."""
    from ..lmi import INFEASIBLE

    alpha = 1e-3 * limit
    F = fixed_error_maps(samples, C)
    if F[0].shape[0] == 1:                    # scalar: equal P_i certify exactly when every |F_i| < sqrt(1 - alpha)
        return Condition("certificate on ker C", True, False,
                         "the error on ker C is scalar (n = p + 1): the zeros decide, as above", {"alpha": alpha})
    if not solver:
        return None
    sol = _reduced_lmis(F).solve(c=1.0 - alpha)
    values = {"alpha": alpha, "verified": bool(sol.verified)}
    if not sol.verified and sol.status not in INFEASIBLE:
        t, status, solves = best_margin(F, 1.0)
        values.update(best_margin=t, best_margin_status=status, best_margin_solves=solves)
        if t is not None and status == "optimal" and t < -MARGIN_PROOF_RTOL:
            return Condition("certificate on ker C", False, True,
                             f"with p = q the LMIs of Corollary 2 reduce exactly to ker C, and there their largest "
                             f"margin is negative even at alpha = 0: {t:.3g} of the Lyapunov matrices' mean eigenvalue "
                             f"(CLARABEL {status} after {solves} solve(s) in recentred coordinates): no quadratic "
                             "Lyapunov function per interval decreases over every succession of these intervals, "
                             "so no observer of this family can be certified; drop intervals from observer.intervals",
                             values, solver=True)
    if sol.status in INFEASIBLE:
        return Condition("certificate on ker C", False, True,
                         f"with p = q the LMIs of Corollary 2 reduce exactly to ker C, and there CLARABEL proves them "
                         f"infeasible even at alpha = {alpha:.3g}: no quadratic Lyapunov function per interval "
                         "decreases over every succession of these intervals, so no observer of this family can be "
                         "certified; drop intervals from observer.intervals", values, solver=True)
    found = ("hold at CLARABEL's point (re-checked)" if sol.verified else
             f"not proved infeasible (CLARABEL {sol.status}): the design decides")
    return Condition("certificate on ker C", True, False,
                     f"the LMIs of Corollary 2 on ker C (p = q) at alpha = {alpha:.3g}: {found}", values, solver=True)


def _switching_condition(samples, C, opts) -> Condition:
    """No exactly-decoupling observer converges for every sequence of intervals when a repeated
    sequence of them multiplies the fixed error (:func:`fixed_error_maps`) by 1 or more per
    sample: the spectral radius of its product, to the power 1/length (sequences of up to three
    intervals). Its largest value also bounds the decay from below, like the sampled zeros."""
    F = np.array(fixed_error_maps(samples, C))                     # (N, m, m)
    if F.shape[1] == 0:
        return Condition("fixed error under switching", True, False,
                         "exact decoupling leaves no error on ker C (p = q = n)", {"switching_radius": 0.0,
                                                                                   "sequence": []})
    best, seq = product_radius(F, 3, MAX_PRODUCTS)
    text = ", ".join(f"{opts.intervals[i]:g}" for i in seq) + " s"
    values = {"switching_radius": best, "sequence": [opts.intervals[i] for i in seq]}
    if not best < 1.0 - ZERO_MARGIN:
        return Condition("fixed error under switching", False, True,
                         f"repeating the intervals {text} multiplies the error that exact decoupling cannot move "
                         f"(p = q: it lives on ker C) by {best:.6g} per sample: no exactly-decoupling observer "
                         "converges for every sequence of these intervals; drop one of them from observer.intervals",
                         values)
    if opts.alpha != "max" and not np.sqrt(1 - opts.alpha) > best + ZERO_MARGIN:
        return Condition("fixed error under switching", False, True,
                         f"requested decay sqrt(1 - alpha) = {np.sqrt(1 - opts.alpha):.6g} (alpha = {opts.alpha:g}) "
                         f"<= {best:.6g}, the decay per sample of the error that exact decoupling cannot move when "
                         f"the intervals {text} repeat; alpha must be < 1 - {best:.6g}^2 = {1 - best * best:.6g}",
                         values)
    return Condition("fixed error under switching", True, False,
                     f"the error that exact decoupling cannot move (ker C, p = q) decays by at most {best:.6g} per "
                     f"sample over the worst repeated sequence of intervals ({text})", values)


def analyse(problem, solver: bool = True) -> Analysis:
    """Rank conditions, sampled invariant zeros and the decay they allow, for every interval (and, with
    ``solver``, whether Corollary 2 on ker C has a certificate at all: one solve)."""
    existence, samples, floor = _analysis(problem, solver)
    return Analysis(existence, {"samples": samples, "decay_floor": floor})


def _lmis(samples, C, gain_cap: float | None = None):
    """Corollary 2's LMIs (15)-(16), and with ``gain_cap`` the LMIs of ``||Pl_i^-1 S_i|| <= gain_cap`` and
    ``||Pl_i^-1 Q_ij|| <= gain_cap`` (:func:`uiofmu.gains.cap_lmis`; in the scaled coordinates, whose gains bound
    the plant's)."""
    N, n, p = len(samples), C.shape[1], C.shape[0]
    Es = [s.E / max(np.linalg.norm(s.E, 2), 1e-300) for s in samples]

    def build(v, prm, ops):
        out = []
        scaled = [prm["c"] * v[f"Pl{j}"] for j in range(N)]           # (1 - alpha) Pl_j, once per j
        for i in range(N):
            P, S = v[f"Pl{i}"], v[f"S{i}"]
            out.append(Lmi(f"Pl_{i + 1} >= I", P - ops.eye(n), strict=False))
            out.append(Lmi(f"Pl_{i + 1} <= mu I", v["mu"] * ops.eye(n) - P, strict=False))
            out.append(Lmi(f"(16) decoupling i={i + 1}", P @ Es[i] - S @ (C @ Es[i]), equality=True))
            base = P @ samples[i].A - S @ (C @ samples[i].A)            # the part of (15) common to all j
            for j in range(N):
                Y = base - v[f"Q{i}_{j}"] @ C
                out.append(Lmi(f"(15) i={i + 1} j={j + 1}", ops.bmat([[P, Y], [Y.T, scaled[j]]])))
        if gain_cap is not None:
            out += cap_lmis(gain_cap, [(f"Pl_{i + 1}", v[f"Pl{i}"], [(f"S_{i + 1}", v[f"S{i}"])]
                                        + [(f"Q_{i + 1}{j + 1}", v[f"Q{i}_{j}"]) for j in range(N)])
                                       for i in range(N)], v["s"], ops)
        return out

    variables = {"mu": scalar(UPPER_BOUND)}
    for i in range(N):
        variables[f"Pl{i}"] = symmetric(n)
        variables[f"S{i}"] = matrix((n, p))
        for j in range(N):
            variables[f"Q{i}_{j}"] = matrix((n, p))
    if gain_cap is not None:
        variables["s"] = scalar()
    return LmiSystem(f"{NAME} (15)-(16)", variables, {"c": 0.99}, build, objective=lambda v: v["mu"],
                     homogeneous=True, structure=([s.A for s in samples], Es, C, gain_cap))


def checks(matrices: dict, decay: float) -> list:
    """The certificate's checks at the stored matrices, worst case over all (i, j).

    (13) ``(I - K_i C) E_i = 0``, (12) ``L_ij - (I - K_i C) A_i - L_ij K_j C + P_ij C = 0``,
    ``G_i = (I - K_i C) B_i``, ``Pl_i > 0`` and ``decay^2 Pl_j - L_ij' Pl_i L_ij > 0``, all
    pairs at once (residuals in the Frobenius norm, which bounds the 2-norm).
    """
    g = {k: np.asarray(v, dtype=float) for k, v in matrices.items()}
    C, K, Pl = g["C"], g["K"], g["Pl"]
    A, B, E = g["A_sampled"], g["B_sampled"], g["E_sampled"]
    L, P = g["N"], g["L"]
    N, n = len(K), C.shape[1]
    Pi = np.eye(n) - K @ C                                            # (N, n, n)
    fro = lambda x: np.sqrt(np.sum(x * x, axis=(-2, -1)))            # noqa: E731
    two = lambda x: np.linalg.norm(x, 2, axis=(-2, -1))               # noqa: E731
    res12 = L - (Pi @ A)[:, None] - L @ (K @ C)[None, :] + P @ C
    scale12 = two(A)[:, None] + two(P) * np.linalg.norm(C, 2)
    Q = decay * decay * Pl[None, :] - np.swapaxes(L, -1, -2) @ Pl[:, None] @ L
    Q = 0.5 * (Q + np.swapaxes(Q, -1, -2))
    lyap = np.linalg.eigvalsh(Q)[..., 0]
    aL = np.abs(L)
    floor = rounding_floor(Q, decay * decay * np.abs(Pl)[None, :] + np.swapaxes(aL, -1, -2) @ np.abs(Pl)[:, None]
                           @ aL, 2 * n + 2)
    need = np.maximum(VERIFY_FRACTION * LMI_MARGIN, ROUNDING_FACTOR * floor)
    worstQ = np.unravel_index(int(np.argmin(lyap - need)), lyap.shape)
    ratio = lambda r, s: (r / (IDENTITY_RTOL * np.maximum(1.0, s)))  # noqa: E731
    scale13 = two(E) + two(K) * two(C @ E)                           # (I - K C) E = E - K (C E)
    worst13 = int(np.argmax(ratio(fro(Pi @ E), scale13)))
    worstG = int(np.argmax(ratio(fro(g["G"] - Pi @ B), two(B) if B.size else np.zeros(N))))
    worst12 = np.unravel_index(int(np.argmax(ratio(fro(res12), scale12))), (N, N))
    return [
        identity_check("(13) max_i ||(I - K_i C) E_i||", (Pi @ E)[worst13], float(scale13[worst13])),
        identity_check("max_i ||G_i - (I - K_i C) B_i||", (g["G"] - Pi @ B)[worstG],
                       np.linalg.norm(B[worstG], 2) if B.size else 0.0),
        identity_check("max_j ||Xy_j - K_j||", (g["Xy"] - K).reshape(-1), 1.0 + float(np.abs(K).max())),
        identity_check("max_j ||Xz_j - I||", (g["Xz"] - np.eye(n)).reshape(-1), 1.0),
        identity_check("max_i ||c_i||", g["c"].reshape(-1), 1.0),
        positive_check("min_i eig_min(Pl_i)", Pl[int(np.argmin(np.linalg.eigvalsh(Pl)[:, 0]))]),
        identity_check("(12) max_ij ||L_ij - (I-K_iC)A_i - L_ij K_j C + P_ij C||", res12[worst12],
                       float(scale12[worst12])),
        Check("min_ij eig_min(delta^2 Pl_j - L_ij' Pl_i L_ij)", float(lyap[worstQ]), float(need[worstQ]),
              at_most=False, floor=float(floor[worstQ])),
        decay_check(decay),
    ]


def verify(card) -> list:
    """Re-check a card's certificate from its matrices alone (no solver), the overshoot and the noise gain it
    claims."""
    d = card.data
    return (checks(d["matrices"], d["decay_bound"]) + [overshoot_check(d["overshoot_bound"], d["matrices"]["Pl"])]
            + pair_checks(d.get("noise"), d["matrices"]))


def error_system(matrices: dict) -> tuple:
    """The error system from output noise ``v`` (on the samples, ``y_k = C x_k + v_k``) at the stored matrices
    (:func:`uiofmu.noise.pair_error_system`), the step ``(i, j)`` for the intervals ``(h_k, h_k-1)``.

    ``e_k = eps_k - K_j v_k`` with ``eps_k = (I - K_j C) x_k - z_k``, and by (13), ``G_i = (I - K_i C) B_i`` and (12)
    (``(I - K_i C) A_i - P_ij C = L_ij (I - K_j C)``), ``eps+ = L_ij eps - P_ij v``: the runtime's ``N_ij = L_ij``,
    ``L_ij = P_ij`` and ``Xy_j = K_j``.
    """
    return pair_error_system(matrices)


def sampled_noise(plant, intervals) -> np.ndarray:
    """``W`` sampled at each design interval (the noise held over the interval, as ``E``): ``W_sampled[i]``."""
    return np.array([plant.sampled_noise(h) for h in intervals])


def noise_of(matrices: dict) -> dict:
    """The card's ``noise`` section: ``gain_y``, ``gain_w`` where the problem declares ``[plant] W`` (the error
    ``eps+ = L_ij eps + (I - K_i C) W_i w``, ``W_i`` sampled at the interval ``h_k``: by (13) and (12) every other
    input cancels, :func:`uiofmu.noise.pair_process_error_system`) and, where the card has dhat, ``gain_dhat_y``,
    for every sequence of design intervals (:func:`uiofmu.noise.pair_section`).

    dhat after the interval ``h_k`` (index ``i``, after ``j``) is ``dhat_(k+1) = Dy_i (y_(k+1) - Yx_i xhat_k -
    Yu_i u_k)`` with the plant sampled at ``h_k`` (``Dy_i = (C E_i)^+``, ``Yx_i = C A_i``, ``Yu_i = C B_i``) and
    the unknown input held over the interval: ``dhat_(k+1) - d_k = Dy_i C A_i e_k + Dy_i v_(k+1)``
    (:func:`uiofmu.noise.pair_dhat_error_system`)."""
    return pair_section(matrices, NO_W)


#: The bound the card states.
BOUND = "||e_k|| <= overshoot_bound * decay_bound**k * ||e_0|| for every sequence of design intervals"


def _schedule(opts: Options) -> dict:
    return {"kind": "interval", "intervals": list(opts.intervals), "h_prev0": opts.h_prev0,
            "step_policy": opts.step_policy, "step_rtol": STEP_RTOL}


def determined(problem, card_data, analysis: Analysis) -> dict:
    """What the card's problem determines: the plant sampled at each interval, dhat's matrices
    (absent unless ``rank(C E(h)) = q`` at every interval), the schedule, the intervals and
    ``alpha = 1 - decay_bound^2``; the zeros and the decay limit of its analysis, the LMIs' size of the
    card's design method, the state scaling, and the eigenvalues of the stored ``L_ij``."""
    plant, opts = problem.plant, problem.options
    samples, C = [plant.sampled(h) for h in opts.intervals], plant.C
    mats = {"A_sampled": np.array([s.A for s in samples]), "B_sampled": np.array([s.B for s in samples]),
            "E_sampled": np.array([s.E for s in samples]), "C": C, "c": np.zeros((len(samples), plant.n))}
    if all(identifiability_condition(C, s.E).holds for s in samples):
        mats.update(dhat_record(C, mats["A_sampled"], mats["B_sampled"], mats["E_sampled"],
                                np.zeros((len(samples), plant.n))))
    else:
        mats.update(dict.fromkeys(DHAT))
    if opts.alpha == "max":
        decay = float(card_data["decay_bound"])
        alpha = {"alpha": Determined(1.0 - decay * decay, 1.0)}
    else:                                                   # a fixed alpha is the card's
        alpha = {"alpha": float(opts.alpha), "decay_bound": float(np.sqrt(1.0 - opts.alpha))}
    noise = {"noise.norm": "l2"}                       # gain_y, gain_w and gain_dhat_y: verify re-checks them
    if plant.r:
        mats["W_sampled"] = sampled_noise(plant, opts.intervals)
    else:
        noise["noise.gain_w"] = None
    if mats["Dy"] is None:
        noise["noise.gain_dhat_y"] = None
    return {**noise, "dt": None, "schedule": _schedule(opts), "bound": BOUND, "intervals": list(opts.intervals),
            **alpha, **{f"matrices.{k}": v for k, v in mats.items()}, **figures_of(problem, card_data, analysis)}


#: What the card says of its ``largest_sampled_zero``.
DECAY_FLOOR_NOTE = ("the largest sampled zero, or (p = q) the fixed error's decay under the worst repeated sequence "
                    "of intervals when larger")


def lmi_size(plant, intervals: int, method: str) -> dict:
    """The size of the LMIs of a design method (``"lmi"``: (15)-(16); on ker C: the reduced LMIs)."""
    n, p, N = plant.n, plant.p, intervals
    if method == NOISE_METHOD:
        return {"lmis": 2 * N * N, "lmi_dim": 2 * n, "normalisation_lmis": N, "equalities": 0,
                "scalar_variables": 1 + N * n * (n + 1) + N * n * n + N * N * n * p}
    if method != "lmi":
        return {"lmis": N * N, "lmi_dim": 2 * (n - p), "normalisation_lmis": 2 * N, "equalities": 0,
                "scalar_variables": 1 + N * (n - p) * (n - p + 1) // 2}
    return {"lmis": N * N, "lmi_dim": 2 * n, "normalisation_lmis": 2 * N, "equalities": N,
            "scalar_variables": 1 + N * n * (n + 1) // 2 + N * n * p + N * N * n * p}


def figures_of(problem, card_data: dict, analysis: Analysis) -> dict:
    """The figures a sampled-data card lists that its analysis and stored matrices determine: the decay
    limit and the largest zero, each interval's sampled zeros, the LMIs' size and the state scaling of
    the card's design method (``lmi``, or ``lmi on ker C (p = q)``), the eigenvalues of each ``L_ii``
    and the largest modulus of every ``L_ij``."""
    plant, opts = problem.plant, problem.options
    zmax, n = analysis.data["decay_floor"], plant.n
    rtol = eigen_rtol(n)
    size = max(float(np.linalg.norm(s.A, 2)) for s in analysis.data["samples"])
    method = card_data.get("design_method")
    methods = (("lmi", "lmi on ker C (p = q)") if plant.p == plant.q and n > plant.p else ("lmi",)) + (
        (NOISE_METHOD,) if opts.noise == "min" or opts.noise_gain is not None else ())
    N = np.asarray(card_data["matrices"]["N"], dtype=float)
    zeros = analysis.existence.value("stable sampled invariant zeros", "per_interval")
    return {"alpha_limit_from_zeros": Determined(1.0 - zmax * zmax, 1.0, rtol),
            "largest_sampled_zero": Determined(zmax, 1.0, rtol), "decay_floor_note": DECAY_FLOOR_NOTE,
            "sampled_invariant_zeros": [{"h": z["h"], "zeros": computed_values(from_pairs(z["zeros"]), size, n)}
                                        for z in zeros],
            "design_method": method if method in methods else methods[0],
            "lmi_size": lmi_size(plant, len(opts.intervals), method),
            "scaling": scaling_data(state_scaling(plant.A, opts.scaling) if method == "lmi" else np.ones(n),
                                    opts.scaling),
            "spectral_radius_max": spectrum(N, "radius"),
            "eigenvalues_L_constant": spectrum(N[np.arange(len(N)), np.arange(len(N))])}


def observer_matrices(v: dict, samples, C) -> dict:
    """The runtime's matrices (and the certificate's) from a point of the LMIs (18)-(19).

    Parameters
    ----------
    v : dict of str to numpy.ndarray
        The LMI variables ``Pl_i``, ``S_i``, ``Q_ij``.
    samples : list of Sampled
        The plant at each design interval.
    C : (p, n) array

    Returns
    -------
    dict
        ``N``, ``L``, ``G``, ``c``, ``Xz``, ``Xy``, ``C``, ``K``, ``Pl``, the sampled plant and
        ``Dy``, ``Yx``, ``Yu``, ``Yc`` (the family drops these when dhat is not identifiable).
    """
    N, n, p = len(samples), C.shape[1], C.shape[0]
    Pl = [0.5 * (v[f"Pl{i}"] + v[f"Pl{i}"].T) for i in range(N)]
    K, G, Yx, Yu, Dy = [], [], [], [], []
    for i, s in enumerate(samples):
        Ki = np.linalg.solve(Pl[i], v[f"S{i}"])
        CE = C @ s.E
        Ki = Ki + (s.E - Ki @ CE) @ np.linalg.pinv(CE)        # exact (13): K_i C E_i = E_i
        K.append(Ki)
        G.append((np.eye(n) - Ki @ C) @ s.B)
        Yx.append(C @ s.A)
        Yu.append(C @ s.B)
        Dy.append(np.linalg.pinv(CE))
    Q = np.array([[v[f"Q{i}_{j}"] for j in range(N)] for i in range(N)])       # (N, N, n, p)
    Gq = np.linalg.solve(np.array(Pl)[:, None], Q)                               # Pl_i^{-1} Q_ij
    PiA = np.array([(np.eye(n) - K[i] @ C) @ s.A for i, s in enumerate(samples)])
    Lm = PiA[:, None] - Gq @ C                                                   # (18)
    Pm = Gq + Lm @ np.array(K)[None, :]                                          # (19), sign corrected
    return {
        "N": Lm, "L": Pm, "G": np.array(G), "c": np.zeros((N, n)),
        "Xz": np.array([np.eye(n)] * N), "Xy": np.array(K), "C": C,
        "K": np.array(K), "Pl": np.array(Pl),
        "A_sampled": np.array([s.A for s in samples]), "B_sampled": np.array([s.B for s in samples]),
        "E_sampled": np.array([s.E for s in samples]),
        "Dy": np.array(Dy), "Yx": np.array(Yx), "Yu": np.array(Yu), "Yc": np.zeros((N, p)),
    }


def gain_figures(card_data: dict) -> tuple:
    """The gains ``K_i`` and ``Pl_i^-1 Q_ij = P_ij - L_ij K_j`` (the card's ``L`` and ``N``), ``||C||`` and the
    largest ``||A_i||`` of the sampled plant (:mod:`uiofmu.gains`)."""
    m = {k: np.asarray(card_data["matrices"][k], dtype=float) for k in ("K", "L", "N", "C", "A_sampled")}
    return ([m["K"], m["L"] - m["N"] @ m["K"][None]], float(np.linalg.norm(m["C"], 2)),
            float(two_norms([m["A_sampled"]]).max()))


#: Interval sets up to this size get every pair tried when a design fails.
DIAGNOSED_PAIRS = 8


def _interval_diagnosis(samples, C, t, intervals, alpha: float) -> str:
    """Which intervals admit no certificate together, when the whole set admits none.

    Corollary 2 needs one Lyapunov function per interval that decreases over every pair of
    successive intervals; each interval may design alone while a pair of them does not.
    Solves the LMIs at ``alpha`` for each interval alone and (for at most
    :data:`DIAGNOSED_PAIRS` intervals) for each pair, and names the smallest failing sets.
    """
    if len(samples) < 2:
        return ""
    steps, Cs = StateScaling(t).coordinates(samples, C)

    def certifies(ks):
        return _lmis([steps[k] for k in ks], Cs).solve(c=1.0 - alpha).verified

    fmt = lambda ks: " and ".join(f"{intervals[k]:g}" for k in ks) + " s"       # noqa: E731
    alone = [k for k in range(len(samples)) if not certifies((k,))]
    if alone:
        return (f"at alpha = {alpha:.3g} the LMIs of interval(s) {fmt(alone)} alone have no certificate "
                "either: remove them from observer.intervals")
    if len(samples) > DIAGNOSED_PAIRS:
        return (f"at alpha = {alpha:.3g} every interval alone has a certificate, but no Lyapunov function "
                "was found that decreases over every succession of the set's intervals")
    pairs = [(i, j) for i in range(len(samples)) for j in range(i + 1, len(samples)) if not certifies((i, j))]
    if not pairs:
        return (f"at alpha = {alpha:.3g} every interval and every pair of intervals has a certificate, but the "
                "whole set has none")
    return (f"at alpha = {alpha:.3g} every interval alone has a certificate, but the pair(s) "
            f"{'; '.join(fmt(p) for p in pairs[:4])}{' ...' if len(pairs) > 4 else ''} have none (no Lyapunov "
            "function was found that decreases over their successions): drop one interval of each pair, or "
            "narrow the range")


def _attempts(samples, C, t, plant, gain_cap: float | None = None):
    """The LMI systems a design tries, in order, each built when it is tried, with the map from its
    point to the stored matrices; each is a reduction of (15)-(16). For ``p = q``, Corollary 2 on
    ``ker C`` first (:class:`KerC`, exact there, in ``n - p`` unknowns): its optimal overshoot is at most
    the full LMIs', in the plant's own coordinates, and CLARABEL resolves its margins where the full
    LMIs' drown in the gains' scale (a campaign plant whose full LMIs certify only alpha = 2.9e-6 gets
    0.0916 of the limit 0.0919 there); then (15)-(16) in the balanced coordinates
    (:class:`uiofmu.scaling.StateScaling`). With ``gain_cap`` only the latter, capped: the reduced LMIs
    leave the gains to a formula.

    Yields
    ------
    (str, LmiSystem, callable)
        The design method, its system (``certify`` set) and the map to the stored matrices.
    """
    attempts = [("lmi", StateScaling(t), PlantLmis(lambda steps, Cs: _lmis(steps, Cs, gain_cap), samples, C))]
    if plant.p == plant.q and plant.n > plant.p and gain_cap is None:
        attempts.insert(0, ("lmi on ker C (p = q)", KerC(), (samples, C)))
    for method, reduction, lmis in attempts:
        system, inverse = reduction.apply(lmis)
        matrices_at = lambda v, r=reduction, inv=inverse: observer_matrices(r.invert(v, inv), samples, C)  # noqa: E731
        system.certify = lambda v, prm, at=matrices_at: all(c.holds for c in checks(at(v), np.sqrt(prm["c"])))
        system.figure = lambda v, at=matrices_at: overshoot(list(at(v)["Pl"]))
        yield method, system, matrices_at


def noise_options(opts: Options, decay, noise: str) -> Options:
    """These options at another decay (a number, given as ``alpha = 1 - decay^2``, or ``"max"``) with the noise
    objective ``noise``, for :mod:`uiofmu.tradeoff`: no ``noise_gain``."""
    alpha = decay if decay == "max" else 1.0 - float(decay) ** 2
    return replace(opts, alpha=alpha, noise=noise, noise_gain=None)


#: The ``K_i`` a least-noise design keeps: the least-norm ``E_i (C E_i)^+``, and the default design's.
NOISE_K = ("least-norm K_i = E_i (C E_i)^+", "the default design's K_i")


def _noise_runtime(samples, C, K, values: dict) -> dict:
    """The runtime's matrices of a point of the least-noise LMIs: :func:`observer_matrices` of
    ``Pl_i = S_i`` (the decay's Lyapunov matrices), ``S_i = Pl_i K_i`` and ``Q_ij = Pl_i H_ij``."""
    N = len(samples)
    Pl = [np.asarray(values[f"S{i}"], dtype=float) for i in range(N)]
    v = {**{f"Pl{i}": Pl[i] for i in range(N)}, **{f"S{i}": Pl[i] @ K[i] for i in range(N)},
         **{f"Q{i}_{j}": Pl[i] @ pair_noise_gain(values, i, j) for i in range(N) for j in range(N)}}
    return observer_matrices(v, samples, C)


def _noise_systems(samples, C, default: dict | None, sigma: float, opts: Options) -> list:
    """The least-noise LMIs (:func:`uiofmu.noise.pair_noise_lmis`, ``PA_i = (I - K_i C) A_i``, ``Xy_j = K_j``,
    one gain per pair of intervals) for each ``K`` of :data:`NOISE_K` (with ``gain_cap``, the default's only;
    without a default design, the least-norm only), each point certified by :func:`checks` at the runtime's
    matrices.

    Returns
    -------
    list
        ``(system, runtime, which)`` for each.
    """
    C = np.asarray(C, dtype=float)
    least = [s.E @ np.linalg.pinv(C @ s.E) for s in samples]
    out = []
    choices = list(zip(NOISE_K, (least, None if default is None else list(np.asarray(default["K"], dtype=float)))))
    for which, K in [c for c in choices[1 if opts.gain_cap is not None else 0:] if c[1] is not None]:
        PA = [(np.eye(C.shape[1]) - K[i] @ C) @ s.A for i, s in enumerate(samples)]
        system = pair_noise_lmis(NAME, PA, C, K, sigma, pair_gains=True, gain_cap=opts.gain_cap)
        runtime = (lambda K: lambda v: _noise_runtime(samples, C, K, v))(K)
        system.certify = (lambda rt: lambda v, prm: all(c.holds for c in checks(rt(v), float(np.sqrt(prm["lam2"])))))(
            runtime)
        out.append((system, runtime, which))
    return out


def _gain_y(matrices: dict):
    """The card's certified ``gain_y`` at these matrices (every sequence of design intervals)."""
    return certified(*error_system(matrices), switched=True)[0]


def design(problem, analysis: Analysis) -> DesignResult:
    """Design the sampled-data UIO (Corollary 2)."""
    existence, samples, zmax = analysis.existence, analysis.data["samples"], analysis.data["decay_floor"]
    plant, opts = problem.plant, problem.options
    C, n, N = plant.C, plant.n, len(opts.intervals)
    t = state_scaling(plant.A, opts.scaling)
    limit = 1.0 - zmax * zmax
    search = dict(feasible_end=1e-3 * limit, infeasible_end=limit, safe_end=0.0, tol=SEARCH_TOL * limit,
                  label=f"{problem.name}: largest alpha", transform=lambda a: 1.0 - a, name="alpha")
    failures = []
    for method, system, matrices_at in _attempts(samples, C, t, plant, opts.gain_cap):
        try:
            tuned = tune(system, "c", opts.alpha, **search)
            break
        except InfeasibleError as exc:
            failures.append(exc)
    else:
        note = _interval_diagnosis(samples, C, t, opts.intervals, 1e-3 * limit)
        text = "; with the full LMIs (15)-(16), the same certificates in more unknowns: ".join(str(f) for f in failures)
        raise type(failures[-1])(f"{text}; {note}" if note else text) from None
    alpha, sol = tuned.value, tuned.solution
    searched = tuned.search.to_data() if tuned.search else None
    matrices = matrices_at(sol.values)
    decay, digits, noise_design = float(np.sqrt(1.0 - alpha)), figure_digits(sol), None
    coordinates = ("recentred: ker C in the coordinates where the mean Lyapunov matrix of a point the re-check "
                   "refused is the identity (the point mapped back and re-checked)" if system.recentred
                   else "as scaled")
    if opts.noise == "min" or opts.noise_gain is not None:    # the least noise gain: uiofmu.noise.least_noise_design
        built, lmi = [], system

        def candidates(default, sigma):
            out = _noise_systems(samples, C, default, sigma, opts)
            built.extend(c[0] for c in out)
            return out

        def default_at(rho):
            at = lmi.solve(c=rho * rho)
            return (at, matrices_at(at.values)) if at.verified else None

        lam, least, noise_design = least_noise_design(
            {"default_at": default_at, "candidates": candidates, "gain": _gain_y}, decay, opts.alpha == "max",
            opts.noise_gain, (sol, matrices), problem.name)
        system = (lmi, *built)
        decay, alpha = lam, (1.0 - lam * lam if opts.alpha == "max" else alpha)   # the default certifies there too
        if least is not None:
            sol, matrices, which = least
            if which == "default":
                digits = figure_digits(sol)
            else:
                method, digits, coordinates = NOISE_METHOD, UNDETERMINED, "the plant's"
    Pl = list(matrices["Pl"])
    if not existence.holds("rank(C E(h)) = q"):
        for k in ("Dy", "Yx", "Yu", "Yc"):
            matrices.pop(k)
    if problem.plant.r:
        matrices["W_sampled"] = sampled_noise(problem.plant, opts.intervals)
    cert = certificate(sol, checks(matrices, decay), f"{NAME} design of {problem.name}")
    zeros = existence.value("stable sampled invariant zeros", "per_interval")
    diagonal = matrices["N"][np.arange(N), np.arange(N)]            # L_ii: a constant interval
    results = {
        "noise": noise_of(matrices),
        "alpha": alpha,
        "decay_bound": decay,
        "overshoot_bound": overshoot(Pl),
        "overshoot_digits": digits,
        "bound": BOUND,
        "intervals": list(opts.intervals),
        "alpha_limit_from_zeros": limit,
        "largest_sampled_zero": zmax,
        "decay_floor_note": DECAY_FLOOR_NOTE,
        "sampled_invariant_zeros": [{"h": z["h"], "zeros": z["zeros"]} for z in zeros],
        "lmi_size": lmi_size(plant, N, method),
        "search": searched,
        "design_method": method,
        "scaling": scaling_data(t if method == "lmi" else np.ones(n), opts.scaling),
        **({} if noise_design is None else {"noise_design": noise_design}),
        "lmi_coordinates": coordinates,
        "spectral_radius_max": float(np.abs(np.linalg.eigvals(matrices["N"])).max()),
        "eigenvalues_L_constant": [complex_list(e) for e in np.linalg.eigvals(diagonal)],
    }
    return DesignResult(n, None, _schedule(opts), matrices, cert, results, system, opts.xhat0)
