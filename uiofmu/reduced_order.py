"""Reduced-order unknown-input observer of the lti-uio family (``observer.order = "reduced"``).

For the sampled plant ``x+ = A x + B u + E d + w``, ``y = C x`` with ``C`` of full row rank ``p`` and
``rank(CE) = rank(E)``, the observer's state has ``n - p`` entries; ``y`` gives the rest of the state.

Construction (every step exact, the card stores the result)::

    M  = -E (CE)^+,   P = I + M C              (P E = 0, as the full-order observer)
    Q  = orthonormal basis of null(C)          (the last n - p columns of the Householder QR of C')
    R  = Q' P                                  ([R; C] = [[I, Q'M], [0, I]] [Q'; C] is invertible)
    [Xz0, Xy0] = [R; C]^-1                     (x = Xz0 R x + Xy0 y)
    Pi = I - (CE)(CE)^+                        (Pi C E = 0)
    Ar = R A Xz0,   Cr = Pi C A Xz0            (the decoupled pair, n - p states)

``w = R x`` obeys ``w+ = Ar w + R A Xy0 y + R B u + R w_aff`` (``R E = 0``) and the next output gives the
measurement ``Pi (y+ - C A Xy0 y - C B u - C w_aff) = Cr w`` free of ``d``. A gain ``K`` of the pair ``(Ar, Cr)``
(the full-order design's LMI or Riccati gain, :mod:`uiofmu.families.lti_uio`) makes ``Ar - K Cr`` contract;
the observer's state ``z`` estimates ``R_K x`` with ``R_K = R - K Pi C`` (the next output moved into the state,
so the runtime reads ``y_k`` only). With ``Xz0 = Qz Rz`` (QR) the card's coordinates are ``z <- Rz z``::

    Zx = Rz (R - K Pi C),   Xz = Qz,   Xy = Xy0 + Xz0 K Pi
    N  = Zx A Xz,   L = Zx A Xy,   G = Zx B,   c = Zx w_aff

so that ``Zx E = 0``, ``Zx A - N Zx - L C = 0``, ``Xz Zx + Xy C = I`` and ``Xz' Xz = I``, which the checks
re-check at the stored matrices. The error ``eps = Zx x - z`` obeys ``eps+ = N eps`` whatever ``d`` and
``x - xhat = Xz eps``. The runtime starts at ``z_0 = Zx (xhat0 - Xy y_0) = Zx xhat0`` (``Zx Xy = 0``), so
``eps_0 = Zx e_0`` with ``e_0 = x_0 - xhat0``. With ``X`` the Lyapunov matrix of ``N``
(``rho^2 X - N'XN > 0``, the full-order design's ``X`` moved to the card's coordinates,
``X <- Rz^-T X Rz^-1``) and ``||Xz|| = 1``::

    ||e_k|| = ||eps_k|| <= sqrt(cond X) rho^k ||eps_0|| <= sqrt(cond X) ||Zx|| rho^k ||e_0||

so the card's ``overshoot_bound`` is ``sqrt(cond X) ||Zx||_2`` (rounded up), the bound of every lti-uio card.
The fixed modes of ``(Ar, Cr)`` are those of the full-order observer (the stable invariant zeros): the
conditions are the family's. Measurement noise ``v`` (``y = C x + v``) enters as ``eps+ = N eps - L v``,
``e = Xz eps - Xy v``; process noise ``W w`` as ``eps+ = N eps + Zx W w``, ``e = Xz eps``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .certificate import (UNDETERMINED, Check, certificate, decay_check, identity_check, lyapunov_check, magnitude,
                          overshoot, positive_check)
from .decoupling import decoupling_gain
from .existence import complex_list
from .lmi import tune
from .noise import dhat_error_step
from .runtime.errors import InfeasibleError, ProblemError
from .runtime.tolerances import SEARCH_TOL
from .scaling import to_data as scaling_data
from .structure import rank

#: The relative room the stored ``overshoot_bound`` takes above ``sqrt(cond X) ||Zx||`` (rounding of the norms on
#: another machine).
OVERSHOOT_ROOM = 1e-9


def complement(C: np.ndarray) -> np.ndarray:
    """An orthonormal basis of ``null(C)`` (``n x (n - p)``): the last columns of the complete Householder QR of
    ``C'`` (deterministic, no choice among equal singular values)."""
    p = C.shape[0]
    Q, _ = np.linalg.qr(C.T, mode="complete")
    return Q[:, p:]


def reduced_pair(A, E, C, M) -> dict:
    """``R``, ``Xz0``, ``Xy0``, ``Pi`` and the pair ``(Ar, Cr)`` of the module docstring."""
    n, p = C.shape[1], C.shape[0]
    if rank(C) != p:
        raise ProblemError(f'observer.order = "reduced": plant.C ({p} x {n}) has rank {rank(C)} < {p} outputs; the '
                           "reduced observer needs independent outputs")
    P = np.eye(n) + M @ C
    R = complement(C).T @ P
    T = np.linalg.inv(np.vstack([R, C]))
    Xz0, Xy0 = T[:, :n - p], T[:, n - p:]
    CE = C @ E
    Pi = np.eye(p) - CE @ np.linalg.pinv(CE) if E.size else np.eye(p)
    return {"R": R, "Xz0": Xz0, "Xy0": Xy0, "Pi": Pi, "A": R @ A @ Xz0, "C": Pi @ C @ A @ Xz0}


