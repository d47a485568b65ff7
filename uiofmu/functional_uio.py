"""Functional unknown-input observers: estimate ``L x`` (``r`` functionals) whatever the unknown input.

For the sampled plant ``x+ = A x + B u + E d``, ``y = C x`` and ``L`` (``r x n``), the observer of order ``k``::

    z+   = N z + J y + H u,        zhat = R z + Q y

with ``e = z - T x`` (``T``: ``k x n``) has ``e+ = N e + (N T + J C - T A) x + (H - T B) u - T E d`` and
``zhat - L x = R e + (R T + Q C - L) x``. So ``zhat - L x -> 0`` for every ``x_0``, ``u`` and ``d`` when::

    T E = 0,     T A - N T = J C,     H = T B,     R T + Q C = L,     N Schur.

**Order r** (``R = I``, ``T = L - Q C``). ``T E = 0`` reads ``Q (C E) = L E``: it is solvable iff
``rank [C E; L E] = rank (C E)`` (*functional decoupling*), with ``Q = L E (CE)^+ + Z Pi``,
``Pi = I - CE (CE)^+`` and ``Z`` free. Then ``T = L P - Z Pi C`` with ``P = I - E (CE)^+ C`` (``L P E = 0``:
``L E`` lies in the row space of ``CE``, so ``L E (CE)^+ CE = L E``), and
``T A - N T = J C`` becomes, with ``K = J - N Z Pi``, the equation linear in ``(N, Z, K)``::

    L P A = [N  Z  K] Phi,      Phi = [L P; Pi C A; C]

solvable iff ``rank [L P A; Phi] = rank Phi`` (*functional matching*: the condition of Darouach (2000), "Existence and
design of functional observers for linear systems", for the decoupled plant). Its solutions are
``[N Z K] = L P A Phi^+ - Y (I - Phi Phi^+)`` for any ``Y``, so ``N = Omega_1 - Y beta_1`` (the first ``r``
columns of ``Omega = L P A Phi^+`` and of ``beta = I - Phi Phi^+``): an output-injection problem on the pair
``(Omega_1, beta_1)``. ``N`` can decay faster than ``rho`` iff every mode of ``Omega_1`` that ``beta_1`` does not
see is inside ``rho`` (*functional detectability*, with the margin ``ZERO_MARGIN`` of the classical UIO's decay
condition; the role of Darouach's condition on ``[s L P - L P A; Phi]``). ``Y`` is the Riccati gain of
:func:`uiofmu.structure.decay_gain`; then ``Z = Omega_2 - Y beta_2``, ``K = Omega_3 - Y beta_3``,
``J = K + N Z Pi``, ``Q = L E (CE)^+ + Z Pi``, ``H = T B``.

**Without a full-state observer.** Nothing above reads ``rank(CE) = rank(E)`` or the decoupled pair of the
full-state observer: ``P E = 0`` needs ``rank(CE) = rank(E)``, ``L P E = 0`` only the functional decoupling, and the
matching and the fixed modes are written on ``L P``, ``Pi C A`` and ``C``. Each condition is also necessary for its
order (``R = I``): every ``Q`` with ``Q CE = L E`` and every ``[N Z K]`` solving the matching are of the forms
above, so ``N`` ranges over ``Omega_1 - Y beta_1`` and no other ``N`` exists. So an observer of ``L x`` exists
where none of ``x`` does: an unknown input that reaches only states ``L x`` does not depend on
(``rank(CE) < rank(E)``), a fixed mode of the decoupled pair outside the decay that the functional error does not
see. Only order ``n`` (``F = I``: ``rank [CE; E] =
rank CE`` is ``rank(CE) = rank(E)``) brings the full-state conditions back; lti-uio with ``observer.functional``
decides on these conditions alone and tells the full-state ones as notes (:func:`informational`).

**The order.** Order ``r`` is tried with ``L``; then ``L`` completed, one direction at a time, by the rows of
``L (P A)^j`` it does not span (orders ``r+1, r+2, ...``; ``R = [I 0]`` reads ``L x`` off the first ``r``
components); last the identity (order ``n``, ``R = L``, ``Q = L Q_n``), the full-order unknown-input observer
whose ``zhat = L xhat`` exists whenever the classical UIO does. The first order whose three conditions hold is
designed. Orders below ``r`` (functionals read off ``y``) and other completions are not searched: the order is
the least among those tried, not always the least that exists.

**Certificate.** ``X`` solves ``(N/rho)' X (N/rho) - X = -I`` (``rho^2 X - N' X N = rho^2 I``), re-checked at the
stored matrices without a solver (:func:`uiofmu.certificate.lyapunov_check`), with the identities above
(:func:`uiofmu.certificate.identity_check`). Then ``||e_k|| <= sqrt(cond X) rho^k ||e_0||`` and::

    ||zhat_k - L x_k|| <= ||R||_2 sqrt(cond X) rho^k ||z_0 - T x_0||.

**The card** (:func:`card_design`) runs on the affine kernel: ``N``, ``L = J``, ``G = H``, ``c = T w``, ``Xz = R``,
``Xy = Q``, ``Zx = T`` and ``Lf = L``, with ``dims.nz`` the order and ``dims.nf = r``; at order ``n`` the
state instead, ``Xz = F^-1``, ``Xy = F^-1 Qk`` (``F``: the order's functionals, ``T + Qk C = F``) and
``zhat = Lf xhat``. The runtime starts at
``z_0 = Zx xhat0`` and outputs ``zhat_0 = Lf xhat0``, then ``zhat_k = Xz z_k + Xy y_k``. With ``eps = Zx x - z``,
``zhat_k - Lf x_k = -Xz eps_k`` and ``eps_0 = Zx (x_0 - xhat0)``, so the card's bound reads the initial estimate's
error: ``||zhat_k - Lf x_k|| <= overshoot_bound rho^k ||x_0 - xhat0||`` with
``overshoot_bound >= max(||Xz|| sqrt(cond X) ||Zx||, ||Lf||)`` (:func:`bound`, re-checked by
:func:`overshoot_check`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .certificate import (UNDETERMINED, Check, certificate, decay_check, identity_check, lyapunov_check, magnitude,
                          overshoot, positive_check)
from .existence import Condition, complex_list
from .runtime.errors import ProblemError
from .scaling import to_data as scaling_data
from .runtime.tolerances import RANK_RTOL, ZERO_MARGIN
from .structure import decay_gain, rank, unobservable_modes
from .threads import blas_module

#: Most functionals ``observer.functional`` lists.
MAX_FUNCTIONALS = 1000


def parse_functional(raw, n: int) -> np.ndarray:
    """``observer.functional``: a list of ``r`` rows of ``n`` finite numbers, none of them all zeros.

    Raises
    ------
    ProblemError
        Naming the key and the numbers.
    """
    key = "observer.functional"
    if not isinstance(raw, list) or not 1 <= len(raw) <= MAX_FUNCTIONALS:
        raise ProblemError(f"{key}: expected a list of 1 to {MAX_FUNCTIONALS} rows of {n} numbers, "
                           f"found {type(raw).__name__}")
    rows = []
    for i, row in enumerate(raw):
        if not isinstance(row, list) or len(row) != n:
            width = len(row) if isinstance(row, list) else "no list"
            raise ProblemError(f"{key}[{i}]: expected a row of {n} numbers (the plant has n = {n}), found {width}")
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in row):
            raise ProblemError(f"{key}[{i}]: every entry must be a number")
        values = np.array(row, dtype=float)
        if not np.all(np.isfinite(values)):
            raise ProblemError(f"{key}[{i}]: non-finite entry (inf or nan)")
        if not np.any(values):
            raise ProblemError(f"{key}[{i}]: a row of zeros estimates nothing")
        rows.append(values)
    L = np.vstack(rows)
    if rank(L) < len(rows):
        raise ProblemError(f"{key}: the {len(rows)} rows are dependent (rank {rank(L)}): a functional the others give "
                           "is estimated by them, remove it")
    return L


@dataclass(frozen=True)
class FunctionalDesign:
    """A functional unknown-input observer ``z+ = N z + J y + H u``, ``zhat = R z + Q y``.

    ``T`` maps the state to the observer's ``z`` (``z - T x -> 0``); ``X`` certifies ``N``'s decay ``rho``.
    """

    order: int
    N: np.ndarray
    J: np.ndarray
    H: np.ndarray
    R: np.ndarray
    Q: np.ndarray
    T: np.ndarray
    X: np.ndarray
    rho: float
    conditions: tuple
    Qk: np.ndarray | None = None      # the Q of the order's own functionals F (``T + Qk C = F``)
    F: np.ndarray | None = None       # those functionals (L completed); at order n xhat = F^-1 (z + Qk y)

    @property
    def overshoot(self) -> float:
        """``sqrt(cond X)``."""
        w = np.linalg.eigvalsh(self.X)
        return float(np.sqrt(w[-1] / w[0]))

    def bound(self, e0_norm: float, k) -> np.ndarray:
        """The certified bound ``||R|| sqrt(cond X) rho^k ||e_0||`` on ``||zhat_k - L x_k||``."""
        return np.linalg.norm(self.R, 2) * self.overshoot * self.rho ** np.asarray(k, dtype=float) * e0_norm


def _pinv(M: np.ndarray) -> np.ndarray:
    """The pseudo-inverse at the rank tolerance (singular values below ``RANK_RTOL * max(1, s_max)`` dropped, as
    :func:`uiofmu.structure.rank` does not count them)."""
    if not M.size:
        return M.T.copy()
    s_max = float(np.linalg.norm(M, 2))
    return np.linalg.pinv(M, rtol=RANK_RTOL * max(1.0, s_max) / max(s_max, 1e-300))


def order_conditions(A, C, E, L, rho) -> tuple[tuple, dict | None]:
    """The three conditions of an observer of order ``rows(L)`` estimating ``L x`` (module docstring), with
    their numbers, and the matrices of the design when they hold (else None)."""
    r = L.shape[0]
    CE, LE = C @ E, L @ E
    r_ce, r_stack = rank(CE), rank(np.vstack([CE, LE]))
    decoupled = r_stack == r_ce
    conds = [Condition("rank [CE; LE] = rank CE", decoupled, True,
                       f"rank [CE; LE] = {r_stack} {'=' if decoupled else '>'} rank CE = {r_ce}",
                       {"rank_stack": r_stack, "rank_CE": r_ce})]
    if not decoupled:
        return tuple(conds), None
    CEp = _pinv(CE)
    P = np.eye(A.shape[0]) - E @ CEp @ C
    Pi = np.eye(C.shape[0]) - CE @ CEp
    LP = L @ P
    Phi = np.vstack([LP, Pi @ C @ A, C])
    r_phi, r_aug = rank(Phi), rank(np.vstack([LP @ A, Phi]))
    matched = r_aug == r_phi
    conds.append(Condition("rank [LPA; Phi] = rank Phi", matched, True,
                           f"rank [LPA; LP; Pi C A; C] = {r_aug} {'=' if matched else '>'} rank [LP; Pi C A; C] "
                           f"= {r_phi}", {"rank_augmented": r_aug, "rank_Phi": r_phi}))
    if not matched:
        return tuple(conds), None
    Phip = _pinv(Phi)
    Omega = LP @ A @ Phip
    beta = np.eye(Phi.shape[0]) - Phi @ Phip
    fixed = unobservable_modes(Omega[:, :r], beta[:, :r])
    largest = float(np.max(np.abs(fixed))) if fixed.size else 0.0
    detectable = largest + ZERO_MARGIN < rho
    conds.append(Condition("fixed modes inside decay", detectable, True,
                           f"largest fixed mode of the functional error |{largest:.6g}| "
                           f"{'<' if detectable else '>='} decay {rho:g} ({fixed.size} fixed modes)",
                           {"largest_fixed_mode": largest, "decay": rho, "fixed_modes": int(fixed.size)}))
    if not detectable:
        return tuple(conds), None
    return tuple(conds), {"P": P, "Pi": Pi, "CEp": CEp, "LP": LP, "Omega": Omega, "beta": beta}


def _design_order(A, B, C, E, L, rho, parts) -> dict:
    """``N, J, H, Q, T`` of the observer estimating ``L x`` at its own order (``R = I``)."""
    r, p = L.shape[0], C.shape[0]
    Omega, beta, Pi = parts["Omega"], parts["beta"], parts["Pi"]
    Y = decay_gain(Omega[:, :r], beta[:, :r], rho)
    NZK = Omega - Y @ beta
    N, Z, K = NZK[:, :r], NZK[:, r:r + p], NZK[:, r + p:]
    Q = L @ E @ parts["CEp"] + Z @ Pi
    T = L - Q @ C
    return {"N": N, "J": K + N @ Z @ Pi, "H": T @ B, "Q": Q, "T": T}


def design(A, B, C, E, L, rho: float) -> FunctionalDesign:
    """The functional observer of least order this module proves (``r``, else ``n``), certified at ``rho``.

    Raises
    ------
    ProblemError
        When neither order exists (the order-``n`` conditions, i.e. the full-order UIO's, fail); the message
        gives both orders' failing conditions with their numbers.
    """
    solve_discrete_lyapunov = blas_module("scipy.linalg").solve_discrete_lyapunov

    n, r = A.shape[0], L.shape[0]
    tried = []
    for target, R in _completions(A, C, E, L):
        conds, parts = order_conditions(A, C, E, target, rho)
        tried.append((target.shape[0], conds))
        if parts is not None:
            break
    else:
        failed = "; ".join(f"order {k}: " + ", ".join(c.message for c in cs if not c.holds) for k, cs in tried)
        raise ProblemError(f"observer.functional: no functional unknown-input observer of order {r} to {n} "
                           f"exists at decay {rho:g}: {failed}")
    order = target.shape[0]
    conds = tuple(c for _, cs in tried for c in cs)
    d = _design_order(A, B, C, E, target, rho, parts)
    Ns = d["N"] / rho
    X = solve_discrete_lyapunov(Ns.T, np.eye(order))
    X = 0.5 * (X + X.T)
    return FunctionalDesign(order, d["N"], d["J"], d["H"], R, R @ d["Q"], d["T"], X, rho, conds, d["Q"], target)


def _completions(A, C, E, L):
    """The functionals each order is tried with, and the ``R`` that reads ``L x`` from them: ``L`` (order ``r``),
    then ``L`` completed by the directions of ``L (P A)^j`` (``j = 1, 2, ...``) that ``L`` and the earlier ones do
    not span, one at a time, and the identity (order ``n``, the full-order observer, ``R = L``)."""
    n, r = A.shape[0], L.shape[0]
    yield L, np.eye(r)
    CE = C @ E
    PA = (np.eye(n) - E @ _pinv(CE) @ C) @ A
    basis = np.linalg.qr(L.T)[0][:, :rank(L)].T
    current, row, extra = L, L, []
    for _ in range(n):
        row = row @ PA
        for w in row:
            w = w - (w @ basis.T) @ basis
            w = w - (w @ basis.T) @ basis
            size = float(np.linalg.norm(w))
            if size <= RANK_RTOL * max(1.0, float(np.linalg.norm(row, 2))) or basis.shape[0] + 1 >= n:
                continue
            basis = np.vstack([basis, w / size])
            extra.append(w / size)
            current = np.vstack([L, np.array(extra)])
            if current.shape[0] < n:
                yield current, np.eye(current.shape[0])[:r]
    if r < n or rank(L) < n:
        yield np.eye(n), L


def card_matrices(s, C, L, design_: FunctionalDesign) -> dict:
    """The card's matrices of a design on the sampled plant ``s`` (``A, B, E`` and its affine term ``w``): the
    affine kernel's ``N``, ``L = J``, ``G = H``, ``c = T w``, ``Xz = R``, ``Xy = Q``, ``C``, with ``Zx = T``
    (``z_0 = Zx xhat0``), the functionals ``Lf`` (``zhat_0 = Lf xhat0``), the Lyapunov matrix ``X`` and the sampled
    plant the checks read. At order ``n`` the observer estimates the state: its functionals ``F`` (``L``
    completed, independent rows) are invertible and ``Zx + Qk C = F``, so ``Xz = F^-1``, ``Xy = F^-1 Qk`` give
    ``xhat = Xz z + Xy y`` and ``zhat = Lf xhat``."""
    f = design_
    if f.order == C.shape[1]:            # order n: T + Qk C = F (invertible), xhat = F^-1 (z + Qk y), zhat = Lf xhat
        Xz = np.linalg.inv(f.F)
        Xy = Xz @ f.Qk
    else:
        Xz, Xy = f.R, f.Q
    return {"N": f.N, "L": f.J, "G": f.H, "c": f.T @ s.w, "Xz": Xz, "Xy": Xy, "C": C, "Zx": f.T, "Lf": L,
            "X": f.X, "A_sampled": s.A, "B_sampled": s.B, "E_sampled": s.E, "w_sampled": s.w}


def estimates_state(matrices: dict) -> bool:
    """Whether a functional card's observer has order ``n`` and so estimates the state (``xhat = Xz z + Xy y``,
    ``zhat = Lf xhat``): its ``Zx`` is square."""
    Zx = np.shape(matrices["Zx"])
    return len(Zx) == 2 and Zx[0] == Zx[1]


def card_checks(matrices: dict, rho: float) -> list[Check]:
    """The re-check at a card's stored matrices, without a solver: ``Zx E = 0``, ``Zx A - N Zx - L C = 0``,
    ``Zx B = G``, ``c = Zx w``, ``Xz Zx + Xy C = Lf`` (at order ``n``: ``= I``, the state), ``X > 0``,
    ``rho^2 X - N'XN > 0`` and ``rho < 1``."""
    g = {k: np.asarray(v, dtype=float) for k, v in matrices.items()}
    T, A, B, E, C = g["Zx"], g["A_sampled"], g["B_sampled"], g["E_sampled"], g["C"]
    N, J, H, R, Q, Lf = g["N"], g["L"], g["G"], g["Xz"], g["Xy"], g["Lf"]
    return [
        identity_check("decoupling ||Zx E||", T @ E, magnitude([T, E])),
        identity_check("||Zx A - N Zx - L C||", T @ A - N @ T - J @ C, magnitude([T, A], [N, T], [J, C])),
        identity_check("||Zx B - G||", T @ B - H, magnitude([T, B], [H]) if B.size else 0.0),
        identity_check("||c - Zx w||", g["c"] - T @ g["w_sampled"], magnitude([T, g["w_sampled"][:, None]])),
        (identity_check("||Xz Zx + Xy C - I|| (xhat at order n)", R @ T + Q @ C - np.eye(len(A)),
                        magnitude([R, T], [Q, C], [np.eye(len(A))])) if estimates_state(matrices) else
         identity_check("||Xz Zx + Xy C - Lf||", R @ T + Q @ C - Lf, magnitude([R, T], [Q, C], [Lf]))),
        positive_check("eig_min(X)", g["X"]),
        lyapunov_check("eig_min(rho^2 X - N'XN)", N, g["X"], rho),
        decay_check(rho),
    ]


