"""The least value of a function of one variable on an interval: Brent's method, numpy-free.

Kept for a bounded scalar search that loads no optimiser (it agrees with ``scipy.optimize.minimize_scalar``).
"""

from __future__ import annotations

import math

#: The fraction of an interval a golden-section step moves into its larger part: (3 - sqrt 5) / 2.
GOLDEN = 0.5 * (3.0 - math.sqrt(5.0))

#: Relative resolution of the abscissa (the square root of the double precision's epsilon).
RELATIVE = math.sqrt(2.0 ** -52)


def bounded_minimum(f, lo: float, hi: float, xatol: float = 1e-5, maxiter: int = 500) -> tuple[float, float]:
    """A local minimum of ``f`` on ``[lo, hi]`` and its value (Brent 1973, golden sections and parabolas).

    Each step fits a parabola through the three best points and moves to its vertex when that falls
    well inside the bracket and moves less than half the step before last; otherwise it takes a golden
    section of the bracket's larger part. No point closer than the tolerance to one already evaluated or
    to the ends is evaluated.

    Parameters
    ----------
    f : callable
        ``f(x) -> float``.
    lo, hi : float
        The interval, ``lo < hi``.
    xatol : float, optional
        Absolute tolerance on the abscissa; the search ends when the bracket around the best point is
        within ``2 tol`` of it, ``tol = sqrt(eps) |x| + xatol / 3``.
    maxiter : int, optional
        Most evaluations of ``f`` after the first.

    Returns
    -------
    x, fx : float
        The best point found and ``f(x)``.

    Examples
    --------
    >>> x, fx = bounded_minimum(lambda t: (t - 0.3) ** 2, 0.0, 1.0, xatol=1e-10)
    >>> round(x, 8), round(fx, 12)
    (0.3, 0.0)
    """
    a, b = float(lo), float(hi)
    x = w = v = a + GOLDEN * (b - a)
    fx = fw = fv = float(f(x))
    step = last = 0.0                     # the step just taken and the one before it
    for _ in range(maxiter):
        middle = 0.5 * (a + b)
        tol = RELATIVE * abs(x) + xatol / 3.0
        if abs(x - middle) <= 2.0 * tol - 0.5 * (b - a):
            break
        golden = True
        if abs(last) > tol:               # try the vertex of the parabola through (x, w, v)
            r = (x - w) * (fx - fv)
            q = (x - v) * (fx - fw)
            p = (x - v) * q - (x - w) * r
            q = 2.0 * (q - r)
            if q > 0.0:
                p = -p
            q = abs(q)
            before, last = last, step
            if abs(p) < abs(0.5 * q * before) and q * (a - x) < p < q * (b - x):
                step = p / q
                if (x + step) - a < 2.0 * tol or b - (x + step) < 2.0 * tol:
                    step = tol if x < middle else -tol
                golden = False
        if golden:
            last = (b - x) if x < middle else (a - x)
            step = GOLDEN * last
        u = x + (step if abs(step) >= tol else math.copysign(tol, step))
        fu = float(f(u))
        if fu <= fx:
            if u < x:
                b = x
            else:
                a = x
            v, fv, w, fw, x, fx = w, fw, x, fx, u, fu
        else:
            if u < x:
                a = u
            else:
                b = u
            if fu <= fw or w == x:
                v, fv, w, fw = w, fw, u, fu
            elif fu <= fv or v == x or v == w:
                v, fv = u, fu
    return x, fx


__all__ = ["GOLDEN", "RELATIVE", "bounded_minimum"]
