"""The dead-beat functional observer (seed 003, Fiacchini-Millerioux): every deterministic number of
the paper's example, the identity on exact simulations of its nonlinear plant (17), Proposition 6,
the refusal of G = I, a plant of our own whose formula needs theta, and the window runtime."""

from __future__ import annotations

import copy

import numpy as np
import pytest

import uiofmu
from uiofmu.families.deadbeat_functional import evaluate
from uiofmu.problem import problem_from_data
from uiofmu.runtime.card import card_from_data
from uiofmu.runtime.errors import NoObserverError, ProblemError
from uiofmu.runtime.lpv import LpvPlantRuntime
from uiofmu.runtime.observer import RuntimeInputError
from uiofmu.runtime.state import StateRejected
from uiofmu.runtime.window import WindowRuntime

EXAMPLE = {
    "name": "fiacchini-millerioux-example",
    "plant": {"time": "discrete", "dt": 1.0,
              "A": [[-4.0, 1.0, 0.0], [0.0, 0.0, 1.0], [-2.0, 0.0, 0.0]],
              "E": [[0.0], [1.0], [1.0]], "C": [[1.0, 0.0, 0.0]],
              "scheduling": [{"A": [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]}],
              "theta": {"kind": "state", "T": [[3.0, 2.0, 0.0]]}},
    "observer": {"family": "deadbeat-functional", "G": [[3.0, 2.0, 0.0]]},
}

#: A plant of our own (theta an input) whose formula needs theta at two lags: r = 1, K = 2.
THETA_PLANT = {
    "name": "needs-theta",
    "plant": {"time": "discrete", "dt": 0.5,
              "A": [[-1.0, 0.0, -2.0], [1.0, 2.0, 2.0], [2.0, -2.0, -2.0]],
              "E": [[1.0], [0.0], [0.0]], "C": [[1.0, 0.0, 0.0]],
              "scheduling": [{"A": [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]}],
              "theta": {"kind": "input"}},
    "observer": {"family": "deadbeat-functional", "G": [[1.0, -2.0, 1.0]]},
}


def with_G(data, G):
    out = copy.deepcopy(data)
    out["observer"]["G"] = G
    return out


def design(data):
    return uiofmu.design(problem_from_data(copy.deepcopy(data)))


def nonlinear_17(x, u):
    """The paper's nonlinear system (17), written directly (not through the LPV matrices)."""
    x1, x2, x3 = x
    return np.array([-4 * x1 + x2, 3 * x1 ** 2 + 2 * x2 * x1 + x3 + u, -2 * x1 + u])


def test_example_numbers():
    existence = uiofmu.check(problem_from_data(copy.deepcopy(EXAMPLE)))
    assert existence.exists
    values = {c.name: c.values for c in existence.conditions}
    assert values["inherent delay"]["r"] == 2
    P = np.array(values["P decomposition (8)"]["P"])
    np.testing.assert_allclose(P[0], [[-4, 1, 0], [-16, 4, 0], [-18, 4, -1]], atol=1e-9)   # paper prints -14
    np.testing.assert_allclose(P[1], [[0, 0, 0], [0, 0, 0], [-1, 0, 0]], atol=1e-9)
    assert values["P decomposition (8)"]["monomials"] == [[], [[0, 0, 1]]]                 # rho = [1, theta_k]
    basis = np.array(values["robust invariant subspace in ker G"]["basis"])
    assert basis.shape == (1, 3) and abs(abs(basis[0, 2]) - 1) < 1e-12                     # span(e_3)
    Phat = np.array(values["robust invariant subspace in ker G"]["Phat"])
    np.testing.assert_allclose(Phat[0], [[-4, 1], [-16, 4]], atol=1e-9)           # on span(e1, e2), as printed
    np.testing.assert_allclose(Phat[1], 0, atol=1e-12)
    assert values["nilpotent semigroup"] == {"t": 2, "K": 1}
    card = design(EXAMPLE)
    assert (card.data["r"], card.data["K"], card.data["window"], card.data["delay"]) == (2, 1, 4, 1)
    F, exps = card.matrices["F"], card.matrices["Fexp"]
    assert F.shape == (1, 1, 4) and not exps.any()
    np.testing.assert_allclose(F[0, 0], [0, 0, 11, 2], atol=1e-9)        # on y_k-2, y_k-1, y_k, y_k+1
    assert card.data["formula"] == "(G x)_1 at k = 11·y_k + 2·y_k+1"
    assert all(c.holds for c in uiofmu.verify(card))


