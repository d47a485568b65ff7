"""Structural analysis of linear systems: ranks, uncontrollable modes, invariant zeros.

Everything here uses orthogonal transformations (SVD) and one rank rule,
:func:`rank`, whose tolerance is documented in :mod:`uiofmu.runtime.tolerances`.
"""

from __future__ import annotations

import numpy as np

from .runtime.tolerances import RANK_RTOL
from .threads import blas_module


def _count_above(s: np.ndarray, rank_rtol: float) -> int:
    """The rank rule on singular values ``s`` (descending): those above ``rank_rtol * max(1, s_max)``."""
    return int(np.sum(s > rank_rtol * max(1.0, s[0]))) if s.size else 0


def rank(M: np.ndarray, rank_rtol: float = RANK_RTOL) -> int:
    """Numerical rank: singular values above ``rank_rtol * max(1, s_max)``.

    Parameters
    ----------
    M : array_like
        Any matrix (an empty one has rank 0).
    rank_rtol : float
        Relative tolerance (default :data:`~uiofmu.runtime.tolerances.RANK_RTOL`).

    Returns
    -------
    int

    Examples
    --------
    >>> rank(np.array([[1.0, 2.0], [2.0, 4.0]]))
    1
    """
    M = np.atleast_2d(np.asarray(M, dtype=float))
    if M.size == 0:
        return 0
    return _count_above(np.linalg.svd(M, compute_uv=False), rank_rtol)


def _range_split(M: np.ndarray, rank_rtol: float) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal bases of the column range of ``M`` (n x r) and of its orthogonal
    complement (n x (n - r)), from one SVD."""
    if M.size == 0:
        return np.zeros((M.shape[0], 0)), np.eye(M.shape[0])
    U, s, _ = np.linalg.svd(M, full_matrices=True)
    r = _count_above(s, rank_rtol)
    return U[:, :r], U[:, r:]


def uncontrollable_modes(A: np.ndarray, B: np.ndarray, rank_rtol: float = RANK_RTOL) -> np.ndarray:
    """Eigenvalues of ``A`` that no input through ``B`` can move.

    The controllable subspace is grown by orthonormal bases (``K <- orth([K, A K])``);
    the uncontrollable modes are the eigenvalues of ``A`` on its orthogonal complement.

    Parameters
    ----------
    A : (n, n) array
    B : (n, m) array
    rank_rtol : float
        Rank tolerance.

    Returns
    -------
    numpy.ndarray
        The uncontrollable modes (complex), sorted by decreasing modulus.
    """
    _, Q = controllable_split(A, B, rank_rtol)
    if not Q.shape[1]:
        return np.zeros(0, dtype=complex)
    modes = np.linalg.eigvals(Q.T @ A @ Q)
    return modes[np.argsort(-np.abs(modes), kind="stable")]


def controllable_split(A: np.ndarray, B: np.ndarray, rank_rtol: float = RANK_RTOL) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal bases of the controllable subspace of ``(A, B)`` and of its complement.

    The subspace is grown by orthonormal bases (``K <- orth([K, A K])``) from the range of ``B``.

    Parameters
    ----------
    A : (n, n) array
    B : (n, m) array
    rank_rtol : float
        Rank tolerance.

    Returns
    -------
    K : (n, r) array
        The controllable subspace (``A K`` stays in its span, ``B`` lies in it).
    Q : (n, n - r) array
        Its orthogonal complement.
    """
    K, Q = _range_split(B, rank_rtol)
    while 0 < K.shape[1] < A.shape[0]:
        grown, complement = _range_split(np.hstack([K, A @ K]), rank_rtol)
        if grown.shape[1] == K.shape[1]:
            break
        K, Q = grown, complement
    return K, Q


