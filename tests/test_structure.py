"""Ranks, invariant zeros and ``uiofmu check --json`` on systems whose zeros are known by hand."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.linalg as sla

from uiofmu.structure import invariant_zeros, rank, uncontrollable_modes, unobservable_modes


def pencil_min_sv(A, E, C, z):
    n, q, p = A.shape[0], E.shape[1], C.shape[0]
    S = np.block([[A - z * np.eye(n), E], [C, np.zeros((p, q))]])
    return np.linalg.svd(S if S.shape[0] >= S.shape[1] else S.T, compute_uv=False)[-1]


def assert_same_set(got, ref, atol=1e-8):
    """Compare two multisets of complex numbers (order-free)."""
    got, ref = list(np.asarray(got)), list(np.asarray(ref))
    assert len(got) == len(ref), (got, ref)
    for v in got:
        i = int(np.argmin([abs(v - r) for r in ref]))
        assert abs(v - ref[i]) < atol * max(1.0, abs(v)), (v, ref)
        ref.pop(i)


def test_rank_rule():
    assert rank(np.array([[1.0, 2.0], [2.0, 4.0]])) == 1
    assert rank(np.zeros((2, 0))) == 0
    assert rank(np.diag([1.0, 1e-12])) == 1
    assert rank(np.diag([1.0, 1e-6])) == 2


def test_siso_zero_by_hand():
    # G(s) = (s + 3) / (s^2 + 3 s + 2): companion form, numerator from C = [3, 1].
    A = np.array([[0.0, 1.0], [-2.0, -3.0]])
    E = np.array([[0.0], [1.0]])
    z = invariant_zeros(A, E, np.array([[3.0, 1.0]]))
    np.testing.assert_allclose(z, [-3.0], atol=1e-12)
    assert invariant_zeros(A, E, np.array([[1.0, 0.0]])).size == 0  # G = 1/(...): no zero


def test_tall_system_zero_by_hand():
    # d enters x1; x1, x2 measured; x3 drives x1 but d can cancel it: zero at a3 = 0.7.
    A = np.array([[0.5, 0.0, 1.0], [1.0, 0.2, 0.0], [0.0, 0.0, 0.7]])
    E = np.array([[1.0], [0.0], [0.0]])
    C = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    z = invariant_zeros(A, E, C)
    np.testing.assert_allclose(z, [0.7], atol=1e-12)
    assert pencil_min_sv(A, E, C, 0.7) < 1e-12
    assert pencil_min_sv(A, E, C, 0.3) > 1e-3


@pytest.mark.parametrize("seed", range(5))
def test_tall_random_systems_have_no_zeros(seed):
    rng = np.random.default_rng(seed)
    A, E, C = rng.normal(size=(4, 4)), rng.normal(size=(4, 1)), rng.normal(size=(2, 4))
    assert invariant_zeros(A, E, C).size == 0


@pytest.mark.parametrize("seed", range(5))
def test_square_zeros_match_generalized_eigenvalues(seed):
    rng = np.random.default_rng(100 + seed)
    n, q = 5, 2
    A, E, C, D = rng.normal(size=(n, n)), rng.normal(size=(n, q)), rng.normal(size=(q, n)), rng.normal(size=(q, q))
    for DD in (np.zeros((q, q)), D):
        Mp = np.block([[A, E], [C, DD]])
        Np = np.block([[np.eye(n), np.zeros((n, q))], [np.zeros((q, n + q))]])
        ref = sla.eigvals(Mp, Np)
        assert_same_set(invariant_zeros(A, E, C, DD), ref[np.isfinite(ref)])


@pytest.mark.parametrize("seed", range(3))
def test_wide_pencil_zeros_are_rank_drops(seed):
    """Tall-output systems built with a known zero: every computed zero drops the pencil's rank."""
    rng = np.random.default_rng(7 + seed)
    # x4 evolves alone at 0.4 and is not measured; d can cancel its effect on x1: a zero at 0.4.
    A = rng.normal(size=(4, 4)) * 0.3
    A[3, :3] = 0.0
    A[3, 3] = 0.4
    A[1:3, 3] = 0.0          # x4 reaches only x1, where d can cancel it
    E = np.zeros((4, 1))
    E[0, 0] = 1.0
    C = np.hstack([rng.normal(size=(3, 3)), np.zeros((3, 1))])
    z = invariant_zeros(A, E, C)
    assert any(abs(v - 0.4) < 1e-10 for v in z)
    for v in z:
        assert pencil_min_sv(A, E, C, v) < 1e-9