def test_the_identity_holds_on_the_nonlinear_plant_and_shifted_conventions_fail():
    card = design(EXAMPLE)
    F, exps = card.matrices["F"], card.matrices["Fexp"]
    rng = np.random.default_rng(0)
    for _ in range(50):
        xs = [rng.normal(size=3) * 0.3]
        for u in rng.uniform(-0.2, 0.2, size=8):
            xs.append(nonlinear_17(xs[-1], u))
        xs = np.array(xs)
        y = xs[:, :1]
        for k in range(2, 7):
            Gx = 3 * xs[k, 0] + 2 * xs[k, 1]
            scale = max(1.0, abs(Gx), np.abs(y[k - 2:k + 2]).max() * 13)
            got = evaluate(F, exps, y[k - 2:k + 2], np.zeros((4, 1)))
            assert abs(got - Gx) <= 1e-12 * scale
            assert abs(11 * y[k, 0] + 2 * y[k + 1, 0] - Gx) <= 1e-12 * scale
            shifted = 11 * y[k - 1, 0] + 2 * y[k, 0]
            assert abs(shifted - Gx) > 1e-3 * scale or abs(Gx) < 1e-9


def test_proposition_6_gives_K_0():
    existence = uiofmu.check(problem_from_data(with_G(EXAMPLE, [[-4.0, 1.0, 0.0]])))
    assert {c.name for c in existence.conditions} >= {"Proposition 6"}
    card = design(with_G(EXAMPLE, [[-4.0, 1.0, 0.0]]))
    assert card.data["K"] == 0
    np.testing.assert_allclose(card.matrices["F"][0, 0], [0, 0, 1], atol=1e-12)    # G x_k = y_k+1
    assert card.data["delay"] == 1


def test_full_state_is_refused_with_the_reason():
    with pytest.raises(NoObserverError, match=r"do not generate a nilpotent semigroup.*Phat_1: -1"):
        design(with_G(EXAMPLE, "identity"))


def test_a_formula_that_needs_theta_is_exact_and_the_window_runtime_equals_it():
    card = design(THETA_PLANT)
    assert card.data["schedule"]["uses_theta"] and card.matrices["Fexp"].any()
    assert (card.data["r"], card.data["K"], card.data["delay"]) == (1, 2, 0)
    assert [p["name"] for p in card.data["ports"]] == ["y", "theta", "gx", "gx_valid"]
    plant = LpvPlantRuntime(problem_from_data(copy.deepcopy(THETA_PLANT)).plant.to_data())
    rng = np.random.default_rng(1)
    plant.x0 = rng.normal(size=3)
    plant.reset()
    rt = WindowRuntime(card)
    G = np.array(THETA_PLANT["observer"]["G"])
    for k in range(40):
        plant.d[:] = rng.normal(size=1)
        plant.theta_in[:] = rng.uniform(-0.5, 0.5, size=1)
        rt.set_y(plant.y())
        rt.set_theta(plant.theta())
        assert rt.valid == (k >= card.data["window"] - 1)
        if rt.valid:
            want = G @ plant.x                         # delay 0
            assert np.abs(rt.gx() - want).max() <= 1e-9 * max(1.0, np.abs(want).max())
        else:
            assert not rt.gx().any()
        rt.step(0.5)
        plant.step(0.5)
    # without theta the formula is wrong: theta is really needed
    zero = WindowRuntime(card)
    zero.set_state({**rt.get_state(), "thetas": [0.0] * len(rt.get_state()["thetas"]), "theta": [0.0]})
    rt.set_y(plant.y())
    rt.set_theta(plant.theta())
    zero.set_y(plant.y())
    assert np.abs(zero.gx() - rt.gx()).max() > 1e-3


def test_window_state_round_trip_and_refusals():
    card = design(THETA_PLANT)
    rt = WindowRuntime(card)
    rng = np.random.default_rng(2)
    for _ in range(5):
        rt.set_y(rng.normal(size=1))
        rt.set_theta(rng.normal(size=1))
        rt.step(0.5)
    state = rt.get_state()
    other = WindowRuntime(card)
    other.set_state(copy.deepcopy(state))
    y, th = rng.normal(size=1), rng.normal(size=1)
    for r in (rt, other):
        r.set_y(y)
        r.set_theta(th)
    np.testing.assert_array_equal(rt.gx(), other.gx())
    for bad in ({**state, "ys": state["ys"][:-1]}, {**state, "k": -1}, {**state, "thetas": [np.nan] * 3}):
        with pytest.raises(StateRejected):
            other.set_state(bad)
    rt.set_theta([np.nan])
    with pytest.raises(RuntimeInputError, match="theta"):
        rt.step(0.5)
    rt.set_theta([0.1])
    with pytest.raises(Exception, match="dt = 0.5"):
        rt.step(0.25)


def test_no_drift_over_100000_steps():
    """The finite window has no state to drift: after 1e5 steps of a bounded plant the output is
    as exact as at the first full window."""
    data = copy.deepcopy(THETA_PLANT)
    data["plant"]["A"] = (0.3 * np.array(data["plant"]["A"])).tolist()     # a bounded plant
    card = design(data)
    plant = LpvPlantRuntime(problem_from_data(copy.deepcopy(data)).plant.to_data())
    rt = WindowRuntime(card)
    G = np.array(data["observer"]["G"])
    rng = np.random.default_rng(3)
    d, theta = rng.uniform(-1, 1, size=100_000), rng.uniform(-0.3, 0.3, size=100_000)
    worst = 0.0
    for k in range(100_000):
        plant.d[0], plant.theta_in[0] = d[k], theta[k]
        rt.set_y(plant.y())
        rt.set_theta(plant.theta_in)
        if rt.valid and (k < 100 or k > 99_900):
            worst = max(worst, float(np.abs(rt.gx() - G @ plant.x).max()))
        rt.step(0.5)
        plant.step(0.5)
    assert worst < 1e-12


