"""What sensor noise does to the estimate: the certified l2 noise gains of a card.

Every card has a ``noise`` section of the same shape::

    "noise": {"norm": "l2", "gain_y": float or null, "gain_w": float or null, "gain_dhat_y": float or null,
              "reason": str or null, ...}

``gain_y`` bounds the l2 gain from a measurement noise ``v`` (added to ``y`` at the observer's input)
to the estimation error ``e = x - xhat``, with the initial-condition term kept::

    ||e||_2 <= gain_y ||v||_2 + initial_term ||e_0||

``gain_w`` does the same for process noise and ``gain_dhat_y`` for the error of ``dhat``; a gain that
is null comes with ``reason``, which says why (the family's structure, no process noise declared, ...).

A discrete error system ``eps+ = A eps + B v``, ``e = C eps + D v`` is certified by the bounded real
lemma at the card's stored matrices: with ``X > 0``::

    [[X - A'XA - C'C,   -(A'XB + C'D)],
     [-(B'XA + D'C),    gamma^2 I - B'XB - D'D]]  > 0

summed along a run gives ``||e||^2 <= gamma^2 ||v||^2 + eps_0' X eps_0``, so ``initial_term`` is
``sqrt(eig_max(X))``. Both inequalities are decided as the decay is (:func:`uiofmu.certificate.definite_check`:
a verdict that no BLAS kernel's rounding can change). ``gamma`` is the H-infinity norm of the error
system (:func:`hinf_norm`: the level sets of its symplectic pencil, within 1e-10 below the norm; a frequency
sweep where the pencil's eigenvalues cannot be read), times ``1 + NOISE_MARGIN``, rounded up to
:data:`NOISE_DIGITS` significant digits; ``X`` is the stabilising solution of the bounded real
Riccati equation at that ``gamma`` (no solver). The card records the ``gamma`` the re-check proves.

A runtime whose matrices follow a mode or an interval (switched, sampled-data) is certified for every sequence
by the poly-quadratic lemma, one ``X`` per mode or interval (:func:`lemma_certificate`, solved by CLARABEL,
rounded up and re-checked alike): ``gain_y`` on :func:`pair_error_system`, ``gain_dhat_y`` on
:func:`pair_dhat_error_system` (dhat reads the next sample: a system one step ahead with the state
``(eps, v_prev)``, whose output reads the interval or mode of the step just taken, as lti-uio's
:func:`dhat_error_step` with one step).

A continuous error system that varies over a grid of points, ``eps' = A_g eps + B_g v``, ``e = C_g eps + D_g v``
(the delayed UIO on its premise grid), is certified by the continuous lemma with one ``X`` at every point
(:func:`continuous_brl_checks`), ``X`` a scale of a given Lyapunov matrix (:func:`continuous_brl_certificate`).

A finite-impulse-response error (the dead-beat functional observer: ``sum_j K_j v_{k-j}``) is certified
alike on its shift-register realisation (:func:`fir_system`), and its peak-to-peak gain is the sum of the
coefficients' norms (:func:`peak_to_peak`).
"""

from __future__ import annotations

import math
from functools import partial

import numpy as np

from .certificate import Check, definite_check, figure_text, rounding_floor, round_up
from .runtime.card import noise_determined
from .runtime.tolerances import NOISE_DIGITS, ROUNDING_FACTOR
from .threads import blas_module

#: The norm every gain of a card's ``noise`` section is in.
NORM = "l2"

#: The keys every ``noise`` section has.
KEYS = ("norm", "gain_y", "gain_w", "gain_dhat_y", "reason")

#: Relative margin added to the H-infinity norm before it is rounded up and certified.
NOISE_MARGIN = 1e-3

#: Points of the frequency sweep on [0, pi] (besides the angles of the error system's poles), where the level sets
#: of :func:`hinf_norm` cannot be read.
SWEEP_POINTS = 512

#: The level sets of :func:`hinf_norm`: the level tried above the largest response found (relative: the norm is
#: found to it), the relative distance from the unit circle within which an eigenvalue of its pencil counts as on
#: it, and the most levels tried before the sweep decides.
LEVEL_GAP, CIRCLE_TOL, LEVELS = 1e-10, 1e-6, 40

#: Angles per bracket in each round of the stacked zoom around the sweep's peaks, and the bracket width it stops at.
ZOOM_POINTS, ZOOM_WIDTH = 33, 1e-12

#: Most pairs (modes or intervals squared) whose poly-quadratic lemma a card's gain is certified by: each pair is
#: one LMI of the solve, as many as the decay design's own.
MAX_PAIRS = 256

#: Tries at a larger gamma (each ``GROWTH`` times the previous) when the re-check refuses a certificate.
TRIES, GROWTH = 12, 1.1


#: The card's ``design_method`` of a least-noise design (its overshoot is not what the LMIs minimise: the problem
#: does not determine its digits).
NOISE_METHOD = "lmi (least noise gain)"

#: ``observer.noise``: the default design (least overshoot bound), or the least noise gain at the decay.
NOISE_OBJECTIVES = ("default", "min")

#: ``observer.noise_gain`` searches the decay between the fastest certified one and this fraction of the way to 1
#: (the slowest decay it tries), and stops when the bracket is narrower than :data:`NOISE_GAIN_RESOLUTION` of that
#: way.
NOISE_GAIN_SLOWEST = 0.999
NOISE_GAIN_RESOLUTION = 1.0 / 1024

#: With ``decay = "max"``, ``noise = "min"`` designs at the fastest certified decay moved this fraction of the way
#: toward 1 (the card's ``decay_bound``): at the edge itself every gain is pinned by the decay, and the least
#: noise gain there is no less than the default design's.
NOISE_DECAY_ROOM = 0.1


def fastest_within(least_at, fastest: float, goal: float, name: str) -> tuple:
    """``observer.noise_gain = goal``: the fastest decay whose least-noise design has a certified ``gain_y`` of at
    most ``goal``, for any family.

    The least noise gain does not grow as the decay slows (every point certified at a decay is certified at any
    slower one), so the decay is bisected on the way from ``fastest`` (the default design's ``"max"``) to
    :data:`NOISE_GAIN_SLOWEST` of the way to 1, to :data:`NOISE_GAIN_RESOLUTION` of that way; the slower end of
    the bracket is the decay kept.

    Parameters
    ----------
    least_at : callable
        ``least_at(rho) -> (gain, design)``: the family's least-noise design at the decay ``rho`` and its
        certified ``gain_y`` (None where not certified); raises ``InfeasibleError`` where it has no point.
    fastest, goal : float
        The fastest certified decay, and the gain asked for.
    name : str
        The problem's name, for the message.

    Returns
    -------
    tuple
        ``(rho, gain, design, search)``, ``search`` the record of the decays tried.

    Raises
    ------
    InfeasibleError
        When even the slowest decay tried has a larger certified gain (the message gives it).
    """
    from .runtime.errors import InfeasibleError

    tried = {}

    def gain_at(f: float):
        rho = fastest + f * (1.0 - fastest)
        try:
            gain, design = least_at(rho)
        except InfeasibleError:
            tried[f] = (rho, None, None)
            return tried[f]
        tried[f] = (rho, gain, design)
        return tried[f]

    lo, hi = 0.0, NOISE_GAIN_SLOWEST
    rho, gain, _ = gain_at(hi)
    if gain is None or gain > goal:
        said = "no certified point" if gain is None else f"certified gain_y {gain:g}"
        ask = "" if gain is None else f": ask for noise_gain >= {gain:g}"
        raise InfeasibleError(f"{name}: observer.noise_gain = {goal:g}: the slowest decay tried, {rho:.6g}, has "
                              f"{said} for its least-noise gain, more than {goal:g}{ask}")
    while hi - lo > NOISE_GAIN_RESOLUTION:
        mid = 0.5 * (lo + hi)
        _, gain_mid, _ = gain_at(mid)
        if gain_mid is not None and gain_mid <= goal:
            hi = mid
        else:
            lo = mid
    rho, gain, design = tried[hi]
    search = {"parameter": "decay", "solves": len(tried), "tried": sorted((v[0], v[1]) for v in tried.values())}
    return rho, gain, design, search


