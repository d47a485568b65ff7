"""The switched UIO (seed 002, Millerioux-Daafouz): check, design, certificate and runtime.

The paper's setups 1 and 2 (setup 2's E_2 = [0, -6(a + lambda), 0] with a + lambda = 3 chosen:
the paper gives neither), a 3-mode plant whose fastest decay is known in closed form, and a
plant whose modes are stable one by one but not under switching.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

import uiofmu
from uiofmu.problem import problem_from_data
from uiofmu.runtime.card import card_from_data
from uiofmu.runtime.errors import NoObserverError, ProblemError
from uiofmu.runtime.observer import Runtime, RuntimeInputError
from uiofmu.runtime.state import StateRejected
from uiofmu.runtime.switching import SwitchedPlantRuntime
from uiofmu.structure import product_radius

A1 = [[0.0, 0.89, -2.0], [-1.28, 0.89, 0.0], [-0.1, 0.0, 0.1]]
A2 = [[0.0, 0.89, -2.0], [1.95, 0.89, 0.0], [-0.1, 0.0, 0.1]]


def setup(C, switching=None, **observer) -> dict:
    """Seed 002's example with output matrix ``C`` (setup 1: one row; setup 2: two)."""
    return {"name": "millerioux-daafouz",
            "plant": {"time": "discrete", "dt": 1.0, "C": C, "E": [[1.0], [-2.0], [1.0]],
                      "modes": [{"A": A1}, {"A": A2, "w": [0.0, -18.0, 0.0]}],
                      "switching": switching or {"rule": "threshold", "state": 1, "threshold": 6.0}},
            "observer": {"family": "switched", **observer}}


SETUP1 = setup([[1.0, 1.0, -1.0]])
SETUP2 = setup([[1.0, 1.0, -1.0], [2.0, -1.0, 1.0]])


def rotation_plant(radii=(0.6, 0.75, 0.5), angles=(0.4, 1.3, -2.0), seed=3) -> dict:
    """Three modes whose error on ker C (the part no gain moves, p = q = 1) is ``r_i R(theta_i)``:
    normal and commuting, so the joint spectral radius, and the fastest certifiable decay, is
    ``max r_i``; everything else is random (small enough for a bounded plant)."""
    rng = np.random.default_rng(seed)
    modes = []
    for r, th in zip(radii, angles):
        A = 0.3 * rng.normal(size=(3, 3))
        A[1:, 1:] = r * np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
        modes.append({"A": A.tolist(), "B": rng.normal(size=(3, 1)).tolist(), "w": rng.normal(size=3).tolist()})
    return {"name": "rotations",
            "plant": {"time": "discrete", "dt": 0.1, "C": [[1.0, 0.0, 0.0]], "E": [[1.0], [0.0], [0.0]],
                      "modes": modes, "switching": {"rule": "random", "seed": 5}},
            "observer": {"family": "switched", "decay": "max"}}


def design(data):
    return uiofmu.design(problem_from_data(copy.deepcopy(data)))


def run(card, data, modes, d, u=None, x0=None, xhat0=None):
    """The plant (rule "input", driven by ``modes``) and the reference runtime; the errors."""
    plant_data = problem_from_data(copy.deepcopy(data)).plant.to_data()
    plant_data["switching"] = {"rule": "input", "mode0": 1}
    plant = SwitchedPlantRuntime(plant_data)
    if x0 is not None:
        plant.x0 = np.asarray(x0, dtype=float)
        plant.reset()
    rt = Runtime(card, xhat0=xhat0)
    errors = []
    for k, mode in enumerate(modes):
        plant.mode_in = int(mode)
        rt.set_y(plant.y())
        rt.set_u(u[k] if u is not None else np.zeros(plant.m))
        rt.set_mode(int(mode))
        errors.append(np.linalg.norm(plant.x - rt.xhat()))
        plant.u[:] = u[k] if u is not None else 0.0
        plant.d[:] = d[k]
        rt.step(plant.dt)
        plant.step(plant.dt)
    return np.array(errors), plant


