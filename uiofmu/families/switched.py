"""Unknown-input observer for switched linear discrete systems (Millerioux, Daafouz; seed 002).

A switched plant (:mod:`uiofmu.switched_plant`) ``x+ = A_i x + B_i u + E_i d + w_i``, ``y = C x``,
in the mode ``i = alpha_k`` known in real time. The paper's B_i (unknown input) is our ``E_i``,
its affine E_i our ``w_i``. With ``Q_i`` solving ``Q_i C E_i = E_i`` (13) and ``P_i = I - Q_i C``,
the observer (10), split at the communication point::

    xhat_k  = z_k + Q_{alpha(k-1)} y_k
    z_{k+1} = (P_i A_i - K_i C) xhat_k + K_i y_k + P_i (w_i + B_i u_k),     i = alpha_k

gives ``e_{k+1} = Phi_i e_k`` (14) with ``Phi_i = P_i A_i - K_i C`` whatever ``d`` (``P_i E_i = 0``).
The runtime keeps the previous mode: ``xhat`` at k uses the ``Q`` of the step before.

Parametrisation (15): ``Q_i = E_i (C E_i)^+ + Y_i U_i'``, with ``U_i`` an orthonormal basis of the
range of ``I - C E_i (C E_i)^+`` (the part of ``Y_i`` that acts: the paper's ``Y_i`` is one
choice among many giving the same ``Q_i``). Then ``Phi_i = At_i - Kt_i Ct_i`` with
``At_i = A_i - E_i (C E_i)^+ C A_i``, ``Ct_i = [C; U_i' C A_i]`` and ``Kt_i = [K_i, Y_i]``: the rows
of the paper's ``C At_i`` that are not zero by construction (with as many outputs as unknown
inputs ``Ct_i = C``, the paper's (17)-(18)).

Design, LMI (16) with a decay ``lambda`` (transposed poly-quadratic form, all pairs (i, j))::

    [[G_i + G_i' - S_i,          (At_i' G_i - Ct_i' F_i)'],
     [At_i' G_i - Ct_i' F_i,     lambda^2 S_j            ]]  > 0,    I <= S_i <= t I

minimising ``t``; ``Kt_i = (G_i^-1)' F_i'``. It implies ``Phi_i' S_i Phi_i < lambda^2 S_j`` for all
(i, j), which the certificate re-checks at the stored matrices: with ``V_k = e_k' S_{alpha(k-1)} e_k``,
``||e_k|| <= sqrt(kappa) lambda^k ||e_0||`` under arbitrary switching, ``kappa`` the ratio of the
extreme eigenvalues of all ``S_i``. ``decay = "max"`` bisects lambda between the largest fixed
eigenvalue of the pairs ``(At_i, Ct_i)`` (which no gain moves) and 1.

Dead-beat: when every ``Ct_i`` has rank n, ``Kt_i = At_i Ct_i^+`` gives ``Phi_i = 0``; it is unique
when ``Ct_i`` is square (seed 002's setup 2). The certificate is then ``||e_{k+1}|| <= ||Phi_i|| ||e_k||``
at the stored matrices: decay bound ``max_i ||Phi_i||`` (round-off), overshoot 1.

Least noise gain (``observer.noise = "min"``, ``observer.noise_gain``): the error from output noise ``v`` is
``eps+ = Phi_i eps - L_ij v``, ``e = eps - Q_j v`` with ``L_ij = K_i + Phi_i Q_j``, bilinear in ``Y_j`` (in
``Q_j``) and ``Kt_i``: the least-noise design fixes ``Q_i`` (the least-norm ``Q0_i``, ``Y_i = 0``, or the default
design's) and frees ``K_i``: with ``PA_i = P_i A_i`` and ``Xy_j = Q_j`` the LMIs of
:func:`uiofmu.noise.pair_noise_lmis` (for every pair the decay LMI, ``Phi_i' S_i Phi_i < lambda^2 S_j`` as the
certificate re-checks it, and the poly-quadratic bounded real lemma the card's ``gain_y`` re-checks, with a slack
``G_i`` per mode and ``K_i = G_i^-1 F_i``). Its points are accepted only where :func:`checks` hold at the runtime's
matrices, and kept only where the certified gain is below the default design's
(:func:`uiofmu.noise.least_noise_design`).

Noise on dhat (``rank(C E_i) = q`` in every mode): dhat after a step in the mode ``i`` reads the next sample, so its
error ``Dy_i (C A_i e_k + v_(k+1))`` is a system one step ahead with the state ``(eps, v_prev)``; the card's
``gain_dhat_y`` is its poly-quadratic bounded real lemma for every switching sequence (:func:`noise_of`,
:func:`uiofmu.noise.pair_dhat_error_system`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np

from ..certificate import (EPS, FIGURE_DIGITS, UNDETERMINED, Check, certificate, decay_check, figure_digits,
                           identity_check,
                           lyapunov_check, overshoot, overshoot_check, positive_check, round_up)
from ..gains import cap_lmis, two_norms
from ..consistency import Determined, computed_values, dhat_record, eigen_rtol, spectrum
from ..decoupling import weak_modes_condition
from ..runtime.card import DHAT
from ..existence import Condition, Existence, complex_list, format_complex
from ..lmi import Lmi, LmiSolution, LmiSystem, tune
from ..runtime.errors import ProblemError
from ..runtime.tolerances import RANK_RTOL, SEARCH_TOL, ZERO_MARGIN
from ..structure import kernel_maps, product_radius, rank, unobservable_modes
from ..switched_plant import as_switched
from ..noise import (NOISE_METHOD, NOISE_OBJECTIVES, certified, least_noise_design, pair_checks,
                     pair_error_system, pair_noise_gain, pair_noise_lmis, pair_section)
from . import Analysis, DesignResult

NAME = "switched"

#: What a switched card's noise section says of the gains it has not.
NO_W = "gain_w: a switched plant declares no process noise"

#: Design methods: dead-beat where every mode allows it, else the LMI; or one of them.
METHODS = ("auto", "lmi", "deadbeat")


@dataclass(frozen=True)
class Options:
    """Options of the switched UIO.

    Attributes
    ----------
    decay : float or "max"
        Contraction factor per step lambda in (0, 1), or ``"max"`` for the fastest certifiable.
    dt : float
        The plant's period.
    xhat0 : numpy.ndarray or None
        Initial estimate.
    mode_prev0 : int
        The mode assumed before the first step, alpha_{-1} (its ``Q`` gives ``z_0``).
    method : {"auto", "lmi", "deadbeat"}
        See :data:`METHODS`.
    gain_cap : float or None
        Bound on ``||Kt_i||_2 = ||[K_i, Y_i]||_2`` (:mod:`uiofmu.gains`), None for none; with a cap,
        ``method = "auto"`` designs dead-beat only where its gains are within the cap.
    noise : {"default", "min"}
        ``"min"``: the gains ``K_i`` that minimise ``gain_y`` at the decay (see :func:`_noise_lmis`).
    noise_gain : float or None
        The fastest decay whose least-noise design has a certified ``gain_y`` of at most this.
    """

    decay: object
    dt: float
    xhat0: np.ndarray | None
    mode_prev0: int = 1
    method: str = "auto"
    gain_cap: float | None = None
    noise: str = "default"
    noise_gain: float | None = None

    @property
    def step(self) -> float:
        """The communication step: the plant's period."""
        return self.dt