def decay_gain(A: np.ndarray, C: np.ndarray, rho: float) -> np.ndarray:
    """An output-injection gain ``K`` with every mode of ``A - K C`` inside ``rho``, without a solver.

    ``K = rho L`` with ``L`` the steady-state Kalman gain of the scaled pair ``(A / rho, C)``
    (unit noise covariances), from the discrete algebraic Riccati equation: ``A/rho - L C`` is
    then Schur, i.e. ``A - K C`` decays faster than ``rho``, whenever the modes ``C`` does not see
    are inside ``rho``. Modes already well inside ``rho`` are moved little, so the gains stay as
    small as the decay allows (weakly observable modes still need large ones).

    Parameters
    ----------
    A : (n, n) array
        A discrete-time state matrix.
    C : (p, n) array
    rho : float
        The decay to beat, in (0, 1].

    Returns
    -------
    (n, p) array

    Raises
    ------
    numpy.linalg.LinAlgError, ValueError
        When the Riccati equation has no stabilising solution (a mode ``C`` does not see is
        not inside ``rho``).
    """
    solve_discrete_are = blas_module("scipy.linalg").solve_discrete_are

    n, p = C.shape[1], C.shape[0]
    As = A / rho
    P = solve_discrete_are(As.T, C.T, np.eye(n), np.eye(p))
    return rho * np.linalg.solve(C @ P @ C.T + np.eye(p), C @ P @ As.T).T


def unobservable_modes(A: np.ndarray, C: np.ndarray, rank_rtol: float = RANK_RTOL) -> np.ndarray:
    """Eigenvalues of ``A`` not seen through ``C`` (dual of :func:`uncontrollable_modes`)."""
    return uncontrollable_modes(A.T, C.T, rank_rtol)


