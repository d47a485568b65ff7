"""Functional unknown-input observers (:mod:`uiofmu.functional_uio`) on seeded random plants: the decoupling and
matching identities at rounding level, the decay certified and re-checked, ``zhat - L x`` within the certified
bound whatever the unknown input, the least order found below ``n`` where one exists, and bad functionals refused."""

import tomllib

import numpy as np
import pytest

from tests.conftest import EXAMPLES
from uiofmu import functional_uio as fu
from uiofmu.problem import to_toml
from uiofmu.runtime.errors import ProblemError


def _plant(seed, n, p, q, r):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    A /= 1.2 * np.max(np.abs(np.linalg.eigvals(A)))
    return (A, rng.normal(size=(n, 1)), rng.normal(size=(p, n)), rng.normal(size=(n, q)), rng.normal(size=(r, n)))


def _simulate(design, A, B, C, E, L, seed, steps=80):
    """Largest ``||zhat_k - L x_k|| - bound_k`` over a run with a large unknown input (rounding excepted)."""
    rng = np.random.default_rng(seed + 1000)
    x, z = 3.0 * rng.normal(size=A.shape[0]), np.zeros(design.order)
    e0 = float(np.linalg.norm(z - design.T @ x))
    worst, last = -np.inf, None
    for k in range(steps):
        u, d = rng.normal(size=B.shape[1]), 10.0 * np.sin(0.3 * k) + rng.normal(size=E.shape[1])
        y = C @ x
        err = float(np.linalg.norm(design.R @ z + design.Q @ y - L @ x))
        slack = 1e-9 * max(1.0, float(np.linalg.norm(x)))
        worst = max(worst, err - float(design.bound(e0, k)) - slack)
        last = err
        z = design.N @ z + design.J @ y + design.H @ u
        x = A @ x + B @ u + E @ d
    return worst, last


SHAPES = [(5, 3, 1, 1), (5, 2, 1, 1), (4, 2, 1, 1), (4, 2, 1, 2), (5, 3, 2, 2)]


@pytest.mark.parametrize("shape", SHAPES)
def test_random_plants_decouple_decay_and_converge(shape):
    designed = 0
    for seed in range(6):
        A, B, C, E, L = _plant(seed, *shape)
        try:
            design = fu.design(A, B, C, E, L, 0.6)
        except ProblemError as err:
            assert "no functional unknown-input observer" in str(err)
            continue
        designed += 1
        checks = fu.checks(design, A, B, C, E, L)
        assert all(c.holds for c in checks), [c.explain() for c in checks if not c.holds]
        assert np.max(np.abs(design.T @ E)) < 1e-12 * max(1.0, np.linalg.norm(design.T) * np.linalg.norm(E))
        assert np.max(np.abs(np.linalg.eigvals(design.N))) < design.rho
        assert shape[3] <= design.order <= shape[0]
        worst, last = _simulate(design, A, B, C, E, L, seed)
        assert worst <= 0.0 and last < 1e-8
    assert designed >= 3


def test_least_order_below_n():
    A, B, C, E, L = _plant(0, 5, 2, 1, 1)
    design = fu.design(A, B, C, E, L, 0.5)
    assert design.order < 5
    failed = [c for c in design.conditions if not c.holds]
    assert failed and "rank [LPA; LP; Pi C A; C] = 5 > rank [LP; Pi C A; C] = 4" in failed[0].message
    A, B, C, E, L = _plant(0, 5, 3, 1, 1)
    assert fu.design(A, B, C, E, L, 0.5).order == 1


def test_order_n_when_the_functionals_span_the_state():
    A, B, C, E, L = _plant(3, 4, 2, 1, 4)
    design = fu.design(A, B, C, E, L, 0.6)
    assert design.order == 4
    assert all(c.holds for c in fu.checks(design, A, B, C, E, L))
    assert _simulate(design, A, B, C, E, L, 3)[0] <= 0.0


def test_hand_edited_design_fails_the_recheck():
    A, B, C, E, L = _plant(1, 5, 2, 1, 1)
    design = fu.design(A, B, C, E, L, 0.6)
    edited = fu.FunctionalDesign(**{**design.__dict__, "J": design.J + 1e-3})
    assert not all(c.holds for c in fu.checks(edited, A, B, C, E, L))
    slow = fu.FunctionalDesign(**{**design.__dict__, "N": design.N * 2.0})
    names = [c.name for c in fu.checks(slow, A, B, C, E, L) if not c.holds]
    assert "rho^2 X - N'XN > 0" in names


def test_no_observer_is_refused_with_its_numbers():
    for seed in range(20):
        A, B, C, E, L = _plant(seed, 3, 1, 1, 1)
        try:
            fu.design(A, B, C, E, L, 0.5)
        except ProblemError as err:
            assert "order 1:" in str(err) and "fixed mode" in str(err)
            return
    pytest.fail("no refused plant among the seeds")


@pytest.mark.parametrize("raw, needle", [
    ([[1.0, 2.0]], "expected a row of 3 numbers"),
    ([[1.0, float("nan"), 0.0]], "non-finite"),
    ([[0.0, 0.0, 0.0]], "a row of zeros"),
    ([], "expected a list"),
    ("x", "expected a list"),
    ([[1.0, True, 0.0]], "must be a number"),
])
def test_bad_functionals_are_refused(raw, needle):
    with pytest.raises(ProblemError, match=needle):
        fu.parse_functional(raw, 3)


def test_good_functional_is_read():
    assert fu.parse_functional([[1, 0, 0], [0, 1.5, 2]], 3).shape == (2, 3)


FUNCTIONAL = EXAMPLES / "functional_uio.toml"


def test_example_check_reports_order_three(cli):
    res = cli("check", FUNCTIONAL)
    assert res.code == 0, res.err
    for line in ("order 1: rank [LPA; LP; Pi C A; C] = 5 > rank [LP; Pi C A; C] = 4",
                 "order 2: largest fixed mode of the functional error |0.933354| >= decay 0.6",
                 "functional observer of order 3 (searched 1..5)"):
        assert line in res.out
    doc = tomllib.loads(FUNCTIONAL.read_text(encoding="utf-8"))
    p = doc["plant"]
    A, B, C, E = (np.array(p[k], dtype=float) for k in "ABCE")
    L = np.array(doc["observer"]["functional"], dtype=float)
    design = fu.design(A, B, C, E, L, doc["observer"]["decay"])
    assert design.order == 3 and all(c.holds for c in fu.checks(design, A, B, C, E, L))


def test_design_refuses_the_functional_observer(cli, tmp_path):
    res = cli("design", FUNCTIONAL, "-o", tmp_path / "card.json")
    assert res.code == 2 and "observer.functional" in res.err and "no card or FMU" in res.err


@pytest.mark.parametrize("edit, needle", [
    ({"observer": {"poles": [0.1, 0.2]}}, "observer.poles"),
    ({"observer": {"noise": "min"}}, "observer.noise"),
    ({"observer": {"functional": [[1.0, 2.0]]}}, "expected a row of 5 numbers"),
    ({"observer": {"functional": [[0, 0, 0, 0, 0]]}}, "a row of zeros"),
    ({"plant": {"F": [[1.0], [0.0]]}}, "plant.F"),
])
def test_unsupported_options_are_refused(cli, tmp_path, edit, needle):
    doc = tomllib.loads(FUNCTIONAL.read_text(encoding="utf-8"))
    for table, values in edit.items():
        doc[table].update(values)
    path = tmp_path / "p.toml"
    path.write_text(to_toml(doc), encoding="utf-8")
    res = cli("check", path)
    assert res.code == 2 and needle in res.err, res.err