def parse_options(table, plant) -> Options:
    """Read ``[observer]``: ``decay`` (default ``"max"``), ``xhat0``, ``mode_prev0``, ``method``, ``gain_cap``."""
    plant = as_switched(plant)
    decay = table.tunable("decay", "max", low=0.0, high=1.0, open_low=True, open_high=True)
    xhat0 = table.vector("xhat0", plant.n, None)
    mode_prev0 = table.get("mode_prev0", 1)
    if isinstance(mode_prev0, bool) or not isinstance(mode_prev0, int) or not 1 <= mode_prev0 <= plant.N:
        raise ProblemError(f"observer.mode_prev0: expected a mode from 1 to {plant.N}, found {repr(mode_prev0)[:40]}")
    if table.has("dt"):
        raise ProblemError(f"observer.dt: a switched plant fixes the period (plant.dt = {plant.dt:g}); "
                           "remove observer.dt")
    method = table.choice("method", METHODS, "auto")
    noise = table.choice("noise", NOISE_OBJECTIVES, "default")
    noise_gain = table.scalar("noise_gain", None, low=0.0, open_low=True)
    if (noise == "min" or noise_gain is not None) and method == "deadbeat":
        raise ProblemError('observer.noise: the least noise gain is designed with the LMI (the dead-beat gains are '
                           'fixed): use method = "auto" or "lmi"')
    if noise_gain is not None and decay != "max":
        raise ProblemError(f"observer.noise_gain = {noise_gain:g} asks for the fastest decay whose certified gain_y "
                           f"is at most {noise_gain:g}: leave observer.decay unset (or \"max\"), found {decay!r}")
    return Options(decay, plant.dt, xhat0, mode_prev0, method, table.scalar("gain_cap", None, low=0.0, open_low=True),
                   noise, noise_gain)


@dataclass(frozen=True)
class Mode:
    """One mode's decoupled data: ``At``, ``Ct`` of (15), the forced part of ``Q`` and the basis ``U``."""

    A: np.ndarray
    B: np.ndarray
    E: np.ndarray
    w: np.ndarray
    At: np.ndarray
    Ct: np.ndarray
    Q0: np.ndarray
    U: np.ndarray
    fixed: np.ndarray