def pair_noise_lmis(name: str, PA, C, Xy, sigma: float, pair_gains: bool = False,
                    gain_cap: float | None = None):
    """The least-noise LMIs of a runtime whose step ``(i, j)`` (this step's mode or interval, and the previous one)
    is ``eps+ = (PA_i - H_ij C) eps - (H_ij + (PA_i - H_ij C) Xy_j) v``, ``e = eps - Xy_j v``
    (:func:`pair_error_system` with ``N_ij = PA_i - H_ij C``, ``L_ij = H_ij + N_ij Xy_j``), the output gains ``H``
    free (one per mode, ``H_i``, or with ``pair_gains`` one per pair) and ``PA_i``, ``Xy_j`` given.

    With a slack ``G_i`` and ``F = G_i H`` (de Oliveira, Bernussou and Geromel's extended form), for every pair
    and with ``g`` bounding ``(gain_y / sigma)^2`` (minimised; the noise in units of ``1 / sigma``)::

        [[lam2 S_j, (G_i N_ij)'], [G_i N_ij, G_i + G_i' - S_i]] > 0                    (N_ij' S_i N_ij < lam2 S_j)
        [[Z_j, 0, (G_i N_ij)', I], [0, g I, (G_i B_ij)', -Xy_j'],
         [G_i N_ij, G_i B_ij, G_i + G_i' - Z_i, 0], [I, -Xy_j, 0, I]] > 0               (gain_y^2 <= g)

    with ``G_i N_ij = G_i PA_i - F C``, ``G_i B_ij = -(F + G_i N_ij Xy_j)``, and ``S_i >= I``: linear in
    ``(S, Z, G, F, g)``. The second is the poly-quadratic bounded real lemma (storage ``Z_j`` to ``Z_i``) that the
    card's ``gain_y`` re-checks; with ``gain_cap``, ``||G_i^-1 F|| <= gain_cap`` (:func:`uiofmu.gains.cap_lmis`).
    A point's gains are :func:`pair_noise_gain`; its decay Lyapunov matrices ``S_i``.
    """
    from .gains import cap_lmis
    from .lmi import Lmi, LmiSystem
    from .reductions import LYAPUNOV, matrix, scalar, symmetric

    C = np.asarray(C, dtype=float)
    PA, Xy = [np.asarray(a, dtype=float) for a in PA], [np.asarray(x, dtype=float) / sigma for x in Xy]
    N, n, p = len(PA), C.shape[1], C.shape[0]
    key = (lambda i, j: f"F{i}_{j}") if pair_gains else (lambda i, j: f"F{i}")      # noqa: E731

    def build(v, prm, ops):
        out = []
        for i in range(N):
            G = v[f"G{i}"]
            out.append(Lmi(f"S_{i + 1} >= I", v[f"S{i}"] - ops.eye(n), strict=False))
            GA, GG = G @ PA[i], G + G.T
            for j in range(N):
                F = v[key(i, j)]
                GN = GA - F @ C
                GB = -(F * (1.0 / sigma)) - GN @ Xy[j]
                out.append(Lmi(f"decay i={i + 1} j={j + 1}",
                               ops.bmat([[prm["lam2"] * v[f"S{j}"], GN.T], [GN, GG - v[f"S{i}"]]])))
                out.append(Lmi(f"bounded real lemma i={i + 1} j={j + 1} (gain_y^2 <= g)", ops.bmat([
                    [v[f"Z{j}"], ops.zeros((n, p)), GN.T, ops.eye(n)],
                    [ops.zeros((p, n)), v["g"] * ops.eye(p), GB.T, -Xy[j].T],
                    [GN, GB, GG - v[f"Z{i}"], ops.zeros((n, n))],
                    [ops.eye(n), -Xy[j], ops.zeros((n, n)), ops.eye(n)]])))
        if gain_cap is not None:
            out += cap_lmis(gain_cap, [(f"G_{i + 1}", v[f"G{i}"], [(key(i, j), v[key(i, j)])
                                                                  for j in (range(N) if pair_gains else (0,))])
                                       for i in range(N)], v["s"], ops)
        return out

    variables = {"g": scalar()}
    for i in range(N):
        variables.update({f"S{i}": symmetric(n), f"Z{i}": symmetric(n), f"G{i}": matrix((n, n), LYAPUNOV)})
        variables.update({key(i, j): matrix((n, p)) for j in (range(N) if pair_gains else (0,))})
    if gain_cap is not None:
        variables["s"] = scalar()
    return LmiSystem(f"{name} least noise gain", variables, {"lam2": 0.98}, build, objective=lambda v: v["g"],
                     structure=(PA, C, Xy, sigma, pair_gains, gain_cap))


def pair_noise_gain(values: dict, i: int, j: int | None = None) -> np.ndarray:
    """The output gain ``H_i`` (``H_ij`` with ``j``) of a point of :func:`pair_noise_lmis`: ``G_i^-1 F``."""
    F = values[f"F{i}" if j is None else f"F{i}_{j}"]
    return np.linalg.solve(np.asarray(values[f"G{i}"], dtype=float), np.asarray(F, dtype=float))


def least_of(candidates, lam: float, name: str, gain, parameter: str = "lam2") -> tuple:
    """The least-noise design at the decay ``lam`` of a family with several least-noise LMIs (each a
    ``(system, runtime, which)``, its points mapped to the card's matrices by ``runtime``): of the points that
    certify (the system's ``certify``), the one of least certified ``gain_y`` (``gain(matrices)``, None where not
    certified). The systems take ``lam^2`` as their parameter ``parameter``.

    Returns
    -------
    tuple
        ``(gain, (solution, matrices, which))``.

    Raises
    ------
    InfeasibleError
        When none has a certified point.
    """
    from .runtime.errors import InfeasibleError

    best, status = None, []
    for system, runtime, which in candidates:
        sol = system.solve(**{parameter: lam * lam})
        status.append(sol.status)
        if not sol.verified:
            continue
        mats = runtime(sol.values)
        found = gain(mats)
        if found is not None and (best is None or found < best[0]):
            best = (found, (sol, mats, which))
    if best is None:
        raise InfeasibleError(f"{name}: the least noise gain at decay {lam:.6g} (observer.noise = \"min\") has no "
                              f"certified point (CLARABEL: {', '.join(status)}); a slower decay leaves the LMIs room")
    return best


#: A least-noise point whose gain is below this fraction of the unit the LMIs measured the noise in is solved
#: again with its own gain as the unit (the solver's tolerance on ``g = (gain / unit)^2`` blurs a gain far below it).
NOISE_UNIT_REFINE = 0.1


def _least_in_units(candidates_for, default, sigma: float, lam: float, name: str, gain) -> tuple:
    """:func:`least_of` the candidates ``candidates_for(default, sigma)``, solved again in the units of the gain
    found where it is far below ``sigma`` (:data:`NOISE_UNIT_REFINE`); the lower certified gain."""
    from .runtime.errors import InfeasibleError

    found, design = least_of(candidates_for(default, sigma), lam, name, gain)
    if found < NOISE_UNIT_REFINE * sigma:
        try:
            again, other = least_of(candidates_for(default, max(found, 1e-300)), lam, name, gain)
        except InfeasibleError:
            return found, design
        if again < found:
            return again, other
    return found, design


def least_noise_design(family, lam: float, decay_max: bool, noise_gain, default: tuple, name: str) -> tuple:
    """``observer.noise = "min"`` or ``observer.noise_gain`` of a family with the callbacks ``family``, after its
    default design ``default`` at the decay ``lam``.

    ``noise = "min"``: the least-noise design at ``lam`` (with ``decay_max``, moved :data:`NOISE_DECAY_ROOM` of
    the way to 1), kept only where its certified gain is below the default's (the default's point certifies at
    the moved decay too). ``noise_gain``: the fastest decay at which that design (the default design at the decay,
    or its least-noise design where lower) has a certified gain of at most ``noise_gain`` (:func:`fastest_within`).

    Parameters
    ----------
    family : dict
        ``"default_at"``: ``rho -> (solution, matrices)`` of the default design at the decay ``rho`` or None;
        ``"candidates"``: ``(default matrices, sigma) -> list`` of :func:`least_of`'s candidates (the noise in
        units of ``1 / sigma``); ``"gain"``: ``matrices -> `` the card's certified ``gain_y`` or None.
    lam : float
        The default design's decay.
    decay_max : bool
        Whether the problem asked for the fastest decay.
    noise_gain : float or None
        ``observer.noise_gain``.
    default : tuple
        ``(solution, matrices)`` of the default design at ``lam``.
    name : str
        The problem's name, for the messages.

    Returns
    -------
    tuple
        ``(lam, design, record)``: ``design`` the ``(solution, matrices, which)`` of the least-noise point, or None
        where the card keeps the default design (the record says why).
    """
    from .runtime.errors import InfeasibleError

    gain = family["gain"]

    def least_at(rho: float, base: tuple | None) -> tuple:
        base_gain = None if base is None else gain(base[1])
        sigma = max(base_gain or 1.0, 1.0)
        try:
            found, design = _least_in_units(family["candidates"], None if base is None else base[1], sigma, rho,
                                            name, gain)
        except InfeasibleError:
            if base_gain is None:
                raise
            return base_gain, (*base, "default")
        if base_gain is not None and not found < base_gain:
            return base_gain, (*base, "default")
        return found, design

    if noise_gain is not None:
        goal = float(noise_gain)
        rho, found, design, search = fastest_within(lambda r: least_at(r, family["default_at"](r)), lam, goal, name)
        return rho, design, {"objective": "fastest decay with gain_y <= noise_gain", "noise_gain": goal,
                             "fastest_decay": lam, "fixed": design[2], "gain_y": found, "search": search}
    default_gain = gain(default[1])
    if decay_max:
        lam = lam + NOISE_DECAY_ROOM * (1.0 - lam)
    record = {"objective": "least gain_y at the decay", "decay": lam, "default_gain_y": default_gain}
    try:
        found, design = _least_in_units(family["candidates"], default[1], max(default_gain or 1.0, 1.0), lam, name,
                                        gain)
    except InfeasibleError as exc:
        return lam, None, {**record, "kept": "default", "why": str(exc)[:300]}
    if default_gain is not None and not found < default_gain:
        return lam, None, {**record, "kept": "default", "least_gain_y": found, "fixed": design[2],
                           "why": "the least-noise point's gain is not below it"}
    return lam, design, {**record, "kept": "least noise", "least_gain_y": found, "fixed": design[2]}


def section(gain_y=None, reason=None, gain_w=None, gain_dhat_y=None, **extra) -> dict:
    """A ``noise`` section: the gains (None where not certified), why some are None, and what re-checks them."""
    out = {"norm": NORM, "gain_y": gain_y, "gain_w": gain_w, "gain_dhat_y": gain_dhat_y, "reason": reason}
    out.update(extra)
    return out