def test_modes():
    A = np.diag([0.5, 0.9])
    np.testing.assert_allclose(uncontrollable_modes(A, np.array([[1.0], [0.0]])), [0.9])
    np.testing.assert_allclose(unobservable_modes(A, np.array([[1.0, 0.0]])), [0.9])
    assert uncontrollable_modes(A, np.eye(2)).size == 0


def _problem(tmp_path, A, E, C, decay='"max"'):
    text = (f'[plant]\ntime = "discrete"\ndt = 1.0\nA = {A}\nE = {E}\nC = {C}\n'
            f'[observer]\nfamily = "lti-uio"\ndecay = {decay}\n')
    path = tmp_path / "p.toml"
    path.write_text(text)
    return path


def test_check_json_tall_system(tmp_path, cli):
    path = _problem(tmp_path, "[[0.5, 0.0, 1.0], [1.0, 0.2, 0.0], [0.0, 0.0, 0.7]]", "[[1.0], [0.0], [0.0]]",
                    "[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]")
    res = cli("check", path, "--json")
    assert res.code == 0, res.err
    data = json.loads(res.out)
    assert data["exists"] is True and data["family"] == "lti-uio"
    conds = {c["name"]: c for c in data["conditions"]}
    assert conds["rank(CE) = rank(E)"]["values"] == {"rank_CE": 1, "rank_E": 1}
    np.testing.assert_allclose(conds["stable invariant zeros"]["values"]["moduli"], [0.7], atol=1e-12)
    np.testing.assert_allclose(conds["detectable decoupled pair"]["values"]["fixed_modes"], [[0.7, 0.0]], atol=1e-12)


def test_check_unstable_zero_exits_2(tmp_path, cli):
    path = _problem(tmp_path, "[[0.5, 0.0, 1.0], [1.0, 0.2, 0.0], [0.0, 0.0, 1.2]]", "[[1.0], [0.0], [0.0]]",
                    "[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]")
    res = cli("check", path, "--json")
    assert res.code == 2
    data = json.loads(res.out)
    assert data["exists"] is False
    assert "not all |z| < 1 (largest modulus 1.2)" in res.err
    assert "not detectable" in res.err


def test_check_rank_failure_json(tmp_path, cli):
    path = _problem(tmp_path, "[[0.5, 1.0], [0.0, 0.2]]", "[[0.0], [1.0]]", "[[1.0, 0.0]]")
    res = cli("check", path, "--json")
    assert res.code == 2 and "rank(CE) = 0 < rank(E) = 1" in res.err
    data = json.loads(res.out)
    assert data["conditions"][0] == {"name": "rank(CE) = rank(E)", "holds": False, "required": True,
                                     "message": "rank(CE) = 0 < rank(E) = 1: the unknown input cannot be decoupled",
                                     "values": {"rank_CE": 0, "rank_E": 1},
                                     # measuring the state E drives makes CE of full rank (C = [0, 1]: CE = 1)
                                     "hint": "measuring x[2] (adding the row e_2' to C): rank(CE) = 1 = rank(E), "
                                             "and every condition of exact decoupling holds"}


def test_seed000_example2_zeros_from_printed_data():
    """Seed 000 claims zeros 0.995 and 0.999; the printed four-digit data gives one unstable zero."""
    A = np.array([[0.5, -0.3847, 0.7036], [0.0, 0.7, 0.5468], [0.0, 0.0, -0.8]])
    E = np.array([[0.0], [0.0], [2.0]])
    C = np.array([[-0.3518, -0.2734, 0.5]])
    z = np.sort(invariant_zeros(A, E, C).real)
    np.testing.assert_allclose(z, [0.99317029, 1.00087291], atol=1e-7)