def checks(design_: FunctionalDesign, A, B, C, E, L) -> list[Check]:
    """:func:`card_checks` of a design on the plant ``x+ = A x + B u + E d`` (no affine term)."""
    from types import SimpleNamespace

    plant = SimpleNamespace(A=A, B=B, E=E, w=np.zeros(A.shape[0]))
    return card_checks(card_matrices(plant, C, L, design_), design_.rho)


#: The relative room the stored ``overshoot_bound`` takes above its figure (rounding of the norms on another
#: machine), as the reduced-order observer's.
OVERSHOOT_ROOM = 1e-9


def _overshoot(matrices: dict) -> float:
    """``max(||Xz|| sqrt(cond X) ||Zx||, ||Lf||)``: ``zhat_k - Lf x_k = -Xz eps_k`` with ``eps = Zx x - z``,
    ``||eps_k|| <= sqrt(cond X) rho^k ||eps_0||`` and ``eps_0 = Zx (x_0 - xhat0)``; ``zhat_0 = Lf xhat0``."""
    g = {k: np.asarray(matrices[k], dtype=float) for k in ("Xz", "Zx", "Lf", "X")}
    norm = lambda M: float(np.linalg.norm(M, 2)) if M.size else 0.0     # noqa: E731
    Xz = g["Lf"] @ g["Xz"] if estimates_state(matrices) else g["Xz"]      # zhat = Lf xhat at order n
    return max(norm(Xz) * overshoot(g["X"]) * norm(g["Zx"]), norm(g["Lf"]))