def _response(A, B, C, D, w: np.ndarray) -> np.ndarray:
    """The largest singular value of ``C (e^{jw} I - A)^-1 B + D`` at each angle ``w``.

    All angles at once: one stacked solve (``B`` broadcast along the stack) and one stacked SVD, the same LAPACK
    calls on the same numbers as one angle at a time, so each value is the same to the last bit.
    """
    w = np.asarray(w, dtype=float)
    n = len(A)
    if n:
        Z = np.exp(1j * w)[:, None, None] * np.eye(n) - A
        H = D + C @ np.linalg.solve(Z, B.astype(complex))
    else:
        H = np.broadcast_to(D, (len(w),) + D.shape)
    if not (len(w) and H.shape[-2] and H.shape[-1]):
        return np.zeros(len(w))
    return np.linalg.svd(H, compute_uv=False).max(axis=-1)


def _refine(A, B, C, D, lo: np.ndarray, hi: np.ndarray) -> float:
    """The largest :func:`_response` found by zooming into each bracket ``[lo_i, hi_i]`` at once.

    Each round evaluates :data:`ZOOM_POINTS` equally spaced angles in every bracket (one stacked call for all
    brackets) and keeps, around the largest value of each, the two neighbouring points' bracket: every round
    divides the widths by ``(ZOOM_POINTS - 1) / 2``, until they are below :data:`ZOOM_WIDTH`. Near a smooth
    peak the response is flat to second order, so the value found is the peak's to the last digits; the
    result is the largest value evaluated (never below the sweep's, which it starts from).
    """
    t = np.linspace(0.0, 1.0, ZOOM_POINTS)
    best = 0.0
    while True:
        w = lo[:, None] + (hi - lo)[:, None] * t[None, :]
        g = _response(A, B, C, D, w.ravel()).reshape(w.shape)
        best = max(best, float(g.max()))
        if float((hi - lo).max()) <= ZOOM_WIDTH:
            return best
        j = np.argmax(g, axis=1)
        rows = np.arange(len(lo))
        lo = np.maximum(w[rows, np.maximum(j - 1, 0)], 0.0)
        hi = np.minimum(w[rows, np.minimum(j + 1, ZOOM_POINTS - 1)], np.pi)


def _sweep_norm(A, B, C, D) -> float:
    """The largest :func:`_response` of a sweep of :data:`SWEEP_POINTS` angles on [0, pi] and the angles of the
    poles, refined by a stacked zoom (:func:`_refine`) into the brackets of the three largest: where the
    level sets of :func:`hinf_norm` cannot be read off its pencil."""
    poles = np.abs(np.angle(np.linalg.eigvals(A))) if len(A) else np.zeros(0)
    w = np.unique(np.concatenate([np.linspace(0.0, np.pi, SWEEP_POINTS), poles]))
    g = _response(A, B, C, D, w)
    step = np.pi / (SWEEP_POINTS - 1)
    top = w[np.argsort(g)[-3:]]
    return max(float(g.max()), _refine(A, B, C, D, np.maximum(top - step, 0.0), np.minimum(top + step, np.pi)))


def _crossings(A, B, C, D, level: float):
    """The angles in [0, pi] at which ``level`` is a singular value of ``G(e^{jw}) = C (e^{jw} I - A)^-1 B + D``:
    the unit-circle eigenvalues ``z`` of the pencil ``M - z E`` (see :func:`hinf_norm`), for ``G / level`` at
    level 1. None when the pencil leaves some eigenvalue undetermined (``alpha = beta = 0``: a singular pencil) or
    not finite, or when its eigenvalues near the circle do not come in the pairs ``(z, 1 / conj(z))`` its
    structure gives them to :data:`CIRCLE_TOL` (rounding has moved them too far to tell which are on it)."""
    dggev = blas_module("scipy.linalg.lapack").dggev

    n, m = B.shape
    Bs, Cs, Ds = B, C / level, D / level
    big_b, big_c = float(np.abs(B).max()), float(np.abs(Cs).max())
    if big_b > 0.0 and big_c > 0.0:        # eps = c eps_s, c a power of 2: B and C / level of one size
        c = math.ldexp(1.0, max(-1000, min(1000, round(0.5 * (math.log2(big_b) - math.log2(big_c))))))
        Bs, Cs = B / c, Cs * c
    M, E = np.zeros((2, 2 * n + m, 2 * n + m))
    M[:n, :n], M[:n, 2 * n:], M[2 * n:, :n], M[2 * n:, n:2 * n] = A, Bs, Ds.T @ Cs, Bs.T
    M[2 * n:, 2 * n:] = Ds.T @ Ds - np.eye(m)
    M[n:2 * n, n:2 * n] = E[:n, :n] = np.eye(n)
    E[n:2 * n, :n], E[n:2 * n, n:2 * n], E[n:2 * n, 2 * n:] = Cs.T @ Cs, A.T, Cs.T @ Ds
    if not (np.isfinite(M).all() and np.isfinite(E).all()):
        return None
    re, im, beta, _, _, _, info = dggev(M, E, compute_vl=0, compute_vr=0, overwrite_a=1, overwrite_b=1)
    alpha = re + 1j * im
    a, b = np.abs(alpha), np.abs(beta)
    if info != 0 or not (np.isfinite(a).all() and np.isfinite(b).all()) or (np.maximum(a, b) == 0.0).any():
        return None
    near = (a < 2.0 * b) & (b < 2.0 * a)
    z = alpha[near] / beta[near]
    on = np.abs(np.abs(z) - 1.0) <= CIRCLE_TOL
    mirror = 1.0 / np.conj(z[~on])              # the eigenvalues off the circle come in pairs (z, 1 / conj(z))
    if len(mirror) and (np.abs(mirror[:, None] - z[None, :]).min(axis=1) > CIRCLE_TOL * np.abs(mirror)).any():
        return None
    return np.abs(np.angle(z[on]))


def hinf_norm(A, B, C, D) -> float:
    """The H-infinity norm of the discrete system ``(A, B, C, D)`` (``A`` Schur stable): a lower bound, the
    largest singular value of ``G(e^{jw})`` at an angle found, within :data:`LEVEL_GAP` of the norm.

    The level sets (Boyd and Balakrishnan; Bruinsma and Steinbuch): ``level`` is a singular value of
    ``G(z) = C (zI - A)^-1 B + D`` at ``z = e^{jw}`` when ``level^2 u = G(z)^H G(z) u`` for some ``u != 0``; with
    ``x = (zI - A)^-1 B u``, ``y = C x + D u`` and ``p`` the state of ``G(1/z)'`` fed ``y``, that is the pencil
    ``M v = z E v`` in ``v = (x, p, u)``::

        M = [[A, 0, B], [0, I, 0], [D'C, B', D'D - level^2 I]],   E = [[I, 0, 0], [C'C, A', C'D], [0, 0, 0]]

    (for ``G / level`` at level 1, numbers near 1 whatever the gains). Its eigenvalues on the unit circle are the
    angles where the response crosses ``level``. The largest response at ``0``, ``pi`` and the angles of the
    poles is a first lower bound; then, at the level ``(1 + LEVEL_GAP)`` times the lower bound, the response at
    the midpoints between the crossings (and the ends) is the next one (above the level wherever a midpoint
    falls in an interval the response exceeds it: quadratic convergence near a peak), until no eigenvalue is on
    the circle (the norm is below that level) or the midpoints bring no increase (the level is at the peak to
    the rounding of the eigenvalues). Where the pencil's eigenvalues are undetermined or :data:`LEVELS` levels
    do not settle it, the sweep :func:`_sweep_norm` (never below the levels' bound). The system is first brought
    to the coordinates that balance ``A`` (:func:`_balanced`), where rounding leaves the pencil's eigenvalues in
    their pairs; a value below the true norm is caught by the certificate's re-check.
    """
    A, B, C, D = (np.asarray(m, dtype=float) for m in (A, B, C, D))
    Ab, Bb, Cb, _ = _balanced(A, B, C)
    return _level_norm(Ab, Bb, Cb, D)


def _balancing(A) -> np.ndarray:
    """The diagonal scaling (powers of 2) that balances the rows and columns of ``A``, no permutation: LAPACK's
    ``dgebal``, the call ``scipy.linalg.matrix_balance(A, permute=False)`` makes, without its wrappers."""
    dgebal = blas_module("scipy.linalg.lapack").dgebal

    if not len(A):
        return np.ones(0)
    if not np.isfinite(A).all():
        raise np.linalg.LinAlgError("Array must not contain infs or NaNs")
    _, lo, hi, scale, info = dgebal(A, scale=1, permute=0)
    if info != 0 or (lo, hi) != (0, len(A) - 1) or not np.isfinite(scale).all():
        raise np.linalg.LinAlgError(f"dgebal did not balance a {len(A)}x{len(A)} matrix (info {info})")
    return np.asarray(scale, dtype=float)


def _balanced(A, B, C) -> tuple:
    """``(A, B, C)`` in the coordinates ``eps = diag(s) eps_b`` that balance ``A`` (:func:`_balancing`, powers of
    2: exact, and the response is the same), and ``s``."""
    s = _balancing(A)
    return A * s[None, :] / s[:, None], B / s[:, None], C * s[None, :], s


def _level_norm(A, B, C, D, poles: np.ndarray | None = None) -> float:
    """:func:`hinf_norm` of a system whose ``A`` is balanced (:func:`_balanced`); ``poles``: the angles of the
    eigenvalues of ``A`` (:func:`_pole_angles`), where already computed."""
    if not (B.shape[1] and C.shape[0]):
        return 0.0
    if not len(A):
        return float(_response(A, B, C, D, np.zeros(1))[0])
    poles = _pole_angles(A) if poles is None else poles
    best = float(_response(A, B, C, D, np.concatenate([[0.0, np.pi], poles])).max())
    for _ in range(LEVELS):
        if not (math.isfinite(best) and best > 0.0):
            break
        cross = _crossings(A, B, C, D, best * (1.0 + LEVEL_GAP))
        if cross is None:
            break
        if not len(cross):
            return best
        edges = np.unique(np.concatenate([[0.0], np.minimum(cross, np.pi), [np.pi]]))
        found = float(_response(A, B, C, D, 0.5 * (edges[1:] + edges[:-1])).max())
        if not found > best:
            return best
        best = found
    return max(best, _sweep_norm(A, B, C, D)) if math.isfinite(best) else _sweep_norm(A, B, C, D)