def runtime(s, C, M, red: dict, X, K) -> dict:
    """The card's matrices of a gain ``K`` of the reduced pair and its Lyapunov matrix ``X`` (module docstring)."""
    Qz, Rz = np.linalg.qr(red["Xz0"])
    Zx = Rz @ (red["R"] - K @ red["Pi"] @ C)
    Xy = red["Xy0"] + red["Xz0"] @ K @ red["Pi"]
    Ri = np.linalg.inv(Rz)
    X = Ri.T @ (0.5 * (X + X.T)) @ Ri
    N, L = Zx @ s.A @ Qz, Zx @ s.A @ Xy
    out = {"N": N, "L": L, "G": Zx @ s.B, "c": Zx @ s.w, "Xz": Qz, "Xy": Xy, "Zx": Zx, "C": C, "M": M, "K": K,
           "X": 0.5 * (X + X.T), "A_sampled": s.A, "B_sampled": s.B, "E_sampled": s.E, "w_sampled": s.w}
    return out


def bound(matrices: dict) -> float:
    """``sqrt(cond X) ||Zx||_2`` with :data:`OVERSHOOT_ROOM`: the card's ``overshoot_bound``."""
    return overshoot(np.asarray(matrices["X"])) * float(np.linalg.norm(matrices["Zx"], 2)) * (1.0 + OVERSHOOT_ROOM)


def checks(matrices: dict, rho: float) -> list:
    """The certificate's checks at the stored matrices: ``Zx E = 0``, ``Zx A - N Zx - L C = 0``, ``Zx B = G``,
    ``c = Zx w``, ``Xz Zx + Xy C = I``, ``Xz' Xz = I``, ``X > 0`` and ``rho^2 X - N'XN > 0``."""
    g = {k: np.asarray(v, dtype=float) for k, v in matrices.items()}
    Zx, A, B, E, C = g["Zx"], g["A_sampled"], g["B_sampled"], g["E_sampled"], g["C"]
    N, L, G, X, Xz, Xy = g["N"], g["L"], g["G"], g["X"], g["Xz"], g["Xy"]
    n = A.shape[0]
    return [
        identity_check("decoupling ||Zx E||", Zx @ E, magnitude([Zx, E])),
        identity_check("||Zx A - N Zx - L C||", Zx @ A - N @ Zx - L @ C, magnitude([Zx, A], [N, Zx], [L, C])),
        identity_check("||Zx B - G||", Zx @ B - G, magnitude([Zx, B], [G]) if B.size else 0.0),
        identity_check("||c - Zx w||", g["c"] - Zx @ g["w_sampled"], magnitude([Zx, g["w_sampled"][:, None]])),
        identity_check("||Xz Zx + Xy C - I||", Xz @ Zx + Xy @ C - np.eye(n), magnitude([Xz, Zx], [Xy, C], [np.eye(n)])),
        identity_check("||Xz' Xz - I||", Xz.T @ Xz - np.eye(Xz.shape[1]), 1.0),
        positive_check("eig_min(X)", X),
        lyapunov_check("eig_min(rho^2 X - N'XN)", N, X, rho),
        decay_check(rho),
    ]


def overshoot_check(claimed, matrices: dict) -> Check:
    """``overshoot_bound >= sqrt(cond X) ||Zx||_2`` (``||Xz|| = 1``, which :func:`checks` re-checks)."""
    need = overshoot(np.asarray(matrices["X"], dtype=float)) * float(np.linalg.norm(np.asarray(matrices["Zx"]), 2))
    value = float(claimed) if isinstance(claimed, (int, float)) else float("nan")
    return Check("overshoot_bound (needs >= sqrt(cond X) ||Zx||)", value, need, at_most=False)


def error_system(matrices: dict) -> tuple:
    """Measurement noise ``v``: ``eps+ = N eps - L v``, ``e = Xz eps - Xy v``."""
    N, L, Xz, Xy = (np.asarray(matrices[k], dtype=float) for k in ("N", "L", "Xz", "Xy"))
    return N, -L, Xz, -Xy


def process_error_system(matrices: dict) -> tuple:
    """Process noise ``w``: ``eps+ = N eps + Zx W_sampled w``, ``e = Xz eps``."""
    N, Zx, W, Xz = (np.asarray(matrices[k], dtype=float) for k in ("N", "Zx", "W_sampled", "Xz"))
    return N, Zx @ W, Xz, np.zeros((Xz.shape[0], W.shape[1]))