def bound(matrices: dict) -> float:
    """The card's ``overshoot_bound``: :func:`_overshoot` with :data:`OVERSHOOT_ROOM`, so that
    ``||zhat_k - Lf x_k|| <= overshoot_bound rho^k ||x_0 - xhat0||`` for every ``k >= 0`` and every ``d``."""
    return _overshoot(matrices) * (1.0 + OVERSHOOT_ROOM)


def overshoot_check(claimed, matrices: dict) -> Check:
    """``overshoot_bound >= max(||Xz|| sqrt(cond X) ||Zx||, ||Lf||)`` at the stored matrices."""
    value = float(claimed) if isinstance(claimed, (int, float)) and not isinstance(claimed, bool) else float("nan")
    return Check("overshoot_bound (needs >= max(||Xz|| sqrt(cond X) ||Zx||, ||Lf||))", value, _overshoot(matrices),
                 at_most=False)


def estimate_output(matrices: dict) -> tuple:
    """The output matrices of the estimate a card's noise gains bound, ``estimate = Xz z + Xy y``: the stored
    ``Xz``, ``Xy``, except a functional observer of order ``n``, whose ``Xz``, ``Xy`` give ``xhat`` and whose
    gains bound ``zhat = Lf xhat`` (``Lf Xz``, ``Lf Xy``)."""
    Xz, Xy = (np.asarray(matrices[k], dtype=float) for k in ("Xz", "Xy"))
    if "Lf" in matrices and estimates_state(matrices):
        Lf = np.asarray(matrices["Lf"], dtype=float)
        return Lf @ Xz, Lf @ Xy
    return Xz, Xy