def _pole_angles(A) -> np.ndarray:
    """The angles in [0, pi] of the eigenvalues of ``A``."""
    return np.abs(np.angle(np.linalg.eigvals(A)))


def scaled_definite_check(name: str, Q: np.ndarray, terms: np.ndarray, length: int) -> Check:
    """``Q > 0`` decided on ``D Q D``, ``D = diag(terms)^(-1/2)``, with margin over its own rounding.

    A positive diagonal congruence keeps the sign of ``Q``; evaluated in double precision it adds two roundings
    to each entry (``length + 2``), and it brings the rounding floor of a badly scaled ``Q`` (an error system with
    gains of 1e6 next to entries of 1e-6) down to the size of its entries (:func:`uiofmu.certificate.definite_check`,
    no margin beyond the rounding: the gain's rounding up is the margin).
    """
    scale = terms.diagonal().copy()
    d = 1.0 / np.sqrt(np.where(scale > 0, scale, 1.0))
    return definite_check(name, d[:, None] * Q * d[None, :], d[:, None] * terms * d[None, :], length + 2, margin=0.0)


def _brl_matrix(A, B, C, D, X_in, X_out, gamma: float) -> tuple:
    """The bounded real lemma's matrix of one step from storage ``X_in`` to ``X_out``, and its terms' sizes."""
    aA, aB, aC, aD, aI, aO = (np.abs(m) for m in (A, B, C, D, X_in, X_out))
    g2 = float(gamma) ** 2
    n, eye = len(A), np.eye(B.shape[1])
    Q, terms = np.empty((2, n + B.shape[1], n + B.shape[1]))
    Q[:n, :n], Q[:n, n:] = X_in - A.T @ X_out @ A - C.T @ C, -(A.T @ X_out @ B + C.T @ D)
    Q[n:, :n], Q[n:, n:] = -(B.T @ X_out @ A + D.T @ C), g2 * eye - B.T @ X_out @ B - D.T @ D
    terms[:n, :n], terms[:n, n:] = aI + aA.T @ aO @ aA + aC.T @ aC, aA.T @ aO @ aB + aC.T @ aD
    terms[n:, :n], terms[n:, n:] = aB.T @ aO @ aA + aD.T @ aC, g2 * eye + aB.T @ aO @ aB + aD.T @ aD
    return 0.5 * (Q + Q.T), terms


def _worst(checks: list) -> Check:
    """The first check that fails, else the one with the least room."""
    return next((c for c in checks if not c.holds), None) or min(checks, key=lambda c: c.value - c.bound)


def brl_checks(A, B, C, D, X, gamma: float, label: str = "gain_y") -> list:
    """The bounded real lemma at stored matrices: ``X > 0`` and the BRL matrix ``> 0`` (see the module),
    each decided with margin over its own rounding (:func:`scaled_definite_check`)."""
    A, B, C, D, X = (np.asarray(m, dtype=float) for m in (A, B, C, D, X))
    Q, terms = _brl_matrix(A, B, C, D, X, X, gamma)
    length = 2 * len(A) + C.shape[0] + 2
    return [scaled_definite_check(f"noise {label}: eig_min(X)", 0.5 * (X + X.T), np.abs(X), 1),
            scaled_definite_check(f"noise {label}: bounded real lemma at gamma = {figure_text(gamma, NOISE_DIGITS)}",
                                  Q, terms, length)]


def _output(M: np.ndarray, i: int, j: int) -> np.ndarray:
    """The output matrix of the step ``(i, j)`` of a switched error system: ``M[j]`` of a stack per previous mode,
    ``M[i][j]`` of a stack per pair (an output that reads both, as dhat's does)."""
    return M[i, j] if M.ndim == 4 else M[j]


def _switched_steps(A, B, C, D) -> list:
    """The steps of a switched error system (see :func:`switched_brl_checks`) as :func:`lemma_checks` takes them."""
    modes = len(A)
    return [(A[i, j], B[i, j], _output(C, i, j), _output(D, i, j), j, i, f"from X_{j + 1} to X_{i + 1}")
            for i in range(modes) for j in range(modes)]


def lemma_checks(steps: list, X, gamma: float, label: str = "gain_y") -> list:
    """The bounded real lemma of every step at stored matrices, the worst case over the storage matrices and the
    steps: ``X[s] > 0``, and for each step ``(A, B, C, D, s_in, s_out, name)`` the lemma's matrix from ``X[s_in]``
    to ``X[s_out]`` ``> 0``, each decided with margin over its own rounding (:func:`scaled_definite_check`)."""
    X = np.asarray(X, dtype=float)
    n = X.shape[-1]
    positive = [scaled_definite_check(f"noise {label}: eig_min(X_{s + 1})", 0.5 * (X[s] + X[s].T), np.abs(X[s]), 1)
                for s in range(len(X))]
    lemma = []
    at = f"at gamma = {figure_text(gamma, NOISE_DIGITS)}"
    for A, B, C, D, s_in, s_out, name in steps:
        A, B, C, D = (np.asarray(m, dtype=float) for m in (A, B, C, D))
        lemma.append(scaled_definite_check(f"noise {label}: bounded real lemma {name} {at}",
                                           *_brl_matrix(A, B, C, D, X[s_in], X[s_out], gamma),
                                           2 * n + C.shape[0] + 2))
    return [_worst(positive), _worst(lemma)]


def switched_brl_checks(A, B, C, D, X, gamma: float, label: str = "gain_y") -> list:
    """The poly-quadratic bounded real lemma of a switched error system at stored matrices, the worst case
    over the modes and pairs.

    The step from ``k`` to ``k + 1`` in the mode ``i = alpha_k`` after ``j = alpha_(k-1)`` is
    ``eps+ = A[i][j] eps + B[i][j] v``, ``e = C[j] eps + D[j] v`` (``C[i][j]``, ``D[i][j]`` where ``C`` and ``D``
    are stacks per pair, as :func:`pair_dhat_error_system`'s); the storage ``eps' X[alpha_(k-1)] eps``
    goes from ``X[j]`` to ``X[i]``: ``X[i] > 0`` and the lemma's matrix from ``X[j]`` to ``X[i]`` ``> 0`` for every
    pair (i, j) give the gain under every switching sequence.
    """
    A, B, C, D = (np.asarray(m, dtype=float) for m in (A, B, C, D))
    return lemma_checks(_switched_steps(A, B, C, D), X, gamma, label)


def pair_error_system(matrices: dict) -> tuple:
    """The error system from output noise of a runtime whose step ``(i, j)`` (this step's mode or interval, and the
    previous one) is ``z+ = N_ij z + L_ij y + ...`` with ``xhat = z + Xy_j y`` (``Xz_j = I``), as stacks for
    :func:`switched_brl_checks`: ``eps+ = N_ij eps - L_ij v``, ``e = eps - Xy_j v``, ``eps`` the error before the
    new sample's share ``Xy_j v`` (the family's identities, which its certificate re-checks, make the plant's
    inputs cancel from ``eps`` as they do from ``e``)."""
    N, L, Xy = (np.asarray(matrices[k], dtype=float) for k in ("N", "L", "Xy"))
    modes, n = N.shape[0], N.shape[-1]
    return N, -L, np.repeat(np.eye(n)[None], modes, axis=0), -Xy


def pair_process_error_system(matrices: dict) -> tuple:
    """The error system from process noise ``w`` (held over the step: ``x+ = ... + W_i w``, ``W_i`` the card's
    ``W_sampled`` of this step's mode or interval) of a runtime stepping on pairs, as stacks for
    :func:`switched_brl_checks`: ``eps+ = N_ij eps + (I - Xy_i C) W_i w``, ``e = eps`` (``eps = (I - Xy_j C) x - z``
    is the error itself without output noise; the family's identities make every other input cancel, as in
    :func:`pair_error_system`)."""
    N, Xy, C, W = (np.asarray(matrices[k], dtype=float) for k in ("N", "Xy", "C", "W_sampled"))
    modes, n = N.shape[0], N.shape[-1]
    B = (np.eye(n)[None] - Xy @ C) @ W                                  # (modes, n, r): this step's i
    return (N, np.repeat(B[:, None], modes, axis=1), np.repeat(np.eye(n)[None], modes, axis=0),
            np.zeros((modes, n, W.shape[-1])))


def dhat_error_step(N, L, Xz, Xy, Dy, Yx) -> tuple:
    """The error of ``dhat`` from output noise ``v`` over one step of an affine runtime, as a system one step
    ahead.

    With ``xhat_k = Xz z_k + Xy y_k`` and the noise error ``e_k = Xz eps_k - Xy v_k`` (``eps`` the error of ``z``:
    ``eps+ = N eps - L v``), ``dhat_(k+1) = Dy (y_(k+1) - Yx xhat_k - Yu u_k - Yc)`` with ``Dy C E = I``,
    ``Yx = C A``, ``Yu = C B`` and ``Yc = C w`` (the plant's step that ``Dy`` inverts) reads the next sample::

        dhat_(k+1) - d_k = Dy (Yx e_k + v_(k+1))

    In the time ``t = k + 1`` the state is ``(eps_(t-1), v_(t-1))``: ``A = [[N, -L], [0, 0]]``, ``B = [0; I]``,
    ``C = Dy Yx [Xz, -Xy]``, ``D = Dy`` (a shift by one step leaves l2 norms as they are). A runtime on a
    schedule passes each step's matrices (:func:`pair_dhat_error_system`).

    Returns
    -------
    tuple
        ``(A, B, C, D)`` of the state ``(eps, v_prev)``.
    """
    N, L, Xz, Xy, Dy, Yx = (np.asarray(m, dtype=float) for m in (N, L, Xz, Xy, Dy, Yx))
    nz, p = L.shape
    A, B = np.zeros((nz + p, nz + p)), np.zeros((nz + p, p))
    A[:nz, :nz], A[:nz, nz:], B[nz:] = N, -L, np.eye(p)
    DyYx = Dy @ Yx
    return A, B, np.concatenate([DyYx @ Xz, -DyYx @ Xy], axis=1), Dy