def decoupled_mode(plant, C) -> Mode:
    """(13) and (15) for one mode: ``Q0 = E (CE)^+``, ``At = A - Q0 C A``, ``U`` spanning the range of
    ``I - CE (CE)^+``, ``Ct = [C; U' C A]``, and the fixed eigenvalues of ``(At, Ct)``."""
    CE = C @ plant.E
    Q0 = plant.E @ np.linalg.pinv(CE)
    At = plant.A - Q0 @ C @ plant.A
    u, s, _ = np.linalg.svd(CE, full_matrices=True)
    r = int(np.sum(s > RANK_RTOL * max(1.0, float(s[0]) if s.size else 0.0)))
    U = u[:, r:]
    Ct = np.vstack([C, U.T @ C @ plant.A])
    return Mode(plant.A, plant.B, plant.E, plant.w, At, Ct, Q0, U, unobservable_modes(At, Ct))


def _analysis(problem):
    plant, opts = as_switched(problem.plant), problem.options
    C = plant.C
    conds, modes = [], []
    for i, mp in enumerate(plant.modes):
        tag = f" in mode {i + 1}"
        rce, re, q = rank(C @ mp.E), rank(mp.E), mp.E.shape[1]
        ok = rce == re
        conds.append(Condition(f"rank(CE_{i + 1}) = rank(E_{i + 1})", ok, True,
                               f"rank(CE) = {rce} = rank(E){tag}" if ok else
                               f"rank(CE) = {rce} < rank(E) = {re}{tag}: the unknown input cannot be decoupled",
                               {"mode": i + 1, "rank_CE": rce, "rank_E": re}))
        conds.append(Condition(f"rank(CE_{i + 1}) = q", rce == q, False,
                               f"rank(CE) = q = {q}{tag}: dhat is estimated by inversion" if rce == q else
                               f"rank(CE) = {rce} < q = {q}{tag}: the unknown input is not identifiable, no dhat",
                               {"mode": i + 1, "rank_CE": rce, "q": q}))
        if not ok:
            continue
        md = decoupled_mode(mp, C)
        modes.append(md)
        moduli = np.abs(md.fixed)
        largest = float(moduli.max()) if moduli.size else 0.0
        det = bool(np.all(moduli < 1 - ZERO_MARGIN))
        what = " (the invariant zeros of (A_i, E_i, C))" if C.shape[0] == q else ""
        shown = ", ".join(f"{format_complex([z])} (|z| = {abs(z):.6g})" for z in md.fixed if z.imag >= 0)
        if not md.fixed.size:
            msg = f"(At_{i + 1}, Ct_{i + 1}) is observable{tag}: every eigenvalue can be placed"
        elif det:
            msg = f"fixed eigenvalues of (At_{i + 1}, Ct_{i + 1}){what}: {shown}; all inside the unit circle"
        else:
            msg = (f"(At_{i + 1}, Ct_{i + 1}) is not detectable: fixed eigenvalues{what} {shown}; no gain moves "
                   f"the one(s) on or outside the unit circle, so no observer of this form converges")
        conds.append(Condition(f"detectable (At_{i + 1}, Ct_{i + 1})", det, True, msg,
                               {"mode": i + 1, "fixed_eigenvalues": complex_list(md.fixed),
                                "moduli": moduli.tolist(), "largest_fixed_modulus": largest,
                                "rank_Ct": rank(md.Ct)}))
        weak = weak_modes_condition(mp.A, mp.E, C, tag)
        conds.append(Condition(f"well observable modes of mode {i + 1}", weak.holds, False, weak.message,
                               weak.values))
    largest = max((float(np.abs(md.fixed).max()) for md in modes if md.fixed.size), default=0.0)
    if len(modes) == plant.N and C.shape[0] == plant.q and all(c.holds for c in conds if c.required):
        cond = _switching_condition(modes, C)
        conds.append(cond)
        largest = max(largest, cond.values["switching_radius"])
    deadbeat = len(modes) == plant.N and all(rank(md.Ct) == plant.n for md in modes)
    if len(modes) == plant.N:
        conds.append(Condition("dead-beat possible", deadbeat, False,
                               "rank Ct_i = n in every mode: Phi_i = 0 is reachable (one-step dead-beat)" if deadbeat
                               else "some Ct_i has rank < n: no one-step dead-beat observer; the LMI design decides",
                               {"ranks_Ct": [rank(md.Ct) for md in modes], "n": plant.n}))
    if opts.decay != "max" and modes and all(c.holds for c in conds if c.required):
        ok = opts.decay > largest + ZERO_MARGIN
        conds.append(Condition(
            "decay above fixed eigenvalues", ok, True,
            f"requested decay {opts.decay:g} > largest fixed eigenvalue modulus {largest:.6g}" if ok else
            f"requested decay {opts.decay:g} <= largest fixed eigenvalue modulus {largest:.6g}: no gain moves "
            "that eigenvalue; ask for a slower decay or decay = \"max\"",
            {"decay": opts.decay, "largest_fixed_modulus": largest}))
    return Existence(NAME, tuple(conds)), modes, largest, deadbeat