#: The bound a functional card states (the master checks each run of ``zhat`` against it).
BOUND = "||zhat_k - Lf x_k|| <= overshoot_bound * decay_bound**k * ||x_0 - xhat0||"


def card_design(problem, analysis, name: str, schedule: dict, noise_section):
    """The functional observer of an lti-uio problem with ``observer.functional`` as a
    :class:`~uiofmu.families.DesignResult`: the least order :func:`design` proves, at the problem's decay, with
    the card's matrices (:func:`card_matrices`), its re-check (:func:`card_checks`), ``order`` and
    ``overshoot_bound``. ``name`` is the family's, ``schedule`` the card's schedule and
    ``noise_section(matrices)`` the family's noise section (lti-uio's).

    Raises
    ------
    ProblemError
        For what the functional design does not support (``decay = "max"``, ``plant.D``) and when no order
        ``r..n`` exists, naming the failed conditions with their numbers.
    """
    from .families import DesignResult
    from .lmi import LmiSolution

    plant, opts, s = problem.plant, problem.options, analysis.data["sampled"]
    if opts.decay == "max":
        raise ProblemError("observer.functional designs the functional observer at a given decay: give "
                           "observer.decay a number in (0, 1) (decay = \"max\" has no fastest functional design: "
                           "its gain is the Riccati gain at the decay asked for)")
    if plant.feeds_u:
        raise ProblemError("observer.functional: the functional observer is written for y = C x; this plant's known "
                           "input feeds through (plant.D), remove observer.functional")
    rho, L = float(opts.decay), opts.functional
    f = design(s.A, s.B, plant.C, s.E, L, rho)
    matrices = card_matrices(s, plant.C, L, f)
    if plant.r:
        matrices["W_sampled"] = plant.sampled_noise(opts.dt)
    solution = LmiSolution({"X": f.X}, {"rho2": rho * rho}, "closed form (Riccati gain of the functional error, "
                           "discrete Lyapunov equation)", {}, True, 0.0, 0.0)
    cert = certificate(solution, card_checks(matrices, rho), f"{name} functional design of {problem.name}",
                       solver="none")
    eigN = np.linalg.eigvals(f.N)
    results = {
        "order": f.order,
        "decay": rho,
        "decay_bound": rho,
        "overshoot_bound": bound(matrices),
        "overshoot_digits": UNDETERMINED,       # ||Zx||, ||Xz|| read the chosen solution of the matching equation
        "bound": BOUND,
        "fixed_modes": complex_list(analysis.data["fixed"]),
        **full_state_zeros(analysis.existence),
        "eigenvalues_N": complex_list(eigN),
        "spectral_radius_N": float(np.abs(eigN).max()) if eigN.size else 0.0,
        "design_method": "riccati (functional error)",
        "scaling": scaling_data(np.ones(plant.n), "none"),
        "noise": noise_section(matrices),
    }
    return DesignResult(f.order, opts.dt, schedule, matrices, cert, results, None, opts.xhat0,
                        nf=L.shape[0])