def dhat_error_system(matrices: dict) -> tuple:
    """Measurement noise to the error of ``dhat`` (``dhat_k - d_k = Dy (Yx e_k + v_(k+1))``, shifted by one step as
    :func:`uiofmu.families.lti_uio.dhat_error_system`): state ``(eps, v)``, :func:`uiofmu.noise.dhat_error_step`."""
    return dhat_error_step(*(matrices[k] for k in ("N", "L", "Xz", "Xy", "Dy", "Yx")))


def _tuned(red: dict, largest: float, opts, name: str, certify, family):
    """The decay and its certificate on the reduced pair: the family's decay LMI (no state scaling: the pair's
    coordinates are orthonormal ones of the plant's), or its Riccati gain (``method = "riccati"``, and the
    fallback of ``"auto"``)."""

    Ar, Cr = red["A"], red["C"]
    system = family._lmis(Ar, Cr, opts.gain_cap)
    system.certify = lambda v, prm: certify(v["X"], np.linalg.solve(0.5 * (v["X"] + v["X"].T), v["W"]),
                                            float(np.sqrt(prm["rho2"])))
    system.figure = lambda v: overshoot(v["X"])
    if opts.method == "riccati":
        return family._riccati(Ar, Cr, float(opts.decay)), "riccati", system
    try:
        tuned = tune(system, "rho2", opts.decay, feasible_end=0.5 * (1.0 + largest), infeasible_end=largest,
                     safe_end=1.0, tol=SEARCH_TOL, label=f"{name}: fastest decay", transform=lambda r: r * r,
                     name="decay", diagnose=opts.method == "lmi")
        values = dict(tuned.solution.values)
        values["K"] = np.linalg.solve(0.5 * (values["X"] + values["X"].T), values["W"])
        return replace(tuned, solution=replace(tuned.solution, values=values)), "lmi", system
    except InfeasibleError as exc:
        if opts.method == "lmi" or opts.gain_cap is not None:
            raise
        rho = 0.5 * (1.0 + largest) if opts.decay == "max" else float(opts.decay)
        try:
            return family._riccati(Ar, Cr, rho), "riccati (the LMI found no certificate)", system
        except (InfeasibleError, ValueError, np.linalg.LinAlgError) as fallback:
            raise type(exc)(f"{exc}; the solver-free fallback fails too: {fallback}") from None


def design(problem, analysis, family):
    """The reduced-order design of an lti-uio problem (module docstring): a :class:`~uiofmu.families.DesignResult`
    whose ``nz`` is ``n - p``. ``family`` is the lti-uio module, whose decay LMI, Riccati gain, dhat matrices,
    schedule and noise section the design reuses."""
    from .families import DesignResult

    existence, s, fixed = analysis.existence, analysis.data["sampled"], analysis.data["fixed"]
    plant, opts = problem.plant, problem.options
    if plant.feedthrough or opts.poles is not None or opts.noise != "default" or opts.noise_gain is not None:
        raise ProblemError('observer.order = "reduced" designs the decay LMI or the Riccati gain of a plant without '
                           "feedthrough: no plant.D, plant.F, observer.poles, noise or noise_gain")  # options in code
    C = plant.C
    M = decoupling_gain(C, s.E)
    red = reduced_pair(s.A, s.E, C, M)
    largest = float(np.abs(fixed).max()) if fixed.size else 0.0

    def certify(X, K, rho):
        return all(c.holds for c in checks(runtime(s, C, M, red, X, K), rho))

    tuned, method, system = _tuned(red, largest, opts, problem.name, certify, family)
    rho, sol = tuned.value, tuned.solution
    matrices = runtime(s, C, M, red, sol.values["X"], sol.values["K"])
    cert = certificate(sol, checks(matrices, rho), f"{family.NAME} reduced-order design of {problem.name}",
                       solver="CLARABEL" if method.startswith("lmi") else "none")
    if existence.holds("rank(CE) = q"):
        matrices.update({k: v.value for k, v in family._dhat(s, C).items()})
    if plant.r:
        matrices["W_sampled"] = plant.sampled_noise(opts.dt)
    eigN = np.linalg.eigvals(matrices["N"])
    results = {
        "order": "reduced",
        "decay": rho,
        "decay_bound": rho,
        "overshoot_bound": bound(matrices),
        "overshoot_digits": UNDETERMINED,       # ||Zx|| reads the gain, which the LMI's optimum does not fix
        "bound": family.BOUND,
        "fixed_modes": complex_list(fixed),
        "invariant_zeros": existence.value("stable invariant zeros", "zeros"),
        "eigenvalues_N": complex_list(eigN),
        "spectral_radius_N": float(np.abs(eigN).max()) if eigN.size else 0.0,
        "search": tuned.search.to_data() if tuned.search else None,
        "design_method": method,
        "scaling": scaling_data(np.ones(plant.n), "none"),
        "noise": family.noise_section(matrices),
    }
    return DesignResult(plant.n - plant.p, opts.dt, family._schedule(opts), matrices, cert, results, system, opts.xhat0)