def pair_dhat_error_system(matrices: dict) -> tuple:
    """The error of ``dhat`` from output noise of a runtime on pairs (:func:`pair_error_system`'s), as stacks per
    pair for :func:`switched_brl_checks`.

    The runtime's step from ``t_k`` in the mode or interval ``i`` after ``j`` is ``z+ = N_ij z + L_ij y + ...``
    and stores ``Yx_i xhat_k + Yu_i u_k + Yc_i``; at ``t_(k+1)`` the output matrices are those after ``i``:
    ``xhat_(k+1) = z + Xy_i y``, ``dhat_(k+1) = Dy_i (y_(k+1) - Yx_i xhat_k - Yu_i u_k - Yc_i)``. With ``Dy_i``,
    ``Yx_i``, ``Yu_i``, ``Yc_i`` the step of the plant in ``i`` (``Dy_i C E_i = I``, ...) and
    ``e_k = eps_k - Xy_j v_k``::

        dhat_(k+1) - d_k = Dy_i Yx_i (eps_k - Xy_j v_k) + Dy_i v_(k+1)

    so in the time ``t = k + 1``, with the state ``(eps_(t-1), v_(t-1))``, the step ``(i, j)`` (the pair of the
    step just taken, from ``t - 1`` to ``t``: the same as the state's next step) is :func:`dhat_error_step` of
    ``(N_ij, L_ij, I, Xy_j, Dy_i, Yx_i)``: ``A[i][j] = [[N_ij, -L_ij], [0, 0]]``, ``B = [0; I]``, the output
    ``C[i][j] = Dy_i Yx_i [I, -Xy_j]`` and ``D[i][j] = Dy_i`` read both indices. The storage of the state at ``t``
    is the one of the step before it (``X_j``), so the lemma's pairs are :func:`switched_brl_checks`'s.
    """
    N, L, Xy, Dy, Yx = (np.asarray(matrices[k], dtype=float) for k in ("N", "L", "Xy", "Dy", "Yx"))
    modes, n = N.shape[0], N.shape[-1]
    eye = np.eye(n)
    steps = [[dhat_error_step(N[i, j], L[i, j], eye, Xy[j], Dy[i], Yx[i]) for j in range(modes)]
             for i in range(modes)]
    return tuple(np.array([[step[part] for step in row] for row in steps]) for part in range(4))


def gains_section(matrices: dict, y, w, dhat, no_w: str) -> dict:
    """A ``noise`` section of the gains certified by ``y()``, ``w()`` and ``dhat()`` (each ``(gain, extra, why)``,
    :func:`stated`): ``w`` where the card has ``W_sampled`` with a column, ``dhat`` where it has dhat's ``Dy``; ``no_w``
    says why a card without ``W_sampled`` has no ``gain_w``."""
    gain, extra, why = y()
    reasons, gains = [why] if why else [], {"gain_w": None, "gain_dhat_y": None}
    has = {"gain_w": matrices.get("W_sampled") is not None and np.shape(matrices["W_sampled"])[-1] > 0,
           "gain_dhat_y": matrices.get("Dy") is not None}
    for key, certify in (("gain_w", w), ("gain_dhat_y", dhat)):
        if has[key]:
            gains[key], more, why = certify()
            extra.update(more)
            reasons += [why] if why else []
        elif key == "gain_w":
            reasons.append(no_w)
    return section(gain, "; ".join(reasons) or None, **gains, **extra)


def pair_section(matrices: dict, no_w: str) -> dict:
    """The ``noise`` section of a card whose runtime steps on pairs (modes or intervals): ``gain_y``
    (:func:`pair_error_system`), ``gain_w`` where the card has ``W_sampled`` (:func:`pair_process_error_system`) and,
    where it has dhat's matrices, ``gain_dhat_y`` (:func:`pair_dhat_error_system`), each by the poly-quadratic lemma
    for every sequence (:func:`gains_section`)."""
    return gains_section(
        matrices, lambda: certified(*pair_error_system(matrices), switched=True),
        lambda: certified(*pair_process_error_system(matrices), key="gain_w", switched=True),
        lambda: certified(*pair_dhat_error_system(matrices), key="gain_dhat_y", switched=True, balanced=True), no_w)


def pair_checks(noise, matrices: dict) -> list:
    """The re-check of the gains of :func:`pair_section` at a card's stored matrices; a ``gain_dhat_y`` claimed by
    a card without dhat's matrices fails."""
    out = recheck(noise, *pair_error_system(matrices), switched=True)
    if isinstance(noise, dict) and noise.get("gain_w") is not None:
        out += (claimed_without("gain_w", matrices, ("W_sampled",), "the sampled process noise") or
                recheck(noise, *pair_process_error_system(matrices), key="gain_w", switched=True))
    if not isinstance(noise, dict) or noise.get("gain_dhat_y") is None:
        return out
    return out + (dhat_missing(matrices) or
                  recheck(noise, *pair_dhat_error_system(matrices), key="gain_dhat_y", switched=True))


def claimed_without(key: str, matrices: dict, names: tuple, what: str) -> list:
    """The failed check of a gain ``noise.<key>`` claimed by a card without the matrices ``names`` its error system
    is made of (``what`` they are); none where the card has them."""
    if any(matrices.get(k) is None for k in names):
        return [Check(f"noise.{key} claimed by a card without {what} (matrices {', '.join(names)} present)", 0.0, 1.0,
                      at_most=False)]
    return []


def dhat_missing(matrices: dict) -> list:
    """:func:`claimed_without` of ``gain_dhat_y``: dhat's matrices ``Dy``, ``Yx``."""
    return claimed_without("gain_dhat_y", matrices, ("Dy", "Yx"), "dhat")


def switched_brl_certificate(A, B, C, D, label: str = "gain_y", balanced: bool = False) -> dict:
    """The least certified l2 gain of a switched error system (:func:`switched_brl_checks`); see
    :func:`lemma_certificate` (``balanced``: solved in balanced state coordinates)."""
    A, B, C, D = (np.asarray(m, dtype=float) for m in (A, B, C, D))
    modes = len(A)
    if modes * modes > MAX_PAIRS:
        return {"gamma": None, "why": f"{modes} modes or intervals give {modes * modes} pairs, more than the "
                                      f"{MAX_PAIRS} the lemma is solved for"}
    sigma = max(hinf_norm(A[i, i], B[i, i], _output(C, i, i), _output(D, i, i)) for i in range(modes))
    return lemma_certificate(_switched_steps(A, B, C, D), modes, sigma, label, balanced)


#: Most sweeps of :func:`state_balance`, and the entries it counts as zero (relative to the largest).
BALANCE_SWEEPS, BALANCE_FLOOR = 32, 1e-12


def state_balance(steps: list) -> np.ndarray:
    """Powers of 2 ``s`` such that in the coordinates ``eps = diag(s) eps_b`` each state's row of ``[A, B]`` and
    column of ``[A; C]`` (the largest magnitudes over the steps, the diagonal aside) have about the same sum:
    Osborne's balancing on the graph of the states, the input and the output, the input and the output held
    unscaled (the gain is the same in either coordinates). Exact in floating point (powers of 2) and decided on
    sums of magnitudes, not on any BLAS kernel's rounding: entries below :data:`BALANCE_FLOOR` times the largest
    (an exact zero computed as rounding, e.g. the rows of a dead-beat ``N``) count as zero, and a state without an
    in- or outgoing edge keeps 1.
    """
    aA, aB, aC = (np.max([np.abs(step[k]) for step in steps], axis=0) for k in range(3))
    floor = BALANCE_FLOOR * max(float(a.max()) if a.size else 0.0 for a in (aA, aB, aC))
    aA, aB, aC = (np.where(a > floor, a, 0.0) for a in (aA, aB, aC))
    aA = aA - np.diag(np.diag(aA))
    aB, aC = aB.sum(axis=1), aC.sum(axis=0)
    s = np.ones(len(aA))
    for _ in range(BALANCE_SWEEPS):
        moved = False
        for k in range(len(s)):
            out = float(np.sum(aA[k] * s) / s[k] + aB[k] / s[k])          # row k of [A_b, B_b]
            into = float(np.sum(aA[:, k] / s) * s[k] + aC[k] * s[k])      # column k of [A_b; C_b]
            if out > 0.0 and into > 0.0:
                f = 2.0 ** round(0.5 * math.log2(out / into))
                if f != 1.0:
                    s[k], moved = s[k] * f, True
        if not moved:
            break
    return s