def _switching_condition(modes, C) -> Condition:
    """With as many outputs as unknown inputs ``C At_i = 0``, so ``ker C`` is invariant under every
    ``Phi_i`` and the error there evolves by ``At_i`` restricted to it, whatever the gains
    (:func:`uiofmu.structure.kernel_maps`). The joint spectral radius of those maps bounds every
    decay from below; a product of them with spectral radius 1 or more per step (sequences of up
    to three modes, :func:`uiofmu.structure.product_radius`) proves that some switching sequence
    does not converge."""
    radius, seq = product_radius(kernel_maps([md.At for md in modes], C))
    text = " ".join(str(i + 1) for i in seq)
    values = {"switching_radius": radius, "sequence": [i + 1 for i in seq]}
    if radius >= 1 - ZERO_MARGIN:
        return Condition("fixed error under switching", False, True,
                         f"repeating the modes {text} multiplies the error that no gain moves (on ker C) by "
                         f"{radius:.6g} per step (spectral radius of the product, per step): no observer of this "
                         "form converges under arbitrary switching", values)
    return Condition("fixed error under switching", True, False,
                     f"the error no gain moves (on ker C) contracts under switching at best by {radius:.6g} "
                     f"per step (lower bound of its joint spectral radius, from the modes {text})", values)


def analyse(problem, solver: bool = True) -> Analysis:
    """Per mode: rank(CE_i) = rank(E_i), rank(CE_i) = q, the fixed eigenvalues of (At_i, Ct_i) and
    their moduli, the weakly observable modes; whether dead-beat is possible; the requested decay."""
    existence, modes, largest, deadbeat = _analysis(problem)
    return Analysis(existence, {"modes": modes, "largest": largest, "deadbeat": deadbeat})


def _lmis(modes, gain_cap: float | None = None):
    """LMI (16) for every pair of modes, and with ``gain_cap`` the LMIs of ``||F_i G_i^-1|| <= gain_cap``
    (:func:`uiofmu.gains.cap_lmis`; ``Kt_i' = G_i^-1 F_i'`` has the same norm)."""
    N, n = len(modes), modes[0].A.shape[0]

    def build(v, prm, ops):
        out = []
        scaled = [prm["lam2"] * v[f"S{j}"] for j in range(N)]
        for i, md in enumerate(modes):
            G, S = v[f"G{i}"], v[f"S{i}"]
            out.append(Lmi(f"S_{i + 1} >= I", S - ops.eye(n), strict=False))
            out.append(Lmi(f"S_{i + 1} <= t I", v["t"] * ops.eye(n) - S, strict=False))
            M = md.At.T @ G - md.Ct.T @ v[f"F{i}"]
            corner = G + G.T - S
            for j in range(N):
                out.append(Lmi(f"(16) i={i + 1} j={j + 1}", ops.bmat([[corner, M.T], [M, scaled[j]]])))
        if gain_cap is not None:
            out += cap_lmis(gain_cap, [(f"G_{i + 1}", v[f"G{i}"], [(f"F_{i + 1}", v[f"F{i}"].T)]) for i in range(N)],
                            v["s"], ops)
        return out

    variables = {"t": ("scalar",)}
    for i, md in enumerate(modes):
        variables[f"G{i}"] = ("matrix", (n, n))
        variables[f"F{i}"] = ("matrix", (md.Ct.shape[0], n))
        variables[f"S{i}"] = ("symmetric", n)
    if gain_cap is not None:
        variables["s"] = ("scalar",)
    return LmiSystem(f"{NAME} (16)", variables, {"lam2": 0.98}, build, objective=lambda v: v["t"],
                     homogeneous=True, structure=([md.At for md in modes], [md.Ct for md in modes], gain_cap))


def _gains(modes, values) -> list:
    """``Kt_i = (G_i^-1)' F_i'`` of an LMI point."""
    return [np.linalg.solve(values[f"G{i}"].T, values[f"F{i}"].T) for i in range(len(modes))]


def _deadbeat(modes) -> list:
    """``Kt_i = At_i Ct_i^+`` (``Phi_i = 0`` when ``Ct_i`` has rank n)."""
    return [md.At @ np.linalg.pinv(md.Ct) for md in modes]