def test_setup1_is_refused_with_both_fixed_eigenvalue_sets():
    existence = uiofmu.check(problem_from_data(copy.deepcopy(SETUP1)))
    assert not existence.exists
    failed = [c for c in existence.conditions if c.required and not c.holds]
    assert [c.name for c in failed] == ["detectable (At_1, Ct_1)"]
    assert "-3.04274" in failed[0].message
    fixed = {c.values["mode"]: sorted(complex(*z).real for z in c.values["fixed_eigenvalues"])
             for c in existence.conditions if c.name.startswith("detectable")}
    np.testing.assert_allclose(fixed[1], [-3.0427, 0.6127], atol=1e-4)
    np.testing.assert_allclose(fixed[2], [-0.6837, -0.1313], atol=1e-4)     # the paper prints -0.06837
    with pytest.raises(NoObserverError, match="-3.04274"):
        design(SETUP1)


def test_setup2_reproduces_the_papers_dead_beat_gains():
    card = design(SETUP2)
    m = card.data["matrices"]
    K, Q, P, E = (np.array(m[k]) for k in ("K", "Q", "P", "E_modes"))
    np.testing.assert_allclose(K[0], [[0, 0], [0.3166, -0.4893], [0.3166, -0.4893]], atol=1e-3)
    np.testing.assert_allclose(K[1], [[0, 0], [0.8295, 0.0236], [0.8295, 0.0236]], atol=1e-3)
    paper_Q = [[0.3333, 0.3333], [0.2060, -0.3176], [-0.4606, 0.0157]]
    np.testing.assert_allclose(Q[0], paper_Q, atol=1e-3)
    np.testing.assert_allclose(Q[1], paper_Q, atol=1e-3)
    assert np.abs(P @ E).max() < 1e-9
    assert card.data["design_method"] == "deadbeat"
    assert card.data["decay_bound"] < 1e-12 and np.abs(np.array(m["Phi"])).max() < 1e-12
    assert card.data["certificate"]["verified"]
    assert all(c.holds for c in uiofmu.verify(card))


def test_setup2_error_is_zero_after_one_step_under_random_switching():
    card = design(SETUP2)
    rng = np.random.default_rng(0)
    for _ in range(100):
        K = 30
        modes = rng.integers(1, 3, size=K)
        d = rng.uniform(-0.1, 0.1, size=(K, 1))
        x0 = rng.normal(size=3)
        errors, plant = run(card, SETUP2, modes, d, x0=x0, xhat0=np.zeros(3))
        scale = np.linalg.norm(x0)
        assert errors[0] == pytest.approx(scale)
        assert errors[1:].max() <= 1e-9 * scale


def test_a_bad_mode_is_refused_and_nothing_changes():
    card = design(SETUP2)
    rt = Runtime(card)
    rt.set_y([1.0, 2.0])
    rt.set_mode(1)
    rt.step(1.0)
    before = rt.get_state()
    for bad in (0, 3, -1):
        rt.set_mode(bad)
        with pytest.raises(RuntimeInputError, match=rf"mode = {bad} is not a mode .* from 1 to 2"):
            rt.step(1.0)
    assert {k: v for k, v in rt.get_state().items() if k != "mode"} == \
           {k: v for k, v in before.items() if k != "mode"}


def test_state_round_trip_keeps_the_previous_mode():
    card = design(SETUP2)
    rt = Runtime(card)
    rng = np.random.default_rng(1)
    for mode in (2, 1, 2):
        rt.set_y(rng.normal(size=2))
        rt.set_mode(mode)
        rt.step(1.0)
    state = rt.get_state()
    assert state["mode_prev"] == 2
    other = Runtime(card)
    other.set_state(copy.deepcopy(state))
    y = rng.normal(size=2)
    for r in (rt, other):
        r.set_y(y)
    np.testing.assert_array_equal(rt.xhat(), other.xhat())      # xhat uses Q of the previous mode
    for bad, field in (({**state, "mode_prev": 3}, "mode_prev"), ({**state, "mode_prev0": 0}, "mode_prev0"),
                       ({**state, "mode": 1.0}, "mode")):
        with pytest.raises(StateRejected, match=field):
            other.set_state(bad)


def test_fastest_decay_is_the_joint_spectral_radius_and_the_bound_holds():
    data = rotation_plant()
    card = design(data)
    lam = card.data["decay_bound"]
    assert card.data["design_method"] == "lmi"
    assert 0.75 <= lam <= 0.75 * (1 + 1e-3)            # lambda* = max r_i = 0.75
    assert all(c.holds for c in uiofmu.verify(card))
    rng = np.random.default_rng(2)
    K = 200
    for _ in range(20):
        modes = rng.integers(1, 4, size=K)
        x0 = 3 * rng.normal(size=3)
        errors, plant = run(card, data, modes, rng.normal(size=(K, 1)), u=rng.normal(size=(K, 1)), x0=x0,
                            xhat0=np.zeros(3))
        assert np.linalg.norm(plant.x) < 100                # a bounded plant: round-off stays at 1e-14
        bound = card.data["overshoot_bound"] * lam ** np.arange(K) * np.linalg.norm(x0)
        assert np.all(errors <= bound * (1 + 1e-9) + 1e-12)
        assert errors[-1] < 1e-10 < errors[0]


