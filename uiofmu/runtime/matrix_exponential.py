"""The matrix exponential of the plant runtimes (numpy only): the algorithm of the C plant kernel.

Scaling and squaring with a Padé approximant, Higham's algorithm of 2005 ("The scaling and squaring
method for the matrix exponential revisited", SIAM J. Matrix Anal. Appl. 26(4), Algorithm 2.3): the
degree ``m`` of the diagonal approximant r_m is the least of 3, 5, 7, 9 whose bound theta_m (Table 2.3)
the 1-norm of ``M`` does not pass, else 13 after scaling ``M`` by ``2^-s`` until it is at most
theta_13; then ``exp(M) = r_m(2^-s M)^(2^s)``, with ``r_m = (V - U)^-1 (V + U)`` from the odd (``U``) and
even (``V``) parts of the numerator. ``uiofmu/fmu/c/kernel_plant.c`` (``uiofmu_expm``) is the same
algorithm with the same constants, step by step: the Python and C plants discretise alike.
"""

from __future__ import annotations

import math

import numpy as np

#: theta_m of Higham (2005), Table 2.3: the largest 1-norm for which r_m reaches double precision.
THETA = {3: 1.495585217958292e-2, 5: 2.539398330063230e-1, 7: 9.504178996162932e-1, 9: 2.097847961257068e0,
         13: 5.371920351148152e0}

#: The coefficients b_0 .. b_m of the numerator of r_m.
PADE = {
    3: (120.0, 60.0, 12.0, 1.0),
    5: (30240.0, 15120.0, 3360.0, 420.0, 30.0, 1.0),
    7: (17297280.0, 8648640.0, 1995840.0, 277200.0, 25200.0, 1512.0, 56.0, 1.0),
    9: (17643225600.0, 8821612800.0, 2075673600.0, 302702400.0, 30270240.0, 2162160.0, 110880.0, 3960.0, 90.0,
        1.0),
    13: (64764752532480000.0, 32382376266240000.0, 7771770303897600.0, 1187353796428800.0, 129060195264000.0,
         10559470521600.0, 670442572800.0, 33522128640.0, 1323241920.0, 40840800.0, 960960.0, 16380.0, 182.0, 1.0),
}

#: The most squarings: more would mean a 1-norm beyond any double's.
MAX_SQUARINGS = 2000


def degree_and_scaling(norm: float) -> tuple:
    """``(m, s)``: the Padé degree and the number of squarings for a matrix of 1-norm ``norm``."""
    for m in (3, 5, 7, 9):
        if norm <= THETA[m]:
            return m, 0
    return 13, max(0, math.ceil(math.log2(norm / THETA[13])))


def expm(M: np.ndarray) -> np.ndarray:
    """``exp(M)`` by scaling and squaring with a Padé approximant (Higham 2005).

    Parameters
    ----------
    M : (k, k) array

    Returns
    -------
    (k, k) array
        Not finite (NaN) when ``M`` is not, when its 1-norm overflows, when ``V - U`` is singular or
        when more than :data:`MAX_SQUARINGS` squarings would be needed; not finite when the
        exponential overflows.

    Examples
    --------
    >>> float(expm(np.array([[1.0]]))[0, 0]) == float(np.exp(1.0))
    True
    """
    M = np.asarray(M, dtype=float)
    k = M.shape[0]
    if not np.all(np.isfinite(M)):
        return np.full((k, k), math.nan)
    with np.errstate(over="ignore"):
        norm = float(np.abs(M).sum(axis=0).max()) if M.size else 0.0
    if not math.isfinite(norm):                    # finite entries whose sums overflow
        return np.full((k, k), math.nan)
    m, s = degree_and_scaling(norm)
    if s > MAX_SQUARINGS:
        return np.full((k, k), math.nan)
    b = PADE[m]
    A = np.ldexp(M, -s)
    eye = np.eye(k)
    A2 = A @ A
    if m == 13:
        A4 = A2 @ A2
        A6 = A4 @ A2
        V = A6 @ (b[13] * A6 + b[11] * A4 + b[9] * A2)
        V += b[7] * A6 + b[5] * A4 + b[3] * A2
        V += b[1] * eye
        U = A @ V
        V = A6 @ (b[12] * A6 + b[10] * A4 + b[8] * A2)
        V += b[6] * A6 + b[4] * A4 + b[2] * A2
        V += b[0] * eye
    else:
        powers = [A2]
        while len(powers) < m // 2:
            powers.append(powers[-1] @ A2)
        odd, V = b[1] * eye, b[0] * eye
        for j, P in enumerate(powers, start=1):
            odd = odd + b[2 * j + 1] * P
            V = V + b[2 * j] * P
        U = A @ odd
    try:
        X = np.linalg.solve(V - U, V + U)
    except np.linalg.LinAlgError:
        return np.full((k, k), math.nan)
    with np.errstate(over="ignore", invalid="ignore"):          # an overflow is the answer: not finite
        for _ in range(s):
            X = X @ X
    return X


__all__ = ["MAX_SQUARINGS", "PADE", "THETA", "degree_and_scaling", "expm"]