def _runtime(modes, Kt, C, has_dhat: bool) -> dict:
    """The card's matrices from the gains: runtime (``N[i][j] = Phi_i``, ``L[i][j] = K_i + Phi_i Q_j``,
    ``G[i] = P_i B_i``, ``c[i] = P_i w_i``, ``Xz[j] = I``, ``Xy[j] = Q_j``, dhat's ``Dy[j]``, ``Yx[i]``,
    ``Yu[i]``, ``Yc[i]``) and the family's (``K``, ``Y``, ``Q``, ``P``, ``Phi`` and the modes)."""
    N, n, p = len(modes), C.shape[1], C.shape[0]
    K = np.array([kt[:, :p] for kt in Kt])
    Y = [kt[:, p:] for kt in Kt]
    Q = np.array([md.Q0 + y @ md.U.T for md, y in zip(modes, Y)])
    P = np.eye(n)[None] - Q @ C
    A = np.array([md.A for md in modes])
    Phi = P @ A - K @ C
    mats = {"N": np.repeat(Phi[:, None], N, axis=1), "L": K[:, None] + Phi[:, None] @ Q[None, :],
            "G": P @ np.array([md.B for md in modes]), "c": np.einsum("kij,kj->ki", P, [md.w for md in modes]),
            "Xz": np.repeat(np.eye(n)[None], N, axis=0), "Xy": Q, "C": C,
            "K": K, "Q": Q, "P": P, "Phi": Phi, "A_modes": A, "B_modes": np.array([md.B for md in modes]),
            "E_modes": np.array([md.E for md in modes]), "w_modes": np.array([md.w for md in modes])}
    if has_dhat:
        mats.update({"Dy": np.array([np.linalg.pinv(C @ md.E) for md in modes]), "Yx": C @ A,
                     "Yu": C @ mats["B_modes"], "Yc": mats["w_modes"] @ C.T})
    return mats


def checks(matrices: dict, decay: float) -> list:
    """The certificate's checks at the stored matrices, worst case over the modes and pairs.

    Decoupling ``P_i E_i = 0``, ``P_i = I - Q_i C``, the runtime's ``N[i][j] = Phi_i = P_i A_i - K_i C``,
    ``L[i][j] = K_i + Phi_i Q_j``, ``G[i] = P_i B_i``, ``c[i] = P_i w_i``, ``Xz = I``, ``Xy = Q``; with a
    Lyapunov matrix ``S`` (LMI design) ``S_i > 0`` and ``decay^2 S_j - Phi_i' S_i Phi_i > 0`` for all
    (i, j), without one (dead-beat) ``||Phi_i|| <= decay``; and ``decay < 1``.
    """
    g = {k: np.asarray(v, dtype=float) for k, v in matrices.items()}
    C, K, Q, P, Phi = g["C"], g["K"], g["Q"], g["P"], g["Phi"]
    A, B, E, w = g["A_modes"], g["B_modes"], g["E_modes"], g["w_modes"]
    n = C.shape[1]

    def two(x):
        return np.linalg.norm(x, 2, axis=(-2, -1)) if x.size else np.zeros(x.shape[:-2])

    def worst(residuals, scales):
        """The (residual, scale) pair of the mode nearest to failing."""
        i = int(np.argmax(residuals / np.maximum(1.0, scales)))
        return residuals[i], scales[i]

    res = {
        "decoupling ||P_i E_i||": worst(two(P @ E), two(E) + two(Q) * two(C @ E)),
        "||P_i - (I - Q_i C)||": worst(two(P - np.eye(n) + Q @ C), 1.0 + two(Q) * two(C)),
        "||Phi_i - (P_i A_i - K_i C)||": worst(two(Phi - P @ A + K @ C), two(P) * two(A) + two(K) * two(C)),
        "||N_ij - Phi_i||": worst(two(g["N"] - Phi[:, None]).max(axis=1), two(Phi)),
        "||L_ij - (K_i + Phi_i Q_j)||": worst(two(g["L"] - K[:, None] - Phi[:, None] @ Q[None, :]).max(axis=1),
                                              two(K) + two(Phi) * two(Q).max()),
        "||G_i - P_i B_i||": worst(two(g["G"] - P @ B), two(B)),
        "||c_i - P_i w_i||": worst(np.linalg.norm(g["c"] - np.einsum("kij,kj->ki", P, w), axis=1),
                                   np.linalg.norm(w, axis=1)),
        "||Xz_j - I||": worst(two(g["Xz"] - np.eye(n)[None]), np.ones(len(P))),
        "||Xy_j - Q_j||": worst(two(g["Xy"] - Q), two(Q)),
    }
    out = [identity_check(name, np.array([r]), s) for name, (r, s) in res.items()]
    if "S" in g:
        S = g["S"]
        out.append(min((positive_check(f"eig_min(S_{i + 1})", S[i]) for i in range(len(S))), key=lambda c: c.value))
        out.append(min((lyapunov_check(f"eig_min(decay^2 S_{j + 1} - Phi_{i + 1}' S_{i + 1} Phi_{i + 1})", Phi[i],
                                       S[i], decay, S[j]) for i in range(len(S)) for j in range(len(S))),
                       key=lambda c: c.value))
    else:
        norm = float(two(Phi).max())
        out.append(Check("dead-beat max ||Phi_i|| <= decay", norm, decay))
    out.append(decay_check(decay))
    return out


