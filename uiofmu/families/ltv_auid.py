"""Asymptotic unknown-input decoupling LTV observer (Ichalal & Mammar, CDC 2019; seed 000).

For the sampled plant ``x+ = A x + B u + E d + w``, ``y = C x``, with ``a = alpha^k``::

    xhat_k  = z_k - H_k y_k,          H_k = (1 - a) M,   M = -E (CE)^+        (4), (5)
    z_{k+1} = N_k z_k + L_k y_k + G_k u_k + P_{k+1} w
    P_{k+1} = I + MC - alpha a MC                                            (11), (18)
    K_k     = a T_1 + (1 - a) T_2,   N_k = P_{k+1} A - K_k C,
    L_k     = K_k - N_k H_k,         G_k = P_{k+1} B                          (40)-(44)

so that ``e_{k+1} = N_k e_k + S_k d_k`` with ``S_k = P_{k+1} E = -alpha^{k+1} M C E``: the
unknown input is decoupled only as ``k`` grows, and in exchange the slow invariant zeros do
not bind the transient. Every matrix is a polynomial in ``a`` of degree at most 2, which the
runtime evaluates at ``a = alpha**k`` (schedule ``geometric``).

Theorem 2 with the vertices ``A_1 = (I + (1 - alpha) MC) A``, ``A_2 = (I + MC) A``,
``S_1 = -alpha MCE``, ``tau_1 = eta (1 + mu)``, ``tau_2 = eta``. The LMIs are homogeneous in
``(X, G_i, Tbar_i, gamma)``; they are normalised by ``X >= I``, ``X - G_i - G_i'`` replaces
the printed ``X - 2 G_i`` (``G_i`` is a slack and need not be symmetric, so the block must be
symmetrised), ``gamma`` is minimised (Remark 1) and ``T_i = G_i^{-1} Tbar_i``. That settles
``mu`` but leaves ``X`` free above ``I``: the overshoot ``sqrt(cond X)`` was whatever feasible point
the solver's path ended at (the quarter-car's moved between 107.8 and 108.1 with the BLAS kernel).
So at the settled ``mu`` one more solve minimises ``t`` with ``X <= t I`` (``gamma`` free: the
certified bound below does not use it, it takes ``||S_k d_k||_X`` itself), with the strictness
margin ``LEAST_OVERSHOOT_MARGIN`` that keeps its point clear of the solver's tolerance: the stored
point has the least overshoot at that ``mu`` (the quarter-car's 26.80 on every kernel), and only
where that solve is not certified does the design keep the first point. The card records the least
``gamma`` at ``mu`` (Remark 1), an optimal value of the first solve.

What is certified, and re-checked at the stored ``T_i``: ``N_i' X N_i < (1 - tau_i) X`` at
both vertices; ``N' X N`` is matrix-convex in ``N``, so ``N_k' X N_k < (1 - eta_k) X`` with
``eta_k = eta (1 + mu alpha^k)`` for every k. For a run with unknown input ``d``,
``||e_k|| <= b_k / sqrt(eig_min X)`` with ``b_0 = ||e_0||_X`` and
``b_{k+1} = sqrt(1 - eta_k) b_k + ||S_k d_k||_X`` (:func:`certified_bound`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..certificate import (
    certificate,
    decay_check,
    identity_check,
    lyapunov_check,
    UNDETERMINED,
    figure_digits,
    overshoot,
    overshoot_check,
    positive_check,
)
from ..decoupling import (
    decoupling_gain,
    detectable,
    identifiability_condition,
    parse_period,
    sampled_decoupling_conditions,
    short_below,
)
from ..gains import cap_lmis
from ..consistency import Determined, computed_values, condition, conditioned, dhat_record, spectrum
from ..runtime.card import DHAT
from ..runtime.errors import ProblemError
from ..existence import Condition, Existence, complex_list, format_complex, from_pairs
from ..lmi import Lmi, LmiSystem, held_margin, tune
from ..structure import unobservable_modes
from ..runtime.tolerances import LMI_MARGIN, SEARCH_TOL, ZERO_MARGIN
from ..noise import (claimed_without, dhat_error_step, dhat_missing, gains_section, hinf_norm, lemma_certificate,
                     recheck, stated)
from . import Analysis, DesignResult

NAME = "ltv-auid"

#: What an ltv-auid card's noise section says of the gains it has not.
NO_W = "gain_w: the problem declares no process noise"

#: The vertices in ``(a, b)`` of a triangle that holds ``(alpha^k, alpha^2k)`` for every k: ``b = a^2`` on [0, 1]
#: lies above ``b = 0`` and ``b = 2a - 1`` (its tangents at 0 and 1) and below ``b = a``.
NOISE_VERTICES = ((0.0, 0.0), (1.0, 1.0), (0.5, 0.0))

#: Strictness margin of the least-overshoot solve: its optimum sits on the boundary of (33)/(34),
#: where a margin of ``LMI_MARGIN`` left points the re-check refused on some BLAS kernels.
LEAST_OVERSHOOT_MARGIN = 10 * LMI_MARGIN


@dataclass(frozen=True)
class Options:
    """Options of the LTV observer (the paper's names).

    Attributes
    ----------
    alpha : float
        Rate of the time-decreasing sequence ``f_k = alpha^k``, in (0, 1).
    eta : float
        Asymptotic decay parameter: ``tau_2 = eta``.
    mu : float or "max"
        Transient boost: ``tau_1 = eta (1 + mu)`` (needs ``eta (1 + mu) < 1``).
    dt : float
        Period (the plant's, or ``observer.dt`` for a continuous plant).
    xhat0 : numpy.ndarray or None
    step_policy : {"error", "count"}
        A step other than ``dt``: refused, or taken as one step k (explicit opt-in).
    gain_cap : float or None
        Bound on ``||T_1||_2`` and ``||T_2||_2`` (:mod:`uiofmu.gains`), None for none.
    """

    alpha: float
    eta: float
    mu: object
    dt: float
    xhat0: np.ndarray | None
    step_policy: str
    gain_cap: float | None = None

    @property
    def step(self) -> float:
        """The communication step a co-simulation takes by default: the design period."""
        return self.dt


#: Why an ltv-auid observer has no least-noise design (``observer.noise``, ``observer.noise_gain``).
NO_NOISE_DESIGN = ("the ltv-auid design has no least-noise form: its contraction is set by eta and mu (Theorem 2), "
                   "not by a decay to trade against the noise gain, and its card's gain_y holds along the schedule "
                   "through the bounded real lemma at (a, a^2) = (0.5, 0), where K = (T_1 + T_2) / 2 mixes gains "
                   "that Theorem 2 divides by two different slacks (T_i = G_i^-1 Tbar_i), which no LMI in the "
                   "design's unknowns expresses; its card certifies gain_y all the same (family = \"lti-uio\", "
                   "\"sampled-data\" and \"switched\" design for it)")


def parse_options(table, plant) -> Options:
    """Read ``alpha``, ``eta``, ``mu``, ``dt``, ``xhat0``, ``step_policy``, ``gain_cap``; refuse ``noise`` and
    ``noise_gain`` (:data:`NO_NOISE_DESIGN`)."""
    for key in ("noise", "noise_gain"):
        if table.has(key):
            raise ProblemError(f"observer.{key} = {repr(table.get(key))[:40]}: {NO_NOISE_DESIGN}")
    alpha = table.scalar("alpha", low=0.0, high=1.0, open_low=True, open_high=True)
    eta = table.scalar("eta", low=0.0, high=1.0, open_low=True, open_high=True)
    mu = table.tunable("mu", "max", low=0.0, open_low=True)
    if mu != "max" and eta * (1 + mu) >= 1:
        raise ProblemError(f"observer.mu: tau_1 = eta (1 + mu) = {eta:g} * {1 + mu:g} = {eta * (1 + mu):g} must be "
                           f"< 1, i.e. mu < 1/eta - 1 = {1 / eta - 1:g}")
    dt = parse_period(table, plant, NAME)
    xhat0 = table.vector("xhat0", plant.n, None)
    policy = table.choice("step_policy", ("error", "count"), "error")
    return Options(alpha, eta, mu, dt, xhat0, policy, table.scalar("gain_cap", None, low=0.0, open_low=True))


def _vertices(s, C, alpha):
    M = decoupling_gain(C, s.E)
    MC = M @ C
    n = C.shape[1]
    return M, (np.eye(n) + (1 - alpha) * MC) @ s.A, (np.eye(n) + MC) @ s.A, -alpha * M @ C @ s.E


def _analysis(problem):
    plant, opts = problem.plant, problem.options
    s = plant.sampled(opts.dt)
    conds, fixed, decouplable = sampled_decoupling_conditions(plant, s, opts.dt)
    info = {}
    if decouplable and detectable(conds):
        zmax = float(np.abs(fixed).max()) if fixed.size else 0.0
        ok = np.sqrt(1 - opts.eta) > zmax + ZERO_MARGIN
        conds.append(Condition(
            "eta below the zero limit", ok, True,
            (f"sqrt(1 - eta) = {np.sqrt(1 - opts.eta):.6g} > largest fixed mode {zmax:.6g}: the asymptotic "
             "vertex (34) can hold") if ok else
            (f"sqrt(1 - eta) = {np.sqrt(1 - opts.eta):.6g} (eta = {opts.eta:g}) <= largest fixed mode {zmax:.6g}: "
             f"LMI (34) cannot hold; eta must be < 1 - {zmax:.6g}^2 = {1 - zmax * zmax:.6g}"),
            {"eta": opts.eta, "largest_fixed_modulus": zmax},
            hint="" if ok else _below("eta", 1.0 - (zmax + ZERO_MARGIN) ** 2, "the largest fixed mode")))
        _, A1, _, _ = _vertices(s, plant.C, opts.alpha)
        f1 = unobservable_modes(A1, plant.C)
        f1max = float(np.abs(f1).max()) if f1.size else 0.0
        mu_limit = min(1.0 / opts.eta - 1.0, (1.0 - f1max ** 2) / opts.eta - 1.0)
        info = {"fixed_modes_A1": complex_list(f1), "mu_limit": mu_limit}
        if opts.mu == "max":
            conds.append(Condition(
                "transient vertex (A_1, C)", mu_limit > 0, True,
                (f"(A_1, C) is observable: every mode of the transient vertex can be placed; mu < 1/eta - 1 = "
                 f"{mu_limit:.6g}" if not f1.size else
                 f"fixed modes of (A_1, C): {format_complex(f1)}; mu < {mu_limit:.6g}") if mu_limit > 0 else
                f"fixed modes of (A_1, C) {format_complex(f1)} leave no room for tau_1 > eta", info))
        else:
            tau1 = opts.eta * (1 + opts.mu)
            ok = np.sqrt(1 - tau1) > f1max + ZERO_MARGIN
            conds.append(Condition(
                "transient vertex (A_1, C)", ok, True,
                f"sqrt(1 - tau_1) = {np.sqrt(1 - tau1):.6g} > largest fixed mode of (A_1, C) {f1max:.6g}" if ok else
                f"sqrt(1 - tau_1) = {np.sqrt(1 - tau1):.6g} (tau_1 = {tau1:g}) <= largest fixed mode of (A_1, C) "
                f"{f1max:.6g}: LMI (33) cannot hold; mu must be < {mu_limit:.6g}", info,
                hint="" if ok else _below("mu", (1.0 - (f1max + ZERO_MARGIN) ** 2) / opts.eta - 1.0,
                                          "the fixed modes of (A_1, C)")))
    return Existence(NAME, tuple(conds)), s, fixed, info


def _below(key: str, limit: float, what: str) -> str:
    """The hint for a tunable that must stay below ``limit`` (none when no positive value does)."""
    return f"{key} = {short_below(limit):g}: {key} < {limit:.6g} clears {what}" if limit > 0 else ""


def analyse(problem, solver: bool = True) -> Analysis:
    """The classical conditions, the zero limit on eta and the transient vertex's limit on mu."""
    existence, s, fixed, info = _analysis(problem)
    return Analysis(existence, {"sampled": s, "fixed": fixed, "info": info})


def _lmis(A1, A2, S1, C, eta, least_overshoot: bool = False, gain_cap: float | None = None):
    """Theorem 2's LMIs, minimising ``gamma``, or with ``least_overshoot`` the least ``t`` with
    ``X <= t I``; with ``gain_cap`` the LMIs of ``||G_i^-1 Tbar_i|| <= gain_cap`` (:func:`uiofmu.gains.cap_lmis`).

    ``S1`` enters scaled to unit norm: with ``S1 = s S1n``, the congruence ``diag(I, I, I / s)`` maps
    (33) with ``S1`` to (33) with ``S1n`` and the same ``gamma``, so feasibility and ``gamma`` are
    those of the paper, while the block ``Om``, of size ``|S1|^2``, no longer drowns in the strictness
    margin when the unknown input's unit makes ``E`` tiny (``E`` of 1e-10 designs as ``E`` of 1 does).
    """
    n, p, q = C.shape[1], C.shape[0], S1.shape[1]
    S1 = S1 / max(float(np.linalg.norm(S1, 2)), 1e-300)

    def build(v, prm, ops):
        X, G1, G2, gamma = v["X"], v["G1"], v["G2"], v["gamma"]
        Z1 = G1 @ A1 - v["Tb1"] @ C
        Z2 = G2 @ A2 - v["Tb2"] @ C
        Gam = Z1.T @ S1
        Om = gamma * (S1.T @ S1) - S1.T @ (G1 + G1.T) @ S1
        bounded = [Lmi("X <= t I", v["t"] * ops.eye(n) - X, strict=False)] if least_overshoot else []
        if gain_cap is not None:
            bounded += cap_lmis(gain_cap, [("G1", G1, [("Tbar_1", v["Tb1"])]), ("G2", G2, [("Tbar_2", v["Tb2"])])],
                                v["s"], ops)
        return [
            Lmi("X >= I", X - ops.eye(n), strict=False),
            *bounded,
            Lmi("(33) transient vertex", ops.bmat([[(1 - prm["tau1"]) * X, -Z1.T, -Gam],
                                                   [-Z1, G1 + G1.T - X, ops.zeros((n, q))],
                                                   [-Gam.T, ops.zeros((q, n)), Om]])),
            Lmi("(34) asymptotic vertex", ops.bmat([[(1 - eta) * X, -Z2.T], [-Z2, G2 + G2.T - X]])),
        ]

    variables = {"X": ("symmetric", n), "G1": ("matrix", (n, n)), "G2": ("matrix", (n, n)),
                 "Tb1": ("matrix", (n, p)), "Tb2": ("matrix", (n, p)), "gamma": ("scalar",)}
    if gain_cap is not None:
        variables["s"] = ("scalar",)
    if not least_overshoot:
        return LmiSystem(f"{NAME} Theorem 2", variables, {"tau1": 2 * eta}, build,
                         objective=lambda v: v["gamma"], homogeneous=True)
    return LmiSystem(f"{NAME} Theorem 2, least overshoot", {**variables, "t": ("scalar",)}, {"tau1": 2 * eta},
                     build, objective=lambda v: v["t"], homogeneous=True, margin=LEAST_OVERSHOOT_MARGIN)


def coefficients(M, T1, T2, s, C, alpha) -> dict:
    """The runtime matrices as polynomials in ``a = alpha^k`` (coefficient axis first)."""
    n = C.shape[1]
    P = np.eye(n) + M @ C
    MC = M @ C
    N0 = P @ s.A - T2 @ C
    N1 = -alpha * MC @ s.A - (T1 - T2) @ C
    CE = C @ s.E
    return {
        "N": np.array([N0, N1]),
        "L": np.array([T2 - N0 @ M, (T1 - T2) - N1 @ M + N0 @ M, N1 @ M]),
        "G": np.array([P @ s.B, -alpha * MC @ s.B]),
        "c": np.array([P @ s.w, -alpha * MC @ s.w]),
        "Xz": np.array([np.eye(n), np.zeros((n, n))]),
        "Xy": np.array([-M, M]),
        "Dy": np.array([np.linalg.pinv(CE)]), "Yx": np.array([C @ s.A]), "Yu": np.array([C @ s.B]),
        "Yc": np.array([C @ s.w]),
    }


def _poly(c, a):
    return sum(ci * a ** j for j, ci in enumerate(c))


def checks(card_data: dict) -> list:
    """The certificate's checks at the stored matrices.

    Both vertex decays ``N_i' X N_i < (1 - tau_i) X``; ``X > 0``; decoupling
    ``(I + MC) E = 0``; and at ``a`` in {1, alpha^5, 0} the observer identities
    ``P_{k+1} A - N_k P_k - L_k C = 0``, ``G_k = P_{k+1} B``, ``c_k = P_{k+1} w``, the output
    ``xhat = z - H_k y`` (``Xz = I``, ``Xy = -H_k``, ``H_k = (1 - a) M``) from the stored
    polynomial matrices: every matrix the runtime uses is checked.
    """
    g = {k: np.asarray(v, dtype=float) for k, v in card_data["matrices"].items()}
    alpha, tau1, tau2 = card_data["alpha"], card_data["tau1"], card_data["tau2"]
    C, M, X = g["C"], g["M"], g["X"]
    A, B, E = g["A_sampled"], g["B_sampled"], g["E_sampled"]
    n = C.shape[1]
    out = [
        identity_check("decoupling ||(I+MC)E||", (np.eye(n) + M @ C) @ E, np.linalg.norm(E, 2)),
        positive_check("eig_min(X)", X),
        lyapunov_check("vertex 1: eig_min((1-tau_1) X - N_1'XN_1)", g["A1"] - g["T1"] @ C, X, np.sqrt(1 - tau1)),
        lyapunov_check("vertex 2: eig_min((1-tau_2) X - N_2'XN_2)", g["A2"] - g["T2"] @ C, X, np.sqrt(1 - tau2)),
        decay_check(np.sqrt(1 - tau2)),
    ]
    worst = {"PA - NP - LC": 0.0, "G - PB": 0.0, "Xy + H": 0.0, "Xz - I": 0.0, "c - Pw": 0.0}
    for a in (1.0, alpha ** 5, 0.0):
        P_next = np.eye(n) + M @ C - alpha * a * M @ C
        P_now = np.eye(n) + (1 - a) * M @ C
        N, L, G, Xy, Xz, c = (_poly(g[k], a) for k in ("N", "L", "G", "Xy", "Xz", "c"))
        worst["PA - NP - LC"] = max(worst["PA - NP - LC"], float(np.linalg.norm(P_next @ A - N @ P_now - L @ C, 2)))
        worst["G - PB"] = max(worst["G - PB"], float(np.linalg.norm(G - P_next @ B, 2)) if B.size else 0.0)
        worst["Xy + H"] = max(worst["Xy + H"], float(np.linalg.norm(Xy + (1 - a) * M, 2)))
        worst["Xz - I"] = max(worst["Xz - I"], float(np.linalg.norm(Xz - np.eye(n), 2)))
        worst["c - Pw"] = max(worst["c - Pw"], float(np.linalg.norm(c - P_next @ g["w_sampled"])))
    scale = 1.0 + np.linalg.norm(A, 2) * (1 + np.linalg.norm(M, 2) * np.linalg.norm(C, 2)) ** 2
    scales = {"c - Pw": (1 + np.linalg.norm(M, 2) * np.linalg.norm(C, 2)) * np.linalg.norm(g["w_sampled"]),
              "Xz - I": 1.0}
    out += [identity_check(f"max_k ||{k}||", np.array([v]), scales.get(k, scale)) for k, v in worst.items()]
    return out


def verify(card) -> list:
    """Re-check a card's certificate from its matrices alone (no solver), the overshoot and the noise gain it
    claims."""
    d = card.data
    return (checks(d) + [overshoot_check(d["overshoot_bound"], [d["matrices"]["X"]])]
            + noise_checks(d.get("noise"), d["matrices"], float(d["alpha"])))


def noise_steps(matrices: dict, dhat: bool = False, alpha: float | None = None) -> list:
    """The error system from output noise at the stored matrices, at the vertices :data:`NOISE_VERTICES`.

    The runtime's matrices are polynomials in ``a = alpha^k`` of degree at most 2 (``N``, ``L``, ``Xy``, with
    ``Xz = I``), evaluated at the same ``a`` for the step and the output of point k: the noise part of the error
    follows ``eps+ = N(a) eps - L(a) v``, ``e = eps - Xy(a) v``. Read with ``b`` for ``a^2``, each is affine in
    ``(a, b)``, and so is the bounded real lemma's matrix: the lemma at the three vertices with one ``X`` holds at
    every ``(alpha^k, alpha^2k)`` inside, hence along the whole schedule (:func:`uiofmu.noise.lemma_checks`).

    With ``dhat``, the error of dhat (:func:`uiofmu.noise.dhat_error_step`: ``dhat_k - d_k = Dy (Yx e_k +
    v_(k+1))``, a system one step ahead whose state ``(eps_k, v_k)`` steps by ``N(a), L(a)`` and whose output
    ``Dy Yx [I, -Xy(a)]`` reads the same ``a = alpha^k``; ``Dy``, ``Yx`` are constant): affine in ``(a, b)`` too.

    With ``alpha``, the error from process noise ``w`` (held over the step, ``x+ = ... + W_sampled w``): with
    ``y`` noise-free, ``e_k = (I - Xy(a) C) x_k - z_k`` and the certificate's identities leave
    ``e+ = N(a) e + (I - Xy(alpha a) C) W_sampled w``: the next point's ``Xy`` reads ``alpha a``, whose
    coefficients ``alpha^j c_j`` keep it affine in ``(a, b)``.
    """
    g = {k: np.asarray(matrices[k], dtype=float) for k in ("N", "L", "Xy") + (("Dy", "Yx") if dhat else ())}
    if any(len(c) > 3 for c in g.values()):
        raise ValueError("a runtime polynomial of degree above 2: the noise vertices do not hold it")
    n = g["N"].shape[-1]

    def at(c, a, b):
        return sum(m * ci for m, ci in zip((1.0, a, b), c))

    def system(a, b):
        N, L, Xy = (at(g[k], a, b) for k in ("N", "L", "Xy"))
        if alpha is not None:
            C, W = (np.asarray(matrices[k], dtype=float) for k in ("C", "W_sampled"))
            following = at([c * alpha ** j for j, c in enumerate(g["Xy"])], a, b)      # Xy(alpha a)
            return N, (np.eye(n) - following @ C) @ W, np.eye(n), np.zeros((n, W.shape[1]))
        return dhat_error_step(N, L, np.eye(n), Xy, at(g["Dy"], a, b), at(g["Yx"], a, b)) if dhat else \
            (N, -L, np.eye(n), -Xy)

    return [(*system(a, b), 0, 0, f"at (a, a^2) = ({a:g}, {b:g})") for a, b in NOISE_VERTICES]


def noise_of(matrices: dict, alpha: float) -> dict:
    """The card's ``noise`` section: ``gain_y`` along the whole schedule (:func:`noise_steps`), its least value by
    :func:`uiofmu.noise.lemma_certificate` with one ``X``, scaled by the limit observer's gain (``a = 0``; the gain
    along the schedule is at least that); ``gain_w`` where the problem declares ``W`` and ``gain_dhat_y`` where the
    card has dhat, alike."""
    method = "bounded real lemma with one X at the vertices of (alpha^k, alpha^2k)"

    def gain(key: str, **form):
        steps = noise_steps(matrices, **form)
        return stated(lemma_certificate(steps, 1, hinf_norm(*steps[0][:4]), key, balanced=key == "gain_dhat_y"),
                      method, key=key)

    return gains_section(matrices, lambda: gain("gain_y"), lambda: gain("gain_w", alpha=alpha),
                         lambda: gain("gain_dhat_y", dhat=True), NO_W)


def noise_checks(noise, matrices: dict, alpha: float) -> list:
    """The re-check of the gains of :func:`noise_of` at a card's stored matrices; a ``gain_w`` claimed by a card
    without ``W_sampled``, or a ``gain_dhat_y`` by one without dhat's matrices, fails."""
    out = recheck(noise, None, None, None, None, steps=noise_steps(matrices))
    if isinstance(noise, dict) and noise.get("gain_w") is not None:
        out += (claimed_without("gain_w", matrices, ("W_sampled",), "the sampled process noise") or
                recheck(noise, None, None, None, None, key="gain_w", steps=noise_steps(matrices, alpha=alpha)))
    if not isinstance(noise, dict) or noise.get("gain_dhat_y") is None:
        return out
    return out + (dhat_missing(matrices) or
                  recheck(noise, None, None, None, None, key="gain_dhat_y", steps=noise_steps(matrices, dhat=True)))


def gain_figures(card_data: dict) -> tuple:
    """The gains ``T_1``, ``T_2``, ``||C||`` and ``||A||`` of the sampled plant (:mod:`uiofmu.gains`)."""
    m = card_data["matrices"]
    return [m["T1"], m["T2"]], float(np.linalg.norm(m["C"], 2)), float(np.linalg.norm(m["A_sampled"], 2))


def _schedule(opts: Options) -> dict:
    return {"kind": "geometric", "alpha": opts.alpha, "dt": opts.dt, "step_policy": opts.step_policy}


#: The bound the card states (:func:`certified_bound` computes it for a run).
BOUND = "||e_k|| <= b_k / sqrt(eig_min X), b_{k+1} = sqrt(1 - eta (1 + mu alpha^k)) b_k + ||S_k d_k||_X"


def determined(problem, card_data, analysis: Analysis) -> dict:
    """What the card's problem and its certified gains ``T1``, ``T2`` determine: the sampled plant,
    ``M``, the vertices ``A1``, ``A2``, ``S1``, every runtime polynomial (:func:`coefficients`; dhat's
    absent unless ``rank(CE) = q``), ``alpha``, ``eta``, ``tau1 = eta (1 + mu)``, ``tau2 = eta``, the
    decay bounds, the step and the schedule; the fixed modes, invariant zeros and fixed modes of
    ``(A_1, C)`` of its analysis, the eigenvalues of ``N`` at both vertices and ``|M C E|``."""
    plant, opts = problem.plant, problem.options
    s, C = plant.sampled(opts.dt), plant.C
    M, A1, A2, S1 = _vertices(s, C, opts.alpha)
    T1, T2 = (np.asarray(card_data["matrices"][k], dtype=float) for k in ("T1", "T2"))
    poly = coefficients(M, T1, T2, s, C, opts.alpha)
    two = lambda x: float(np.linalg.norm(x, 2)) if np.size(x) else 0.0           # noqa: E731
    cond = condition(C @ s.E)                      # M = -E (CE)^+ is in every polynomial and vertex
    plant = (1 + two(M) * two(C)) * (two(s.A) + two(s.B) + two(s.w) + two(s.E))
    size = plant + (two(T1) + two(T2)) * two(C) * (1 + two(M)) + two(M)        # the terms' size: gains too
    for k in ("N", "L", "G", "c", "Xz", "Xy"):
        poly[k] = conditioned(poly[k], cond, size)
    poly.update(dhat_record(C, s.A[None], s.B[None], s.E[None], s.w[None]) if identifiability_condition(C, s.E).holds
                else dict.fromkeys(DHAT))
    mats = {"A_sampled": s.A, "B_sampled": s.B, "E_sampled": s.E, "w_sampled": s.w, "C": C,
            **{k: conditioned(v, cond, plant) for k, v in (("M", M), ("A1", A1), ("A2", A2), ("S1", S1))}, **poly}
    mu = float(card_data["mu"] if opts.mu == "max" else opts.mu)          # a fixed mu is the card's
    tau1, tau2 = opts.eta * (1 + mu), opts.eta
    n, scale = C.shape[1], two(s.A)
    MCE = M @ C @ s.E
    figures = {"fixed_modes": computed_values(analysis.data["fixed"], scale, n),
               "invariant_zeros": computed_values(
                   from_pairs(analysis.existence.value("stable invariant zeros", "zeros")), scale, n),
               "fixed_modes_A1": computed_values(from_pairs(analysis.data["info"].get("fixed_modes_A1", [])),
                                                 two(A1), n),
               "eigenvalues_N_k0": spectrum(A1 - T1 @ C), "eigenvalues_N_inf": spectrum(A2 - T2 @ C),
               "norm_MCE": Determined(two(MCE), two(M) * two(C) * two(s.E))}
    noise = {"noise.norm": "l2"}                       # gain_y, gain_w and gain_dhat_y: verify re-checks them
    if problem.plant.r:
        mats["W_sampled"] = problem.plant.sampled_noise(opts.dt)
    else:
        noise["noise.gain_w"] = None
    if poly["Dy"] is None:
        noise["noise.gain_dhat_y"] = None
    return {**noise, "dt": opts.dt, "schedule": _schedule(opts), "bound": BOUND, "alpha": opts.alpha, "eta": opts.eta,
            "mu": mu, "tau1": tau1, "tau2": tau2, "decay_bound": float(np.sqrt(1 - tau2)),
            "initial_decay_bound": float(np.sqrt(1 - tau1)), **{f"matrices.{k}": v for k, v in mats.items()}, **figures}


def certified_bound(card, e0, d) -> np.ndarray:
    """``||e_k|| <= b_k / sqrt(eig_min X)``, ``b_{k+1} = sqrt(1 - eta_k) b_k + ||S_k d_k||_X``."""
    g = card.data
    X = np.asarray(g["matrices"]["X"])
    MCE = np.asarray(g["matrices"]["M"]) @ np.asarray(g["matrices"]["C"]) @ np.asarray(g["matrices"]["E_sampled"])
    alpha, eta, mu = g["alpha"], g["eta"], g["mu"]
    lo = float(np.linalg.eigvalsh(X)[0])
    b = np.empty(len(d))
    b[0] = float(np.sqrt(e0 @ X @ e0))
    for k in range(len(d) - 1):
        a = alpha ** k
        s = -alpha * a * MCE @ d[k]
        b[k + 1] = np.sqrt(1 - eta * (1 + mu * a)) * b[k] + float(np.sqrt(s @ X @ s))
    return b / np.sqrt(lo)


def _point(v: dict, M, A1, A2, S1, s, C, opts, mu: float) -> dict:
    """The runtime matrices of an LMI point and the figures :func:`checks` reads (a card's data)."""
    X = 0.5 * (v["X"] + v["X"].T)
    T1 = np.linalg.solve(v["G1"], v["Tb1"])
    T2 = np.linalg.solve(v["G2"], v["Tb2"])
    matrices = {**coefficients(M, T1, T2, s, C, opts.alpha), "C": C, "M": M, "T1": T1, "T2": T2, "X": X,
                "A1": A1, "A2": A2, "S1": S1, "A_sampled": s.A, "B_sampled": s.B, "E_sampled": s.E,
                "w_sampled": s.w}
    return {"matrices": matrices, "alpha": opts.alpha, "eta": opts.eta, "mu": mu, "tau1": opts.eta * (1 + mu),
            "tau2": opts.eta}


def design(problem, analysis: Analysis) -> DesignResult:
    """Design the LTV observer (procedure steps 1-9, Theorem 2)."""
    existence, s, fixed, info = (analysis.existence, analysis.data["sampled"], analysis.data["fixed"],
                                 analysis.data["info"])
    plant, opts = problem.plant, problem.options
    C = plant.C
    M, A1, A2, S1 = _vertices(s, C, opts.alpha)
    system = _lmis(A1, A2, S1, C, opts.eta, gain_cap=opts.gain_cap)
    point = lambda v, tau1: _point(v, M, A1, A2, S1, s, C, opts, tau1 / opts.eta - 1.0)   # noqa: E731
    system.certify = lambda v, prm: all(c.holds for c in checks(point(v, prm["tau1"])))
    limit = info["mu_limit"]
    tuned = tune(system, "tau1", opts.mu, feasible_end=limit * 1e-4, infeasible_end=limit, safe_end=0.0,
                 tol=SEARCH_TOL * limit, label=f"{problem.name}: largest mu", transform=lambda m: opts.eta * (1 + m),
                 name="mu")
    mu, sol = tuned.value, tuned.solution
    searched = tuned.search.to_data() if tuned.search else None
    # the least gamma at mu (Remark 1) is a figure of the card only where the solver reached that optimum
    gamma = float(sol.values["gamma"]) if sol.status == "optimal" and sol.relative_margin is None else None
    least = _lmis(A1, A2, S1, C, opts.eta, least_overshoot=True, gain_cap=opts.gain_cap)
    least.certify = system.certify
    least.figure = lambda v: overshoot(v["X"])
    # where margins decided mu, the least overshoot at the margin its point was held at (determined by the problem)
    held = held_margin(sol)
    tau1 = opts.eta * (1 + mu)
    refined = least.solve(tau1=tau1) if held is None else least.least_at_margin(held, tau1=tau1)
    if refined.verified:
        sol = refined
    data = _point(sol.values, M, A1, A2, S1, s, C, opts, mu)
    matrices, X = data["matrices"], data["matrices"]["X"]
    T1, T2, tau1, tau2 = matrices["T1"], matrices["T2"], data["tau1"], data["tau2"]
    if not existence.holds("rank(CE) = q"):
        for k in ("Dy", "Yx", "Yu", "Yc"):
            matrices.pop(k)
    results = {**{k: data[k] for k in ("alpha", "eta", "mu", "tau1", "tau2")}, "gamma": gamma}
    cert = certificate(sol, checks({"matrices": matrices, **results}), f"{NAME} design of {problem.name}")
    N0 = A1 - T1 @ C                                   # N_k at k = 0 (a = 1)
    results.update({
        "decay_bound": float(np.sqrt(1 - tau2)),
        "initial_decay_bound": float(np.sqrt(1 - tau1)),
        "overshoot_bound": overshoot(X),
        "overshoot_digits": figure_digits(sol) if sol is refined else UNDETERMINED,   # gamma's point: any overshoot
        "bound": BOUND,
        "fixed_modes": complex_list(fixed),
        "invariant_zeros": existence.value("stable invariant zeros", "zeros"),
        "fixed_modes_A1": info.get("fixed_modes_A1", []),
        "eigenvalues_N_k0": complex_list(np.linalg.eigvals(N0)),
        "eigenvalues_N_inf": complex_list(np.linalg.eigvals(A2 - T2 @ C)),
        "norm_MCE": float(np.linalg.norm(M @ C @ s.E, 2)),
        "search": searched,
    })
    if plant.r:
        matrices["W_sampled"] = plant.sampled_noise(opts.dt)
    results["noise"] = noise_of(matrices, opts.alpha)
    return DesignResult(plant.n, opts.dt, _schedule(opts), matrices, cert, results, (system, least), opts.xhat0)