def pbh_margins(A: np.ndarray, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How well each mode of ``A`` is seen through ``C``: the PBH observability margins.

    ``m(lambda) = sigma_min([lambda I - A; C]) / max(||A||, ||C||)`` for each eigenvalue: 0 for a
    mode ``C`` does not see, small for a mode that output injection moves only with large gains
    (of the order of ``1 / m``).

    Parameters
    ----------
    A : (n, n) array
    C : (p, n) array

    Returns
    -------
    modes : (n,) complex array
        The eigenvalues of ``A``.
    margins : (n,) array
        Their relative PBH margins.
    """
    modes = np.linalg.eigvals(A)
    n = A.shape[0]
    scale = max(float(np.linalg.norm(A, 2)), float(np.linalg.norm(C, 2)), 1e-300)
    if not n:
        return modes, np.zeros(0)
    # One stacked SVD of [lambda I - A; C] for every mode: numpy runs the same LAPACK call on each matrix of a
    # stack as on the matrix alone, so each margin is the one a call per mode finds, to the last bit.
    pencils = np.concatenate([modes[:, None, None] * np.eye(n) - A, np.broadcast_to(C.astype(complex),
                                                                                   (n,) + C.shape)], axis=1)
    margins = np.linalg.svd(pencils, compute_uv=False)[:, -1] / scale
    return modes, margins


def invariant_zeros(A: np.ndarray, E: np.ndarray, C: np.ndarray, D: np.ndarray | None = None,
                    rank_rtol: float = RANK_RTOL) -> np.ndarray:
    """Invariant zeros of ``(A, E, C, D)``: where the Rosenbrock pencil loses its normal rank.

    The pencil ``[[A - zI, E], [C, D]]`` may be non-square. It is reduced by constant
    orthogonal transformations that keep its finite zeros (no random squaring-down):

    1. Split the inputs so that ``D = [D1 0]`` with ``D1`` of full column rank. The inputs
       of ``D1`` are fixed by the outputs (``u1 = -D1^+ C x``), which leaves the system
       ``(A - E1 D1^+ C, E2, C2, 0)`` with ``C2 = (I - D1 D1^+) C`` compressed to its rank.
    2. With ``D = 0`` the state must lie in ``ker C2``: with ``W`` an orthonormal basis of
       that kernel and ``W_perp`` one of its complement, the rows along ``W`` keep ``z``
       and the rows along ``W_perp`` do not, giving the smaller system
       ``(W' A W, W' E2, W_perp' A W, W_perp' E2)``. Repeat from 1.
    3. When no output constraint is left, the zeros are the uncontrollable modes of the
       remaining pair ``(A, E)``.

    Each pass removes at least one state, so the reduction ends after at most n passes.

    Parameters
    ----------
    A : (n, n) array
    E : (n, q) array
        Input matrix of the inputs whose zeros are wanted (the unknown inputs here).
    C : (p, n) array
    D : (p, q) array, optional
        Feedthrough (default zero).
    rank_rtol : float
        Rank tolerance.

    Returns
    -------
    numpy.ndarray
        The finite invariant zeros (complex), sorted by decreasing modulus.

    Examples
    --------
    With ``y = x2`` and ``d`` acting on x2, the zero is the pole of the hidden state x1:

    >>> A = np.array([[0.5, 0.0], [1.0, 0.2]])
    >>> invariant_zeros(A, np.array([[0.0], [1.0]]), np.array([[0.0, 1.0]])).real.round(6)
    array([0.5])
    """
    A = np.asarray(A, dtype=float)
    E = np.asarray(E, dtype=float)
    C = np.asarray(C, dtype=float)
    D = np.zeros((C.shape[0], E.shape[1])) if D is None else np.asarray(D, dtype=float)
    while A.shape[0] > 0:
        n = A.shape[0]
        # Step 1: D = [D1 0] with D1 of full column rank (right singular vectors).
        U, s, Vt = np.linalg.svd(D, full_matrices=True) if D.size else (None, np.zeros(0), None)
        r = _count_above(s, rank_rtol)
        if r:
            V = Vt.T
            D1 = D @ V[:, :r]
            E1, E2 = E @ V[:, :r], E @ V[:, r:]
            D1pinv = np.linalg.pinv(D1)
            A = A - E1 @ D1pinv @ C
            Uperp = U[:, r:]                       # left complement of range(D1)
            C = Uperp.T @ C
            E = E2
        # Compress C to its row rank; step 2: x in ker C, x = W xi.
        Wp, W = _range_split(C.T, rank_rtol)
        if Wp.shape[1] == 0:
            return uncontrollable_modes(A, E, rank_rtol) if n else np.zeros(0, dtype=complex)
        if W.shape[1] == 0:
            return np.zeros(0, dtype=complex)
        A, E, C, D = W.T @ A @ W, W.T @ E, Wp.T @ A @ W, Wp.T @ E
    return np.zeros(0, dtype=complex)


def is_stable(values: np.ndarray, continuous: bool, margin: float = 0.0) -> bool:
    """True when every value is in the open left half-plane (continuous) or unit disc (discrete)."""
    values = np.asarray(values)
    if values.size == 0:
        return True
    if continuous:
        return bool(np.all(values.real < -margin))
    return bool(np.all(np.abs(values) < 1.0 - margin))


def product_radius(maps, max_length: int = 3, max_products: int = 4096) -> tuple[float, tuple]:
    """A lower bound on the joint spectral radius of ``maps``: the largest
    ``rho(F_{i_L} ... F_{i_1}) ** (1 / L)`` over every product of length ``L <= max_length``.

    Under arbitrary switching among the maps no quadratic (or other) certificate contracts
    faster than the joint spectral radius, so this bounds every certified decay from below,
    and a value of 1 or more proves that some switching sequence does not converge.

    Parameters
    ----------
    maps : sequence of (m, m) arrays
    max_length : int
        Longest product tried.
    max_products : int
        A length with more products than this (``N ** L``) is not tried.

    Returns
    -------
    radius : float
        The bound (0.0 for maps of size 0).
    sequence : tuple of int
        The indices ``(i_1, ..., i_L)`` of the product that attains it, in the order applied.
    """
    F = np.asarray(maps, dtype=float)
    N, m = F.shape[0], F.shape[1]
    best, seq = 0.0, (0,)
    if m == 0:
        return 0.0, ()
    products = F
    for length in range(1, max_length + 1):          # every product F_{i_L} ... F_{i_1}, all at once
        if length > 1:
            if N ** length > max_products:
                break
            products = (F[:, None] @ products[None]).reshape(-1, m, m)
        radius = np.abs(np.linalg.eigvals(products)).max(axis=-1) ** (1.0 / length)
        top = float(radius.max())
        if top > best * (1 + 1e-9):
            # the rotations of a cycle have one radius, equal up to rounding: name the first of them in
            # index order, so that the same sequence is named under every BLAS kernel
            ties = np.flatnonzero(radius >= top * (1 - 1e-9))
            best = top
            seq = min(tuple(int(i) for i in reversed(np.unravel_index(int(k), (N,) * length))) for k in ties)
    return best, tuple(int(i) for i in seq)


def kernel_maps(matrices, C: np.ndarray) -> list:
    """The maps ``V' M_i V`` on ``ker C`` (``V`` an orthonormal basis) of matrices that leave
    ``ker C`` invariant: with as many outputs as unknown inputs, the error of an exactly decoupling
    observer there evolves by these whatever its gains."""
    p = C.shape[0]
    basis = np.linalg.svd(C)[2][p:].T
    return [basis.T @ M @ basis for M in matrices]