def lemma_certificate(steps: list, storages: int, sigma: float, label: str = "gain_y",
                      balanced: bool = False) -> dict:
    """The least l2 gain that the bounded real lemma of every step (:func:`lemma_checks`) certifies, to
    :data:`NOISE_DIGITS`.

    The LMIs of the lemma for every step, with ``storages`` storage matrices and ``g`` bounding
    ``(gamma / (unit scale))^2`` minimised (CLARABEL; the outputs divided by their largest entry ``scale`` and the
    input measured in ``unit = sigma / scale``, ``sigma`` a lower bound of ``gamma``, e.g. the largest H-infinity
    norm of a mode held constant, so that the solver sees numbers near 1 whatever the gains, ``g`` too; where that
    solve certifies nothing and ``scale`` is not 1, once more with ``unit = sigma``, which CLARABEL solves on some
    error systems of dhat where the former fails; with ``balanced``, in the state coordinates of
    :func:`state_balance`); then ``gamma`` from ``g``, times
    ``1 + NOISE_MARGIN``, rounded up, and re-checked at the stored matrices with the solver's ``X`` (mapped back),
    growing by :data:`GROWTH` where it fails.

    Returns
    -------
    dict
        As :func:`brl_certificate` (``lmi_gamma``, the solver's, in place of ``hinf_norm``).
    """
    steps = [tuple(np.asarray(m, dtype=float) for m in step[:4]) + tuple(step[4:]) for step in steps]
    sigma = max(float(sigma), 1e-300)
    t = state_balance(steps) if balanced else np.ones(steps[0][0].shape[0])       # eps = diag(t) eps_b
    solved = [(A * t[None, :] / t[:, None], B / t[:, None], C * t[None, :], *rest) for A, B, C, *rest in steps]
    scale = max(float(np.abs(step[2]).max()) if step[2].size else 0.0 for step in solved) or 1.0
    found = _lemma_try(steps, solved, t, storages, sigma / scale, scale, label)
    if found["gamma"] is None and scale != 1.0:
        again = _lemma_try(steps, solved, t, storages, sigma, scale, label)
        return again if again["gamma"] is not None else found
    return found


def _lemma_try(steps: list, solved: list, t: np.ndarray, storages: int, unit: float, scale: float,
               label: str) -> dict:
    """One solve of :func:`lemma_certificate`'s LMIs (the steps ``solved`` in the coordinates ``eps = diag(t)
    eps_b``, the input in ``unit``, the output in ``scale``) and the re-check of its gamma at ``steps``."""
    from .lmi import Lmi, LmiSystem
    from .reductions import scalar, symmetric

    n, p, r = solved[0][0].shape[0], solved[0][1].shape[1], solved[0][2].shape[0]

    def build(v, prm, ops):
        out = []
        for A, B, C, D, s_in, s_out, name in solved:
            Xo = v[f"X{s_out}"]
            XA, XB = Xo @ A, Xo @ (B / unit)
            Cs, Ds = C / scale, D / (unit * scale)
            out.append(Lmi(f"bounded real lemma {name}", ops.bmat([
                [v[f"X{s_in}"], ops.zeros((n, p)), XA.T, Cs.T],
                [ops.zeros((p, n)), v["g"] * ops.eye(p), XB.T, Ds.T],
                [XA, XB, Xo, ops.zeros((n, r))],
                [Cs, Ds, ops.zeros((r, n)), ops.eye(r)]])))
        return out

    variables = {**{f"X{s}": symmetric(n) for s in range(storages)}, "g": scalar()}
    system = LmiSystem(f"noise {label}", variables, {}, build, objective=lambda v: v["g"],
                       structure=([step[:6] for step in solved], unit, scale))
    sol = system.solve()
    if not sol.values:
        return {"gamma": None, "why": f"the bounded real lemma's LMIs have no solution (CLARABEL: {sol.status})"}
    # the LMIs are the lemma of (A, B / unit, C / scale, D / (unit scale)) for the input unit v and the output
    # e / scale: multiplied by scale^2, its storage inequality is the card's at gamma = unit scale sqrt(g) (in the
    # balanced coordinates: X = diag(t)^-1 X_b diag(t)^-1 in the stored ones)
    Xb = np.array([0.5 * (sol.values[f"X{s}"] + sol.values[f"X{s}"].T) for s in range(storages)]) * scale ** 2
    X = Xb / t[None, :, None] / t[None, None, :]
    least = unit * scale * math.sqrt(max(float(sol.values["g"]), 0.0))
    if not (np.all(np.isfinite(X)) and math.isfinite(least)):
        return {"gamma": None, "why": "the bounded real lemma's point is not finite in the stored coordinates"}
    gamma = round_up(max(least, 1e-300) * (1.0 + NOISE_MARGIN), NOISE_DIGITS)
    for _ in range(TRIES):
        checks = lemma_checks(steps, X, gamma, label)
        if all(c.holds for c in checks):
            return {"gamma": gamma, "X": X, "initial_term": float(np.sqrt(np.linalg.eigvalsh(X)[:, -1].max())),
                    "lmi_gamma": least, "checks": checks}
        last, gamma = gamma, round_up(gamma * GROWTH, NOISE_DIGITS)
    return {"gamma": None, "why": f"no bounded real lemma certificate up to gamma = {figure_text(last, NOISE_DIGITS)} "
                                  "survives the re-check at the stored matrices"}


def _riccati(A, B, C, D, gamma: float, delta: float) -> np.ndarray:
    """The stabilising solution of the bounded real Riccati equation at ``gamma``, with ``delta I`` added to
    ``C'C`` (the strictness the re-check needs).

    With ``Q = C'C + delta I``, ``R = D'D - gamma^2 I`` and ``S = C'D``, ``X`` solves
    ``X = A'XA - (A'XB + S)(B'XB + R)^-1 (B'XA + S') + Q`` with ``A + B K`` Schur stable. It is read off the
    stable deflating subspace ``[I; X] T`` of the extended pencil in ``(x, p, u)`` (Van Dooren)::

        H = [[A, 0, B], [-Q, I, -S], [S', 0, R]],   J = [[I, 0, 0], [0, A', 0], [0, -B', 0]]

    after a diagonal scaling ``diag(d, 1/d, e)`` in powers of 2 that keeps its structure (Benner: with ``s`` the
    balancing of the pencil's magnitudes, :func:`_balancing`, ``d = sqrt(s_p / s_x)`` rounded to a power of 2
    and ``e = s_u``; ``X`` is ``diag(d)`` times the scaled pencil's ``X`` times ``diag(d)``), the ``u`` columns
    deflated by an orthogonal complement of ``[B; -S; R]``, and the ``n`` eigenvalues inside the unit circle
    ordered first (``scipy.linalg.ordqz``).

    Raises
    ------
    numpy.linalg.LinAlgError
        When the pencil is not finite, does not have ``n`` eigenvalues inside the circle, or its subspace is not a
        graph.
    """
    ordqz = blas_module("scipy.linalg").ordqz

    n, m = B.shape
    H, J = np.zeros((2, 2 * n + m, 2 * n + m))
    with np.errstate(all="ignore"):         # an overflow is refused below
        H[:n, :n], H[:n, 2 * n:], H[n:2 * n, :n] = A, B, -(C.T @ C + delta * np.eye(n))
        H[n:2 * n, 2 * n:], H[2 * n:, :n] = -(C.T @ D), D.T @ C
        H[2 * n:, 2 * n:] = D.T @ D - gamma * gamma * np.eye(m)
    H[n:2 * n, n:2 * n] = J[:n, :n] = np.eye(n)
    J[n:2 * n, n:2 * n], J[2 * n:, n:2 * n] = A.T, -B.T
    size = np.abs(H) + np.abs(J)
    if not np.isfinite(size).all():
        raise np.linalg.LinAlgError(f"the Riccati pencil at gamma = {gamma:g} has entries beyond double precision")
    np.fill_diagonal(size, 0.0)
    e = np.log2(_balancing(size))
    d = 2.0 ** np.round(0.5 * (e[n:2 * n] - e[:n]))
    scale = np.concatenate([d, 1.0 / d, 2.0 ** e[2 * n:]])
    H, J = H * scale[:, None] / scale[None, :], J * scale[:, None] / scale[None, :]
    q = np.linalg.qr(H[:, 2 * n:], mode="complete")[0][:, m:]
    _, _, alpha, beta, _, Z = ordqz(q.T @ H[:, :2 * n], q.T @ J[:, :2 * n], sort="iuc", output="real",
                                    check_finite=False)
    if np.count_nonzero(np.abs(alpha) < np.abs(beta)) != n:
        raise np.linalg.LinAlgError(f"the Riccati pencil at gamma = {gamma:g} has not {n} eigenvalues inside the "
                                    "unit circle")
    X = np.linalg.solve(Z[:n, :n].T, Z[n:, :n].T).T * d[:, None] * d[None, :]      # [I; X] spans [Z_11; Z_21]
    return 0.5 * (X + X.T)


def brl_certificate(A, B, C, D, label: str = "gain_y") -> dict:
    """The least certified l2 gain of ``eps+ = A eps + B v``, ``e = C eps + D v`` to :data:`NOISE_DIGITS`.

    The Riccati equation is solved in the coordinates that balance ``A`` (powers of 2, exact:
    :func:`_balancing`), where a plant with gains of 1e6 still has an accurate solution, and its
    ``X`` is mapped back; the checks are at the given matrices.

    Returns
    -------
    dict
        ``gamma`` (the gain the re-check proves), ``X``, ``initial_term`` (``sqrt(eig_max(X))``),
        ``hinf_norm`` (:func:`hinf_norm`'s) and the checks; ``gamma`` None (with ``why``) when no try certifies.
    """
    A, B, C, D = (np.asarray(m, dtype=float) for m in (A, B, C, D))
    Ab, Bb, Cb, s = _balanced(A, B, C)                                          # eps = diag(s) eps_b
    poles = _pole_angles(Ab) if len(A) else None                               # both norms' first angles
    norm = _level_norm(Ab, Bb, Cb, D, poles)
    # delta I added to C'C raises the gain by at most delta h^2 / (2 gamma), h = ||(zI - A)^-1 B||_inf.
    h = _level_norm(Ab, Bb, np.eye(len(A)), np.zeros_like(B), poles)
    gamma = round_up(max(norm, 1e-300) * (1.0 + NOISE_MARGIN), NOISE_DIGITS)
    for _ in range(TRIES):
        delta = (0.1 * (gamma - norm) * gamma) / max(h * h, 1e-300) if gamma > norm else 0.0
        try:
            Xb = _riccati(Ab, Bb, Cb, D, gamma, delta)
        except (ValueError, np.linalg.LinAlgError):
            pass
        else:
            X = Xb / s[:, None] / s[None, :]
            checks = brl_checks(A, B, C, D, X, gamma, label)
            if np.all(np.isfinite(X)) and all(c.holds for c in checks):
                return {"gamma": gamma, "X": X, "initial_term": float(np.sqrt(np.linalg.eigvalsh(X)[-1])),
                        "hinf_norm": norm, "checks": checks}
        last, gamma = gamma, round_up(gamma * GROWTH, NOISE_DIGITS)
    return {"gamma": None, "hinf_norm": norm,
            "why": f"no bounded real lemma certificate up to gamma = {figure_text(last, NOISE_DIGITS)} survives the "
                   "re-check at the stored matrices"}