def test_problem_file_errors():
    bad = copy.deepcopy(EXAMPLE)
    bad["plant"]["B"] = [[1.0], [0.0], [0.0]]
    with pytest.raises(ProblemError, match="plant.B: every input of an LPV plant is unknown"):
        problem_from_data(bad)
    bad = copy.deepcopy(EXAMPLE)
    bad["plant"]["scheduling"][0]["A"] = [[1.0]]
    with pytest.raises(ProblemError, match=r"plant.scheduling\[0\].A"):
        problem_from_data(bad)
    bad = copy.deepcopy(EXAMPLE)
    bad["observer"] = {"family": "lti-uio"}
    with pytest.raises(ProblemError, match="an LPV plant needs a family that designs for LPV plants"):
        problem_from_data(bad)
    bad = copy.deepcopy(EXAMPLE)
    bad["plant"]["scheduling"][0]["E"] = [[0.0], [1.0], [0.0]]     # the unknown input's path depends on theta
    with pytest.raises(ProblemError, match=r"depends on theta .*its largest theta coefficient, entry \(\d+, 1\) of the "
                                           r"term θ_k\+\d\[1\], is 1 where its products add up to 1: not rounding"):
        design(bad)


def _in_coordinates(doc: dict, T: np.ndarray, theta_scale: float) -> dict:
    """The paper's example for the state ``x = T z`` (``T`` orthogonal), with theta's part scaled by
    ``theta_scale`` and ``theta = T x`` by its inverse: the same plant, the same functional ``G x``."""
    out = copy.deepcopy(doc)
    p, Ti = out["plant"], T.T
    A, E, C, A1 = (np.array(x, dtype=float) for x in (p["A"], p["E"], p["C"], p["scheduling"][0]["A"]))
    p.update(A=(Ti @ A @ T).tolist(), E=(Ti @ E).tolist(), C=(C @ T).tolist())
    p["scheduling"][0]["A"] = (theta_scale * Ti @ A1 @ T).tolist()
    p["theta"]["T"] = (np.array(p["theta"]["T"]) @ T / theta_scale).tolist()
    out["observer"]["G"] = (np.array(out["observer"]["G"]) @ T).tolist()
    return out


def test_products_that_are_zero_in_exact_arithmetic_are_not_theta_terms():
    """In rotated coordinates with theta's part 1e6 times larger, C A_1 E is 4.5e-11 of rounding (its products
    add up to 1e6): M is constant, and the formula is the paper's, with no theta term of rounding (which would
    make the FMU read theta). Decided against the products' sizes, not the largest coefficient: it was refused
    as "M depends on theta"."""
    T, _ = np.linalg.qr(np.array([[1.0, 0.3, 0.2], [0.1, 1.0, 0.4], [0.5, 0.2, 1.0]]))
    for scale in (1.0, 1e6):
        doc = _in_coordinates(EXAMPLE, T, scale)
        p = doc["plant"]
        residual = (np.array(p["C"]) @ np.array(p["scheduling"][0]["A"]) @ np.array(p["E"])).item()
        assert residual != 0.0 and abs(residual) < 1e-9 * scale
        card = design(doc)
        assert card.data["formula"] == "(G x)_1 at k = 11·y_k + 2·y_k+1" and card.data["window"] == 4
        assert not np.any(card.data["matrices"]["Fexp"]) and all(c.holds for c in uiofmu.verify(card))


def test_a_tampered_formula_fails_its_re_check():
    card = design(EXAMPLE)
    data = copy.deepcopy(card.data)
    F = np.array(data["matrices"]["F"])
    F[0, 0, 2] = 11.0001
    data["matrices"]["F"] = F.tolist()
    assert not all(c.holds for c in uiofmu.verify(card_from_data(data)))


def test_a_formula_hidden_behind_overflowing_plant_matrices_fails_its_re_check():
    """The re-check's runs of plant matrices scaled by 1e200 overflow: a NaN residual is a failure,
    not a residual that ``max`` drops, so a wrong coefficient cannot hide behind it."""
    card = design(EXAMPLE)
    data = copy.deepcopy(card.data)
    data["matrices"]["A_parts"] = (np.array(data["matrices"]["A_parts"]) * 1e200).tolist()
    F = np.array(data["matrices"]["F"])
    F[0, 0, -1] = 123.0
    data["matrices"]["F"] = F.tolist()
    checks = uiofmu.verify(card_from_data(data))
    assert not all(c.holds for c in checks), [c.to_data() for c in checks]
