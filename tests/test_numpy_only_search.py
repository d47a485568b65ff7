"""The numpy-only replacements of two scipy.optimize routines agree with them: the least-cost matching
(:mod:`uiofmu.matching`) finds an assignment as cheap as ``linear_sum_assignment``'s, and the bounded
search (:mod:`uiofmu.scalar_search`) the same least value as ``minimize_scalar(method="bounded")``."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment, minimize_scalar

from uiofmu.matching import least_cost_matching
from uiofmu.noise import hinf_norm
from uiofmu.scalar_search import bounded_minimum


@pytest.mark.parametrize("seed", range(5))
def test_matching_is_as_cheap_as_scipys(seed):
    rng = np.random.default_rng(seed)
    for n in range(0, 13):
        values = rng.normal(size=n) + 1j * rng.normal(size=n)
        claimed = values[rng.permutation(n)] + 1e-6 * rng.normal(size=n)
        for cost in (np.abs(claimed[:, None] - values[None, :]), rng.integers(0, 3, size=(n, n)).astype(float)):
            rows, cols = least_cost_matching(cost)
            assert sorted(cols.tolist()) == list(range(n)) and rows.tolist() == list(range(n))
            r, c = linear_sum_assignment(cost)
            assert cost[rows, cols].sum() == pytest.approx(cost[r, c].sum(), rel=1e-12, abs=1e-15)


def test_matching_pairs_eigenvalues_listed_in_another_order():
    values = np.array([0.9, 0.5 + 0.1j, 0.5 - 0.1j, -0.2])
    listed = values[[2, 0, 3, 1]]
    rows, cols = least_cost_matching(np.abs(listed[:, None] - values[None, :]))
    assert np.array_equal(values[cols], listed)


def test_matching_refuses_what_it_cannot_match():
    with pytest.raises(ValueError, match="square"):
        least_cost_matching(np.zeros((2, 3)))
    with pytest.raises(ValueError, match="finite"):
        least_cost_matching([[0.0, math.inf], [1.0, 0.0]])


def test_bounded_search_finds_scipys_least_value():
    rng = np.random.default_rng(0)
    for _ in range(200):
        centre, width, wave = rng.uniform(0.1, 0.9), rng.uniform(1e-3, 5e-2), rng.uniform(0.0, 1.0)

        def f(x):
            return -1.0 / ((x - centre) ** 2 + width) - wave * math.sin(3.0 * x)

        lo, hi = centre - rng.uniform(0.01, 0.3), centre + rng.uniform(0.01, 0.3)
        x, fx = bounded_minimum(f, lo, hi, xatol=1e-12)
        ref = minimize_scalar(f, bounds=(lo, hi), method="bounded", options={"xatol": 1e-12})
        assert lo <= x <= hi and fx == f(x)
        assert fx == pytest.approx(ref.fun, rel=1e-14)


def test_bounded_search_stops_at_an_end_for_a_monotone_function():
    """It ends within twice its tolerance (sqrt(eps) |x| + xatol / 3) of the end, as scipy's does."""
    x, fx = bounded_minimum(lambda t: t, 2.0, 3.0, xatol=1e-9)
    tol = math.sqrt(2.0 ** -52) * 2.0 + 1e-9 / 3
    assert 2.0 <= x <= 2.0 + 2 * tol
    ref = minimize_scalar(lambda t: t, bounds=(2.0, 3.0), method="bounded", options={"xatol": 1e-9})
    assert abs(x - ref.x) < tol


def test_hinf_norm_of_a_first_order_system():
    """|C (z - a)^-1 B + D| peaks at z = 1 for a > 0: 1 / (1 - a) with B = C = 1, D = 0."""
    for a in (0.5, 0.9, 0.99):
        assert hinf_norm([[a]], [[1.0]], [[1.0]], [[0.0]]) == pytest.approx(1.0 / (1.0 - a), rel=1e-12)
    # the peak between grid points: a lightly damped pair at an angle the sweep does not hit
    r, angle = 0.995, 1.0001
    A = r * np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    B, C, D = np.array([[1.0], [0.0]]), np.array([[0.0, 1.0]]), np.zeros((1, 1))
    w = np.linspace(angle - 0.01, angle + 0.01, 200001)
    dense = max(abs((C @ np.linalg.solve(np.exp(1j * t) * np.eye(2) - A, B) + D)[0, 0]) for t in w[::50])
    assert hinf_norm(A, B, C, D) >= dense * (1 - 1e-9)