def verify(card) -> list:
    """Re-check a card's certificate from its matrices alone (no solver), the overshoot it claims
    (the ratio of the Lyapunov matrices ``S``; 1 for a dead-beat design, whose bound is ``||Phi_i||``) and its
    noise gain."""
    d = card.data
    S = d["matrices"].get("S")
    lyapunov = S if S is not None else [np.eye(len(d["matrices"]["C"][0]))]
    return (checks(d["matrices"], d["decay_bound"]) + [overshoot_check(d["overshoot_bound"], lyapunov)]
            + pair_checks(d.get("noise"), d["matrices"]))


def error_system(matrices: dict) -> tuple:
    """The error system from output noise ``v`` at the stored matrices (:func:`uiofmu.noise.pair_error_system`).

    With ``y = C x + v``: ``e_k+1 = Phi_i e_k - K_i v_k - Q_i v_k+1``, so ``eps_k = e_k + Q_j v_k`` follows
    ``eps+ = N_ij eps - L_ij v`` (``N_ij = Phi_i``, ``L_ij = K_i + Phi_i Q_j``) and ``e = eps - Xy_j v``
    (``Xy_j = Q_j``, ``Xz_j = I``), the identities :func:`checks` re-checks.
    """
    return pair_error_system(matrices)


def noise_of(matrices: dict) -> dict:
    """The card's ``noise`` section: ``gain_y`` and, where the card has dhat, ``gain_dhat_y``, for every switching
    sequence (:func:`uiofmu.noise.pair_section`).

    dhat after a step in the mode ``i`` (after ``j``) is ``dhat_(k+1) = Dy_i (y_(k+1) - Yx_i xhat_k - Yu_i u_k -
    Yc_i)`` (``Dy_i = (C E_i)^+``, ``Yx_i = C A_i``, ``Yu_i = C B_i``, ``Yc_i = C w_i``): ``dhat_(k+1) - d_k =
    Dy_i C A_i (eps_k - Q_j v_k) + Dy_i v_(k+1)`` (:func:`uiofmu.noise.pair_dhat_error_system`)."""
    return pair_section(matrices, NO_W)


#: The bound the card states.
BOUND = "||e_k|| <= overshoot_bound * decay_bound**k * ||e_0|| under arbitrary switching"


def _schedule(plant, opts: Options) -> dict:
    return {"kind": "mode", "dt": plant.dt, "modes": plant.N, "mode_prev0": opts.mode_prev0, "step_policy": "error"}


def determined(problem, card_data, analysis: Analysis) -> dict:
    """What the card's problem determines: every mode's ``A_i, B_i, E_i, w_i``, ``C``, dhat's matrices
    (absent unless ``rank(CE_i) = q`` in every mode), the step, the schedule, the number of modes
    and ``decay = decay_bound``; each mode's fixed eigenvalues and the largest modulus of its analysis,
    and the spectral radius of each stored ``Phi_i``."""
    plant, opts = as_switched(problem.plant), problem.options
    C, modes = plant.C, plant.modes
    mats = {f"{k}_modes": np.array([getattr(md, k) for md in modes]) for k in "ABEw"}
    if all(rank(C @ md.E) == md.E.shape[1] for md in modes):
        mats.update(dhat_record(C, mats["A_modes"], mats["B_modes"], mats["E_modes"], mats["w_modes"]))
    else:
        mats.update(dict.fromkeys(DHAT))
    n = plant.n
    size = max(float(np.linalg.norm(md.A, 2)) for md in modes)
    figures = {f"fixed_eigenvalues[{i}]": computed_values(md.fixed, size, n)
               for i, md in enumerate(analysis.data["modes"])}
    noise = {"noise.norm": "l2", "noise.gain_w": None}            # gain_y and gain_dhat_y: verify re-checks them
    if mats["Dy"] is None:
        noise["noise.gain_dhat_y"] = None
    return {**noise, "dt": plant.dt, "schedule": _schedule(plant, opts), "bound": BOUND, "modes": plant.N,
            "decay": float(card_data["decay_bound"]), "matrices.C": C,
            **{f"matrices.{k}": v for k, v in mats.items()}, **figures,
            "largest_fixed_modulus": Determined(analysis.data["largest"], 1.0, eigen_rtol(n)),
            "spectral_radius_Phi": spectrum(card_data["matrices"]["Phi"], "radii")}