# -- continuous time, on a grid of premise points ------------------------------------------------------------------
def _continuous_brl_stack(A, B, C, D, X, gamma: float) -> tuple:
    """The continuous bounded real lemma's matrices of a stack of points, to be positive definite, and their terms'
    sizes (see :func:`continuous_brl_checks`)."""
    aA, aB, aC, aD, aX = (np.abs(m) for m in (A, B, C, D, X))
    g2 = float(gamma) ** 2
    At, Bt, Ct, Dt = (np.swapaxes(m, -1, -2) for m in (A, B, C, D))
    aAt, aBt, aCt, aDt = (np.swapaxes(m, -1, -2) for m in (aA, aB, aC, aD))
    eye = np.broadcast_to(np.eye(B.shape[-1]), B.shape[:-2] + (B.shape[-1],) * 2)
    top = -(At @ X + X @ A + Ct @ C)
    side = -(X @ B + Ct @ D)
    M = np.concatenate([np.concatenate([top, side], axis=-1),
                        np.concatenate([np.swapaxes(side, -1, -2), g2 * eye - Dt @ D], axis=-1)], axis=-2)
    t_top, t_side = aAt @ aX + aX @ aA + aCt @ aC, aX @ aB + aCt @ aD
    T = np.concatenate([np.concatenate([t_top, t_side], axis=-1),
                        np.concatenate([np.swapaxes(t_side, -1, -2), g2 * eye + aDt @ aD], axis=-1)], axis=-2)
    return 0.5 * (M + np.swapaxes(M, -1, -2)), T


def continuous_brl_checks(A, B, C, D, X, gamma: float, label: str = "gain_y", where: str = "premise points") -> list:
    """The continuous bounded real lemma with one storage ``X`` at every point of a stack, at stored matrices.

    The error system ``eps' = A_g eps + B_g w``, ``e = C_g eps + D_g w`` (``A`` ... ``D`` stacks, one row per point
    ``g``) has the l2 gain ``gamma`` along any trajectory whose matrices stay among the points when ``X > 0`` and
    at every point::

        [[-(A_g' X + X A_g) - C_g' C_g,   -(X B_g + C_g' D_g)],
         [-(B_g' X + D_g' C_g),           gamma^2 I - D_g' D_g]]  > 0

    (the storage ``eps' X eps`` then gives ``d/dt (eps' X eps) + |e|^2 - gamma^2 |w|^2 <= 0``). Each is decided as
    :func:`scaled_definite_check` decides one, all points at once; the worst point is reported.
    """
    A, B, C, D, X = (np.asarray(m, dtype=float) for m in (A, B, C, D, X))
    n = X.shape[-1]
    M, T = _continuous_brl_stack(A, B, C, D, X, gamma)
    diag = np.diagonal(T, axis1=-2, axis2=-1)
    d = 1.0 / np.sqrt(np.where(diag > 0, diag, 1.0))
    Ms, Ts = d[..., :, None] * M * d[..., None, :], d[..., :, None] * T * d[..., None, :]
    floor = rounding_floor(Ms, Ts, 2 * n + C.shape[-2] + 4)
    values = np.linalg.eigvalsh(Ms)[..., 0] if len(Ms) else np.zeros(0)
    bound = ROUNDING_FACTOR * floor
    name = (f"noise {label}: continuous bounded real lemma at gamma = {figure_text(gamma, NOISE_DIGITS)} over the "
            f"{where}")
    if len(values):
        i = int(np.argmin(values - bound))
        lemma = Check(name, float(values[i]), float(bound[i]), at_most=False, floor=float(floor[i]))
    else:
        lemma = Check(name, -math.inf, 0.0, at_most=False)
    return [scaled_definite_check(f"noise {label}: eig_min(X)", 0.5 * (X + X.T), np.abs(X), 1), lemma]


def _least_gamma2(M, C, XB, D) -> np.ndarray:
    """``gamma^2`` of the lemma at every point for a storage ``X`` (``M = A'X + XA``, ``XB``): ``eig_max(D'D + Y'
    U^-1 Y)``, ``U = -(M + C'C) > 0``, ``Y = XB + C'D`` (the Schur complement); inf where ``U`` is not definite."""
    Ct, Dt = np.swapaxes(C, -1, -2), np.swapaxes(D, -1, -2)
    U = -(M + Ct @ C)
    U = 0.5 * (U + np.swapaxes(U, -1, -2))
    if not np.all(np.linalg.eigvalsh(U)[..., 0] > 0):
        return np.full(len(M), math.inf)
    L = np.linalg.cholesky(U)
    Z = np.linalg.solve(L, XB + Ct @ D)
    S = Dt @ D + np.swapaxes(Z, -1, -2) @ Z
    return np.linalg.eigvalsh(0.5 * (S + np.swapaxes(S, -1, -2)))[..., -1]


def continuous_brl_certificate(A, B, C, D, Q, label: str = "gain_y", where: str = "premise points") -> dict:
    """The least l2 gain of the stack of points ``(A_g, B_g, C_g, D_g)`` (:func:`continuous_brl_checks`) that a
    storage ``X = c Q`` certifies, ``Q`` given (a Lyapunov matrix of the points: ``A_g' Q + Q A_g < 0``), to
    :data:`NOISE_DIGITS`; no solver.

    For a fixed ``c`` the least ``gamma^2`` of a point is a Schur complement (:func:`_least_gamma2`: it needs
    ``c (A_g' Q + Q A_g) + C_g' C_g < 0``, so ``c`` above ``c_min = max_g eig_max(C_g' C_g, -(A_g' Q + Q A_g))``,
    the generalized eigenvalue). The lemma is linear in ``(c, gamma^2)``: the largest least ``gamma^2`` over the
    points is convex in ``c``, and Brent's method on ``c = c_min (1 + e^s)`` finds its least value. ``gamma`` is
    its square root times ``1 + NOISE_MARGIN``, rounded up, re-checked at ``X = c Q`` and grown by
    :data:`GROWTH` where the re-check fails.

    Returns
    -------
    dict
        As :func:`brl_certificate` (``least_gamma`` in place of ``hinf_norm``); ``gamma`` None with ``why``.
    """
    from .scalar_search import bounded_minimum

    A, B, C, D, Q = (np.asarray(m, dtype=float) for m in (A, B, C, D, Q))
    Q = 0.5 * (Q + Q.T)
    M = np.swapaxes(A, -1, -2) @ Q + Q @ A
    M = 0.5 * (M + np.swapaxes(M, -1, -2))
    if not len(M) or not np.all(np.linalg.eigvalsh(-M)[..., 0] > 0):
        return {"gamma": None, "why": "the storage matrix does not make every point strictly stable"}
    L = np.linalg.cholesky(-M)
    CL = np.swapaxes(np.linalg.solve(L, np.swapaxes(C, -1, -2) * np.ones((len(M), 1, 1))), -1, -2)
    c_min = max(float(np.linalg.norm(CL, 2, axis=(-2, -1)).max()) ** 2, 1e-300)
    QB = Q @ B

    def worst(s: float) -> float:
        c = c_min * (1.0 + math.exp(s))
        top = float(_least_gamma2(c * M, C, c * QB, D).max())
        return math.log(top) if 0 < top < math.inf else 1e300

    s, _ = bounded_minimum(worst, -40.0, 40.0, xatol=1e-4)
    c = c_min * (1.0 + math.exp(s))
    least = math.sqrt(float(_least_gamma2(c * M, C, c * QB, D).max()))
    X = c * Q
    gamma = round_up(max(least, 1e-300) * (1.0 + NOISE_MARGIN), NOISE_DIGITS)
    for _ in range(TRIES):
        checks = continuous_brl_checks(A, B, C, D, X, gamma, label, where)
        if all(ch.holds for ch in checks):
            return {"gamma": gamma, "X": X, "initial_term": float(np.sqrt(np.linalg.eigvalsh(X)[-1])),
                    "least_gamma": least, "checks": checks}
        last, gamma = gamma, round_up(gamma * GROWTH, NOISE_DIGITS)
    return {"gamma": None, "why": f"no continuous bounded real lemma certificate up to gamma = "
                                  f"{figure_text(last, NOISE_DIGITS)} survives the re-check at the stored matrices"}


def fir_system(coefficients) -> tuple:
    """The filter ``e_k = sum_j K_j v_(k-j)`` as a state-space system ``(A, B, C, D)``: a shift register of the
    last ``len(coefficients) - 1`` samples (``A`` nilpotent).

    Parameters
    ----------
    coefficients : sequence of (r, p) arrays
        ``K_0, K_1, ...`` (at least one).
    """
    K = [np.asarray(k, dtype=float) for k in coefficients]
    r, p = K[0].shape
    n = (len(K) - 1) * p
    A = np.zeros((n, n))
    if n > p:
        A[p:, :n - p] = np.eye(n - p)
    B = np.eye(n, p)
    C = np.hstack(K[1:]) if n else np.zeros((r, 0))
    return A, B, C, K[0]