#: The ``[observer]`` keys a functional observer does not support, and why.
UNSUPPORTED = {"poles": "places the state observer's poles", "noise": "designs the state observer's gain",
               "noise_gain": "designs the state observer's gain"}


def parse_option(table, plant) -> np.ndarray | None:
    """``observer.functional`` of an lti-uio problem (None when absent), refusing what the functional observer does
    not support: a plant whose unknown input feeds through (``plant.F``) and the state observer's ``poles``,
    ``noise`` and ``noise_gain``."""
    if not table.has("functional"):
        return None
    L = parse_functional(table.get("functional"), plant.n)
    if plant.feeds_d:
        raise ProblemError("observer.functional: the functional observer is written for y = C x (+ D u); this plant's "
                           "unknown input feeds through (plant.F), remove observer.functional")
    for key, why in UNSUPPORTED.items():
        if table.has(key):
            raise ProblemError(f"observer.functional: observer.{key} {why}, which the functional observer does not "
                               f"use: remove observer.{key}")
    return L


#: What the full-state unknown-input observer's conditions say under ``observer.functional``.
NOT_REQUIRED = "the full-state observer's condition, not required for a functional observer"


def informational(conditions: list) -> list[Condition]:
    """The full-state observer's conditions, told but not required: a functional observer exists on conditions of
    its own (:func:`analysis_conditions`), which ``rank(CE) = rank(E)`` and a detectable decoupled pair are not.
    A failing one says so in its message (its hint, which would make the full-state observer exist, dropped)."""
    return [c if not c.required else replace(c, required=False) if c.holds else
            replace(c, required=False, hint="", message=f"{c.message} ({NOT_REQUIRED})") for c in conditions]


