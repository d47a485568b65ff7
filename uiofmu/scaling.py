"""State scaling of an LMI design: the same LMIs in better-conditioned coordinates.

A plant whose states differ in scale by orders of magnitude (a position in m next to a
current in mA) gives LMIs whose variables differ as much; CLARABEL's tolerance is relative to
the largest of them, so the small ones lose their digits. A diagonal change of coordinates
``x = T xs``, ``T = diag(t)``, fixes that without changing the problem: the design LMIs are
written for ``(T^-1 A T, T^-1 E, T^-1 B, C T)`` and their variables mapped back by congruence,

    X = T^-T Xs T^-1        (Lyapunov matrices)
    W = T^-T Ws             (products X K, whose gain K = T Ks maps back by itself)

which turns each LMI of the scaled coordinates into the same LMI of the plant's coordinates,
pre- and post-multiplied by ``diag(T^-T, ...)`` and its transpose: feasible in one set of
coordinates exactly when feasible in the other. Only the normalisation (``Xs >= I`` becomes
``X >= T^-T T^-1``) and the numbers the solver sees change. The card's matrices are always in
the plant's coordinates, and the certificate is re-checked there.

``t`` is the diagonal balancing of ``A`` (the scaling of LAPACK's ``gebal``, which MATLAB's
``balance`` uses): powers of two, so the scaling itself is exact in floating point, divided by
the largest so that 1 is the largest entry. A plant whose rows and columns are already
balanced gets ``t = 1`` and the design it had without scaling.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

#: The values of ``observer.scaling``: balance the states (default), or design as given.
SCALINGS = ("balance", "none")


def state_scaling(A, kind: str = "balance") -> np.ndarray:
    """The diagonal ``t`` of the state scaling ``x = diag(t) xs`` for a plant matrix ``A``.

    Parameters
    ----------
    A : (n, n) array
        The plant's state matrix (continuous or discrete).
    kind : {"balance", "none"}
        ``"none"`` gives ones.

    Returns
    -------
    (n,) numpy.ndarray
        Powers of two, the largest 1.
    """
    A = np.asarray(A, dtype=float)
    if kind == "none" or A.size == 0 or not np.all(np.isfinite(A)):
        return np.ones(A.shape[0])
    from scipy.linalg import matrix_balance

    _, (t, _) = matrix_balance(A, permute=False, separate=True)
    return np.asarray(t, dtype=float) / float(np.max(t))


def scaled_step(sample, t):
    """A sampled plant (:class:`uiofmu.plant.Sampled`) in the scaled coordinates:
    ``T^-1 A T``, ``T^-1 B``, ``T^-1 E``, ``T^-1 w``."""
    t = np.asarray(t, dtype=float)
    return replace(sample, A=sample.A * t[None, :] / t[:, None], B=sample.B / t[:, None],
                   E=sample.E / t[:, None], w=sample.w / t)


def scaled_output(C, t):
    """``C T``: the output matrix in the scaled coordinates."""
    return np.asarray(C, dtype=float) * np.asarray(t, dtype=float)[None, :]


def lyapunov_back(Xs, t):
    """``T^-T Xs T^-1`` (a Lyapunov matrix of the scaled coordinates in the plant's)."""
    t = np.asarray(t, dtype=float)
    return np.asarray(Xs, dtype=float) / np.outer(t, t)


def product_back(Ws, t):
    """``T^-T Ws`` (a product ``X K`` of the scaled coordinates in the plant's)."""
    t = np.asarray(t, dtype=float)
    return np.asarray(Ws, dtype=float) / t[:, None]


def to_data(t, kind: str) -> dict:
    """The card's record of the scaling used (``observer.scaling`` and the diagonal of ``T``)."""
    return {"kind": kind, "state": np.asarray(t, dtype=float).tolist(),
            "rule": "the LMIs were solved in the coordinates xs = diag(state)^-1 x; the matrices are "
                    "in the plant's coordinates"}