@pytest.mark.parametrize("decay", [0.8, 0.95])
def test_a_fixed_decay_slower_than_the_max_designs(decay):
    card = design({**rotation_plant(), "observer": {"family": "switched", "decay": decay}})
    assert card.data["decay_bound"] == decay and card.data["certificate"]["verified"]


def test_a_decay_faster_than_the_joint_spectral_radius_is_refused():
    with pytest.raises(NoObserverError, match="0.75"):
        design({**rotation_plant(), "observer": {"family": "switched", "decay": 0.7}})


def test_modes_stable_alone_but_not_under_switching_are_refused_naming_the_sequence():
    A = [[0.1, 0.2, 0.3], [0.4, 0.5, 2.0], [0.1, 0.0, 0.5]]
    B = [[0.1, 0.2, 0.3], [0.4, 0.5, 0.0], [0.1, 2.0, 0.5]]
    data = {"name": "unstable-switching",
            "plant": {"time": "discrete", "dt": 1.0, "C": [[1.0, 0.0, 0.0]], "E": [[1.0], [0.0], [0.0]],
                      "modes": [{"A": A}, {"A": B}]},
            "observer": {"family": "switched"}}
    radius, seq = product_radius([np.array(A)[1:, 1:], np.array(B)[1:, 1:]])
    assert radius > 1 and sorted(seq) == [0, 1]
    existence = uiofmu.check(problem_from_data(data))
    assert not existence.exists
    failed = [c for c in existence.conditions if not c.holds and c.required]
    assert failed[0].name == "fixed error under switching" and f"{radius:.6g}" in failed[0].message


def test_a_tampered_card_fails_its_re_check():
    card = design(rotation_plant())
    data = copy.deepcopy(card.data)
    K = np.array(data["matrices"]["K"])
    K[1] *= 1.5
    data["matrices"]["K"] = K.tolist()
    checks = uiofmu.verify(card_from_data(data))
    assert not all(c.holds for c in checks)


def test_problem_file_errors_name_the_key():
    bad = copy.deepcopy(SETUP2)
    bad["observer"]["mode_prev0"] = 3
    with pytest.raises(ProblemError, match="observer.mode_prev0: expected a mode from 1 to 2, found 3"):
        problem_from_data(bad)
    bad = copy.deepcopy(SETUP2)
    bad["plant"]["switching"] = {"rule": "threshold", "state": 1, "thresholds": [1.0, 2.0]}
    with pytest.raises(ProblemError, match="plant.switching.thresholds: expected 1 increasing values for 2 modes"):
        problem_from_data(bad)
    bad = copy.deepcopy(SETUP2)
    bad["observer"]["method"] = "deadbeat"
    problem_from_data(bad)                                  # setup 2 allows it
    with pytest.raises(ProblemError, match="needs rank Ct_i = n = 3 in every mode"):
        design({**rotation_plant(), "observer": {"family": "switched", "decay": 0.9, "method": "deadbeat"}})


def test_switching_rules_of_the_plant_runtime():
    data = problem_from_data(copy.deepcopy(SETUP2)).plant.to_data()
    plant = SwitchedPlantRuntime(data)
    plant.x0 = np.array([5.0, 0.0, 0.0])
    plant.reset()
    assert plant.mode() == 1
    plant.x[0] = 6.0
    assert plant.mode() == 2                                # mode 1 while x[1] < 6, else 2
    data["switching"] = {"rule": "random", "probabilities": [0.25, 0.75], "seed": 7}
    plant = SwitchedPlantRuntime(data)
    drawn = []
    for _ in range(4000):
        drawn.append(plant.mode())
        plant.step(1.0)
        plant.x[:] = 0.0                                    # keep the unstable modes bounded
    assert 0.72 < np.mean(np.array(drawn) == 2) < 0.78
    again = SwitchedPlantRuntime(data)
    replay = []
    for _ in range(50):
        replay.append(again.mode())
        again.step(1.0)
    assert replay == drawn[:50]                             # the seed fixes the sequence