def full_state_zeros(existence) -> dict:
    """``{"invariant_zeros": ...}``, the zeros the full-state conditions computed (a card's figure), or nothing
    where ``rank(CE) < rank(E)`` left them out (no decoupled pair, nothing the functional observer reads)."""
    names = [c.name for c in existence.conditions]
    if "stable invariant zeros" not in names:
        return {}
    return {"invariant_zeros": existence.value("stable invariant zeros", "zeros")}


def analysis_conditions(A, C, E, L, rho: float) -> list[Condition]:
    """The conditions of each order tried (informational, prefixed ``order k:``) and the required one: a functional
    observer of some order ``r..n`` exists at decay ``rho`` (``rho = 1`` for ``decay = "max"``)."""
    out, found, failed = [], None, []
    for target, _ in _completions(A, C, E, L):
        conds, parts = order_conditions(A, C, E, target, rho)
        k = target.shape[0]
        out.extend(Condition(f"order {k}: {c.name}", c.holds, False, f"order {k}: {c.message}", c.values)
                   for c in conds)
        failed += [f"order {k}: {c.message}" for c in conds if not c.holds]
        if parts is not None:
            found = k
            break
    n, r = A.shape[0], L.shape[0]
    msg = (f"functional observer of order {found} (searched {r}..{n}) for the {r} functional(s) of "
           f"observer.functional" if found else
           f"no functional observer of order {r}..{n} at decay {rho:g} ({'; '.join(failed)})")
    out.append(Condition("functional observer order", found is not None, True, msg,
                         {"order": found, "functionals": r, "n": n}))
    return out