def gain_figures(card_data: dict) -> tuple:
    """The gains ``K_i``, ``||C||`` and the largest ``||A_i||`` (:mod:`uiofmu.gains`)."""
    m = card_data["matrices"]
    return [m["K"]], float(np.linalg.norm(m["C"], 2)), float(two_norms([m["A_modes"]]).max())


def _lmi_runtime(modes, values: dict, C, has_dhat: bool) -> dict:
    """The card's matrices of an LMI point: :func:`_runtime` of its gains, and its Lyapunov matrices ``S``."""
    mats = _runtime(modes, _gains(modes, values), C, has_dhat)
    mats["S"] = np.array([0.5 * (values[f"S{i}"] + values[f"S{i}"].T) for i in range(len(modes))])
    return mats


def _closed_form(lam: float, status: str) -> LmiSolution:
    """The record of a design without a solve (its certificate is the re-check at the stored matrices)."""
    return LmiSolution({}, {"lam2": lam * lam}, status, {}, True, 0.0, 0.0)


def _noise_runtime(modes, Q, values: dict, C, has_dhat: bool) -> dict:
    """The card's matrices of a point of the least-noise LMIs (:func:`uiofmu.noise.pair_noise_lmis` with
    ``PA_i = P_i A_i``, ``Xy_j = Q_j``, ``H_i = K_i``): ``Y_i = (Q_i - Q0_i) U_i``, ``K_i = G_i^-1 F_i``, and the
    Lyapunov matrices ``S``."""
    Kt = [np.hstack([pair_noise_gain(values, i), (Q[i] - md.Q0) @ md.U]) for i, md in enumerate(modes)]
    mats = _runtime(modes, Kt, C, has_dhat)
    mats["S"] = np.array([0.5 * (values[f"S{i}"] + values[f"S{i}"].T) for i in range(len(modes))])
    return mats


#: The ``Q_i`` a least-noise design keeps: the least-norm ``Q0_i = E_i (C E_i)^+`` (``Y_i = 0``), and the default
#: design's (whose ``Y_i`` its decay may need).
NOISE_Q = ("least-norm Q0_i (Y_i = 0)", "the default design's Q_i")


def _noise_systems(modes, default: dict | None, sigma: float, C, has_dhat: bool, opts: Options) -> list:
    """The least-noise LMIs for each ``Q`` of :data:`NOISE_Q` (with ``gain_cap``, the default's only: ``Q0``'s
    ``Y_i = 0`` is not capped; without a default design, ``Q0`` only), compiled once for any decay, each point
    certified by the certificate's checks at the runtime's matrices.

    Returns
    -------
    list
        ``(system, runtime, which)`` for each, ``runtime`` the card's matrices of a point.
    """
    out = []
    choices = list(zip(NOISE_Q, ([md.Q0 for md in modes], None if default is None else
                                 [np.asarray(q, dtype=float) for q in default["Q"]])))
    choices = [c for c in choices[1 if opts.gain_cap is not None else 0:] if c[1] is not None]
    for which, Q in choices:
        C = np.asarray(C, dtype=float)
        PA = [(np.eye(C.shape[1]) - Q[i] @ C) @ md.A for i, md in enumerate(modes)]
        system = pair_noise_lmis(NAME, PA, C, Q, sigma, gain_cap=opts.gain_cap)
        runtime = partial(_noise_runtime, modes, Q, C=C, has_dhat=has_dhat)
        system.certify = (lambda rt: lambda v, prm: all(c.holds for c in checks(rt(v), float(np.sqrt(prm["lam2"])))))(
            runtime)
        out.append((system, runtime, which))
    return out


def _gain_y(mats: dict) -> float | None:
    """The card's certified ``gain_y`` at these matrices (every switching sequence)."""
    return certified(*error_system(mats), switched=True)[0]


def noise_options(opts: Options, decay, noise: str) -> Options:
    """These options at another ``decay`` with the noise objective ``noise``, for :mod:`uiofmu.tradeoff`: no
    ``noise_gain``, and the LMI (the dead-beat gains have no freedom)."""
    method = "lmi" if opts.method == "deadbeat" or noise == "min" else opts.method
    return Options(decay, opts.dt, opts.xhat0, opts.mode_prev0, method, opts.gain_cap, noise, None)