def peak_to_peak(coefficients) -> float:
    """``sum_j ||K_j||_2`` rounded up to :data:`NOISE_DIGITS`: the peak-to-peak gain of the filter
    ``e_k = sum_j K_j v_(k-j)`` (``max_k |e_k| <= gain max_k |v_k|``, Euclidean norms of the samples)."""
    return round_up(sum(float(np.linalg.norm(np.asarray(k, dtype=float), 2)) for k in coefficients), NOISE_DIGITS)


def gain_text(value) -> str:
    """A gain as printed: :data:`NOISE_DIGITS` significant digits, or ``none``."""
    return "none" if value is None else figure_text(float(value), NOISE_DIGITS)


def certificate_key(key: str) -> str:
    """Where a card keeps the certificate of ``noise.<key>``: ``certificate`` for ``gain_y``, ``certificate_w`` for
    ``gain_w``, ``certificate_dhat_y`` for ``gain_dhat_y``."""
    return "certificate" if key == "gain_y" else f"certificate_{key[len('gain_'):]}"


def recheck(noise: dict, A, B, C, D, key: str = "gain_y", switched: bool = False, steps: list | None = None,
            continuous: bool = False) -> list:
    """The re-check of a card's ``noise.<key>`` (its certificate at :func:`certificate_key`) at the error system
    ``(A, B, C, D)`` of its stored matrices (with ``switched``, stacks: :func:`switched_brl_checks`; with
    ``continuous``, stacks of points: :func:`continuous_brl_checks`; with ``steps``, those of
    :func:`lemma_checks`, ``A`` ... ``D`` unused): none when the gain is null (a card claims nothing then)."""
    if not isinstance(noise, dict) or noise.get(key) is None:
        return []
    cert = noise.get(certificate_key(key))
    if not isinstance(cert, dict):                  # a gain claimed without the matrices that prove it
        return [Check(f"noise.{key} claimed without its certificate noise.{certificate_key(key)} (present)", 0.0,
                      1.0, at_most=False)]
    X, gamma = np.asarray(cert["X"], dtype=float), float(noise[key])
    if steps is not None:
        lemma = lemma_checks(steps, X, gamma, key)
    elif continuous:
        lemma = continuous_brl_checks(A, B, C, D, X, gamma, key)
    else:
        lemma = (switched_brl_checks if switched else brl_checks)(A, B, C, D, X, gamma, key)
    return lemma + [initial_check(noise if key == "gain_y" else cert, X, key)]


def certified(A, B, C, D, key: str = "gain_y", switched: bool = False, balanced: bool = False) -> tuple:
    """``brl_certificate`` (``switched_brl_certificate`` with ``switched``, in balanced state coordinates with
    ``balanced``) as the card stores it: (gain or None, the section's extra keys, why it is None); see
    :func:`stated`."""
    cert = (partial(switched_brl_certificate, balanced=balanced) if switched else brl_certificate)(A, B, C, D, key)
    method = ("poly-quadratic bounded real lemma (every switching sequence, at the stored matrices)" if switched
              else "bounded real lemma (discrete, at the stored matrices)")
    return stated(cert, method, key)


def stated(cert: dict, method: str, key: str = "gain_y") -> tuple:
    """A certificate (:func:`brl_certificate`, :func:`lemma_certificate`) as the card stores it: (gain or None, the
    section's extra keys, why it is None).

    The extra keys are the certificate (at :func:`certificate_key`: the method, the H-infinity norm or the
    solver's gamma, the margin, ``X``, the checks and ``determined``, whether the gain is the problem's to
    :data:`NOISE_DIGITS` digits, :func:`uiofmu.runtime.card.noise_determined`) and the ``initial_term`` (top level
    for ``gain_y``, in its certificate else).
    """
    if cert["gamma"] is None:
        return None, {}, f"{key}: not certified ({cert['why']})"
    record = {"method": method, **{k: cert[k] for k in ("hinf_norm", "lmi_gamma", "least_gamma") if k in cert},
              "margin": NOISE_MARGIN, "X": cert["X"], "checks": {c.name: c.to_data() for c in cert["checks"]}}
    record["determined"] = noise_determined(cert["gamma"], record)
    if key == "gain_y":
        return cert["gamma"], {"initial_term": cert["initial_term"], "certificate": record}, None
    return cert["gamma"], {certificate_key(key): {**record, "initial_term": cert["initial_term"]}}, None


#: What follows a closed-form design's noise gain that the problem does not determine (its certificate's
#: ``determined`` false) where it is printed.
NOISE_UNDETERMINED_NOTE = "this design's; not determined by the problem"


def _gain_line(label: str, noise: dict, key: str, closed: bool, figures: bool, extra: str = "") -> str:
    """The line of ``noise.<key>``: its figure (left out with ``figures`` false where a closed-form design's
    certificate says the problem does not determine it, which the line then says)."""
    cert = noise.get(certificate_key(key))
    own = closed and isinstance(cert, dict) and cert.get("determined") is False
    figure = "left out" if own and not figures else gain_text(noise.get(key))
    return f"  {label:16s} {figure} (l2 gain{extra}" + (f"; {NOISE_UNDETERMINED_NOTE})" if own else ")")


def noise_lines(card_data: dict, figures: bool = True) -> list[str]:
    """The lines ``uiofmu design`` prints of the card's noise gains.

    Each gain is the least certified gain of the card's error system rounded up to :data:`NOISE_DIGITS`: a figure
    of the card's matrices. Those of an LMI design are the solver's point's, which is not unique at the optimum of
    its objective (a sampled-data design of the robustness sample: 154 under one BLAS kernel, 155 under another; a
    plant at the edge: certified under one, not under the other), so the text every machine prints alike
    (``figures=False``) leaves them out, as it does the largest gain (:func:`uiofmu.gains.gain_lines`). Those of a
    closed-form design (``certificate.solver`` ``"none"``) are the problem's where their certificate says so
    (``determined``, :func:`uiofmu.runtime.card.noise_determined`); where it does not (a re-check held by the
    rounding of its ``X``: 31800 under one kernel, 35000 under another), the line says so and that text leaves
    the figure out.
    """
    noise = card_data.get("noise")
    closed = card_data["certificate"].get("solver") == "none"
    if not isinstance(noise, dict) or not (figures or closed):
        return []
    peak = noise.get("peak_to_peak_y")
    lines = [_gain_line("noise y->e", noise, "gain_y", closed, figures,
                        f"; peak-to-peak {gain_text(peak)}" if peak is not None else "")]
    for key, label in (("gain_dhat_y", "noise y->dhat"), ("gain_w", "noise w->e")):
        if noise.get(key) is not None:
            lines.append(_gain_line(label, noise, key, closed, figures))
    if noise.get("reason"):
        lines.append(f"  {'noise note':16s} {noise['reason']}")
    return lines


def noise_design_lines(card_data: dict, figures: bool = True) -> list[str]:
    """What a noise-aware design did (the card's ``noise_design``), for ``uiofmu design``: the decay
    ``observer.noise_gain`` searched for, or the design ``observer.noise = "min"`` kept. Which design the latter kept
    is decided by two points' gains, so it is printed with the ``figures``; the search's decays are
    the problem's (each decided by a certified gain, rounded up to :data:`NOISE_DIGITS` digits)."""
    record = card_data.get("noise_design")
    if not record:
        return []
    if "noise_gain" in record:
        return [f"  noise design     fastest decay with gain_y <= {gain_text(record['noise_gain'])} "
                f"({len(record['search']['tried'])} decays tried)"]
    if not figures:
        return []
    default = gain_text(record["default_gain_y"])
    return [f"  noise design     least gain_y at decay {record['decay']:.6g}: kept the {record['kept']} design "
            f"(the default design's gain_y {default})"]


def initial_check(noise: dict, X, key: str = "gain_y") -> Check:
    """``initial_term >= sqrt(eig_max(X))`` (up to the rounding of the eigenvalue): the term of ``||e_0||`` in the
    bound of ``noise.<key>`` (``noise`` the section, or the certificate that holds the term)."""
    X = np.asarray(X, dtype=float)
    top = float(np.linalg.eigvalsh(0.5 * (X + np.swapaxes(X, -1, -2)))[..., -1].max())
    try:
        value = float(noise.get("initial_term"))
    except (TypeError, ValueError):
        value = math.nan
    needed = math.sqrt(max(top * (1.0 - 8.0 * X.shape[-1] * np.finfo(float).eps), 0.0))
    return Check(f"noise {key}: initial_term >= sqrt(eig_max(X))", value if math.isfinite(value) else -math.inf, needed,
                 at_most=False)


__all__ = ["KEYS", "MAX_PAIRS", "NOISE_DIGITS", "NOISE_MARGIN", "NOISE_UNDETERMINED_NOTE", "NORM", "brl_certificate",
           "brl_checks",
           "certificate_key", "certified", "claimed_without", "continuous_brl_certificate", "continuous_brl_checks",
           "dhat_error_step", "dhat_missing", "fir_system", "gain_text", "gains_section", "hinf_norm", "initial_check",
           "lemma_certificate", "lemma_checks", "noise_design_lines", "noise_lines", "pair_checks",
           "pair_dhat_error_system", "pair_error_system", "pair_process_error_system", "pair_section",
           "peak_to_peak", "recheck",
           "scaled_definite_check", "section", "stated", "switched_brl_certificate", "switched_brl_checks"]