def design(problem, analysis: Analysis) -> DesignResult:
    """Design the switched UIO: dead-beat where possible (``method = "auto"``), else LMI (16)."""
    plant, opts = as_switched(problem.plant), problem.options
    modes, largest, deadbeat = analysis.data["modes"], analysis.data["largest"], analysis.data["deadbeat"]
    existence = analysis.existence
    C = plant.C
    has_dhat = all(existence.holds(f"rank(CE_{i + 1}) = q") for i in range(plant.N))
    system = None                                  # the dead-beat design needs no LMI
    if opts.method == "deadbeat" and not deadbeat:
        ranks = [rank(md.Ct) for md in modes]
        raise ProblemError(f'observer.method = "deadbeat": needs rank Ct_i = n = {plant.n} in every mode, '
                           f"found ranks {ranks}")
    searched = None
    if deadbeat and opts.method == "auto" and opts.gain_cap is not None:   # the gains gain_figures caps: K_i
        deadbeat = float(two_norms([_runtime(modes, _deadbeat(modes), C, has_dhat)["K"]]).max()) <= opts.gain_cap
    noisy = opts.noise == "min" or opts.noise_gain is not None
    if noisy and opts.method == "deadbeat":                                # options made in code, unparsed
        raise ProblemError('observer.noise: the least noise gain is designed with the LMI: use method = "auto"')
    if deadbeat and opts.method != "lmi" and not noisy:
        mats = _runtime(modes, _deadbeat(modes), C, has_dhat)
        norm = float(np.linalg.norm(mats["Phi"], 2, axis=(-2, -1)).max())
        # Phi_i = 0 in exact arithmetic: its computed norm is rounding, so the bound is the rounding
        # floor of P_i A_i - K_i C (or the norm, if larger), rounded up to one digit: the same figure
        # under every BLAS kernel
        two = lambda x: np.linalg.norm(x, 2, axis=(-2, -1))          # noqa: E731
        floor = 4.0 * plant.n * EPS * float((two(mats["P"]) * two(mats["A_modes"])
                                             + two(mats["K"]) * np.linalg.norm(C, 2)).max())
        norm = round_up(max(norm, floor), 1)
        lam = norm if opts.decay == "max" else max(float(opts.decay), norm)
        sol = _closed_form(lam, "closed form (dead-beat: Kt_i = At_i Ct_i^+)")
        method, solver, bound, digits = "deadbeat", "none", 1.0, FIGURE_DIGITS
    else:
        system = _lmis(modes, opts.gain_cap)
        system.certify = lambda v, prm: all(c.holds for c in checks(_lmi_runtime(modes, v, C, has_dhat),
                                                                    float(np.sqrt(prm["lam2"]))))
        system.figure = lambda v: overshoot(_lmi_runtime(modes, v, C, has_dhat)["S"])
        tuned = tune(system, "lam2", opts.decay, feasible_end=0.5 * (1.0 + largest), infeasible_end=largest,
                     safe_end=1.0, tol=SEARCH_TOL, label=f"{problem.name}: fastest decay",
                     transform=lambda r: r * r, name="decay")
        lam, sol = tuned.value, tuned.solution
        searched = tuned.search.to_data() if tuned.search else None
        mats = _lmi_runtime(modes, sol.values, C, has_dhat)
        bound, digits = overshoot(mats["S"]), figure_digits(sol)
        method, solver = "lmi", "CLARABEL"
    noise_design = None
    if noisy:                                          # the least noise gain: uiofmu.noise.least_noise_design
        built, lmi = [], system

        def candidates(default, sigma):
            out = _noise_systems(modes, default, sigma, C, has_dhat, opts)
            built.extend(c[0] for c in out)
            return out

        def default_at(rho):
            at = lmi.solve(lam2=rho * rho)
            return (at, _lmi_runtime(modes, at.values, C, has_dhat)) if at.verified else None

        lam, least, noise_design = least_noise_design(
            {"default_at": default_at, "candidates": candidates, "gain": _gain_y}, lam, opts.decay == "max",
            opts.noise_gain, (sol, mats), problem.name)
        system = (lmi, *built)
        if least is not None:
            sol, mats, which = least
            bound = overshoot(mats["S"])
            digits, method = (figure_digits(sol), "lmi") if which == "default" else (UNDETERMINED, NOISE_METHOD)
    cert = certificate(sol, checks(mats, lam), f"{NAME} design of {problem.name}", solver=solver)
    results = {
        "noise": noise_of(mats),
        "decay": lam,
        "decay_bound": lam,
        "overshoot_bound": bound,
        "overshoot_digits": digits,
        "bound": BOUND,
        "modes": plant.N,
        "fixed_eigenvalues": [complex_list(md.fixed) for md in modes],
        "largest_fixed_modulus": largest,
        "spectral_radius_Phi": [float(np.abs(np.linalg.eigvals(F)).max()) for F in mats["Phi"]],
        "search": searched,
        "design_method": method,
        **({} if noise_design is None else {"noise_design": noise_design}),
    }
    return DesignResult(plant.n, plant.dt, _schedule(plant, opts), mats, cert, results, system, opts.xhat0)


__all__ = ["NAME", "Options", "analyse", "checks", "design", "determined", "noise_options", "parse_options", "verify"]
