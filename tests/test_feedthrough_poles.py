"""lti-uio on plants measured with direct feedthrough (y = C x + D u + F d), and exact pole placement.

What the theory guarantees and the tests check: with the decoupling equations ``M F = 0``,
``(I+MC)E = L F`` and the observer run on ``y - D u``, the estimation error obeys ``e+ = N e`` whatever the
unknown input does (here: to round-off, on random inputs, through the reference runtime); the rank condition
with F names its ranks when it fails; placed poles are eigenvalues of the stored ``N``, the fixed modes stay,
and ``uiofmu verify`` refuses a card whose poles or bound were edited. Both FMU backends converge in
co-simulation against a plant FMU that feeds u and d through.
"""

from __future__ import annotations

import copy
import json
import re

import numpy as np
import pytest

import uiofmu
from tests.conftest import EXAMPLES
from uiofmu.cosim.master import cosimulate
from uiofmu.problem import load_problem, problem_from_data, to_toml
from uiofmu.runtime.card import card_from_data
from uiofmu.runtime.errors import ProblemError
from uiofmu.synthesis import verify

ACCELEROMETER = EXAMPLES / "accelerometer_feedthrough.toml"
POLES = EXAMPLES / "pole_placement.toml"


def _doc(path) -> dict:
    return copy.deepcopy(load_problem(path).data)


def _errors_through_runtime(card, plant, steps: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Run the reference runtime on the sampled plant with random u and d; the errors e_k = x_k - xhat_k and the
    stored N."""
    rng = np.random.default_rng(seed)
    s = plant.sampled(card.dt)
    rt = uiofmu.Runtime(card, xhat0=rng.normal(size=plant.n))
    x = rng.normal(size=plant.n)
    errors = []
    for _ in range(steps):
        u, d = rng.normal(size=plant.m) * 3.0, rng.normal(size=plant.q) * 5.0
        rt.set_y(plant.C @ x + plant.D @ u + plant.F @ d)
        rt.set_u(u)
        errors.append(x - rt.xhat())
        rt.step(card.dt)
        x = s.A @ x + s.B @ u + s.E @ d + s.w
    return np.array(errors), np.asarray(card.matrices["N"])


@pytest.fixture(scope="module")
def accelerometer_card():
    return uiofmu.design(load_problem(ACCELEROMETER))


def test_feedthrough_decouples_exactly(accelerometer_card):
    card = accelerometer_card
    m = {k: np.asarray(v) for k, v in card.data["matrices"].items()}
    P, E, L, F, M, D = m["P"], m["E_sampled"], m["L"], m["F"], m["M"], m["D"]
    assert np.linalg.norm(P @ E - L @ F) <= 1e-12 and np.linalg.norm(M @ F) <= 1e-12
    np.testing.assert_allclose(m["Xu"], M @ D, atol=1e-14)
    np.testing.assert_allclose(m["G"], P @ m["B_sampled"] - L @ D, atol=1e-14)
    assert max(abs(np.linalg.eigvals(m["N"]))) < card.data["decay_bound"] < 1
    assert all(c.holds for c in verify(card))
    assert not card.has_dhat                           # dhat's formula does not hold with feedthrough
    # the error obeys e+ = N e whatever u and d do (k = 0 is the initial estimate, z takes over after it)
    plant = load_problem(ACCELEROMETER).plant
    e, N = _errors_through_runtime(card, plant, 30, seed=1)
    for k in range(1, len(e) - 1):
        assert np.linalg.norm(e[k + 1] - N @ e[k]) <= 1e-10 * max(1.0, np.linalg.norm(e[k])), k


def test_an_observer_that_ignored_the_feedthrough_would_not_decouple(accelerometer_card):
    """The same plant designed as if y = C x: its error moves with d (the test above is not vacuous)."""
    doc = _doc(ACCELEROMETER)
    del doc["plant"]["D"], doc["plant"]["F"]
    blind = uiofmu.design(problem_from_data(doc))
    plant = load_problem(ACCELEROMETER).plant
    e, N = _errors_through_runtime(blind, plant, 30, seed=1)
    assert max(np.linalg.norm(e[k + 1] - N @ e[k]) for k in range(1, len(e) - 1)) > 1e-2


def test_known_input_feedthrough_alone_changes_only_g_and_xu(tmp_path):
    doc = _doc(EXAMPLES / "seed000_example1.toml")
    doc["observer"]["decay"] = 0.995
    plain = uiofmu.design(problem_from_data(doc))
    doc["plant"]["D"] = [[0.7]]
    fed = uiofmu.design(problem_from_data(doc))
    a, b = plain.data["matrices"], fed.data["matrices"]
    for key in ("N", "L", "Xy", "M"):
        np.testing.assert_allclose(b[key], a[key], rtol=1e-6, atol=1e-9)
    L, D = np.asarray(b["L"]), np.asarray(b["D"])
    np.testing.assert_allclose(b["G"], np.asarray(a["G"]) - L @ D, atol=1e-9)
    assert "Xu" in b and "Xu" not in a and not fed.has_dhat and plain.has_dhat
    plant = problem_from_data(doc).plant
    e, N = _errors_through_runtime(fed, plant, 25, seed=2)
    for k in range(1, len(e) - 1):
        assert np.linalg.norm(e[k + 1] - N @ e[k]) <= 1e-10 * max(1.0, np.linalg.norm(e[k]))


def test_the_rank_condition_with_f_names_its_ranks(tmp_path, cli):
    doc = {"name": "no-decoupling", "plant": {"time": "discrete", "dt": 0.1, "A": [[0.5, 0.1], [0.0, 0.4]],
                                              "E": [[1.0, 0.0], [0.0, 1.0]], "C": [[1.0, 0.0]],
                                              "F": [[1.0, 0.0]]},
           "observer": {"family": "lti-uio"}}
    path = tmp_path / "p.toml"
    path.write_text(to_toml(doc))
    res = cli("check", path)
    assert res.code == 2
    assert "rank [[CE, F], [F, 0]] = 2 < rank F + rank [E; F] = 1 + 2 = 3" in res.out
    res = cli("design", path, "-o", tmp_path / "c.json")
    assert res.code == 2 and "rank [[CE, F], [F, 0]] = 2 < rank F + rank [E; F]" in res.err
    assert "Traceback" not in res.err


def test_feedthrough_is_refused_to_other_families():
    doc = _doc(ACCELEROMETER)
    doc["observer"] = {"family": "sampled-data", "intervals": [0.05], "alpha": 0.9}
    with pytest.raises(ProblemError, match=r"plant\.D and plant\.F: direct feedthrough .* \"lti-uio\" only"):
        problem_from_data(doc)


def test_wrong_shapes_of_d_and_f_name_the_key():
    doc = _doc(ACCELEROMETER)
    doc["plant"]["F"] = [[0.0, 1.0], [0.5, 0.0]]
    with pytest.raises(ProblemError, match=r"plant\.F"):
        problem_from_data(doc)


@pytest.fixture(scope="module")
def accelerometer_fmus(tmp_path_factory):
    from tests.conftest import run_cli

    out = tmp_path_factory.mktemp("accelerometer")
    for argv in (("design", ACCELEROMETER, "-o", out / "card.json"),
                 ("build", out / "card.json", "-o", out / "c.fmu", "--backend", "c"),
                 ("build", out / "card.json", "-o", out / "python.fmu", "--backend", "python"),
                 ("plant", ACCELEROMETER, "-o", out / "plant.fmu", "--backend", "c"),
                 ("plant", ACCELEROMETER, "-o", out / "plant_python.fmu", "--backend", "python")):
        res = run_cli(*map(str, argv))
        assert res.code == 0, res.err
    return out


def _dependencies(path, output: str) -> set:
    from fmpy import read_model_description

    md = read_model_description(str(path))
    (out,) = [u for u in md.outputs if u.variable.name == output]
    return {d.name for d in out.dependencies}


@pytest.mark.parametrize("plant", ["plant.fmu", "plant_python.fmu"])
def test_plant_fmus_measure_the_feedthrough(accelerometer_fmus, cli, plant):
    res = cli("validate", accelerometer_fmus / plant)           # y against C x + D u + F d on random inputs
    assert res.code == 0, res.out + res.err
    assert _dependencies(accelerometer_fmus / plant, "y[2]") == {"u[1]", "d[1]"}


def test_observer_fmus_declare_xhat_on_u(accelerometer_fmus):
    assert _dependencies(accelerometer_fmus / "c.fmu", "xhat[1]") == {"y[1]", "y[2]", "u[1]"}
    assert _dependencies(accelerometer_fmus / "python.fmu", "xhat[1]") == {"y[1]", "y[2]", "u[1]"}


@pytest.mark.parametrize("backend", ["c", "python"])
def test_both_backends_converge_with_an_unknown_input_that_feeds_through(accelerometer_fmus, backend, cli):
    res = cli("validate", accelerometer_fmus / f"{backend}.fmu")
    assert res.code == 0, res.out + res.err
    steps = np.full(120, 0.05)
    result = cosimulate(accelerometer_fmus / "plant.fmu", accelerometer_fmus / f"{backend}.fmu", steps,
                        plant_x0=[0.3, -0.4], xhat0=[0.0, 0.0], show_progress=False)
    e = np.linalg.norm(result.x - result.xhat, axis=1)
    assert e[0] > 0.4 and np.abs(result.d).max() > 1.0          # a real initial error, a real unknown input
    assert result.metrics["bound_respected"] is True
    assert e[-1] <= 1e-9 * max(1.0, float(np.abs(result.x).max()))
    # y carries u and d directly: what the plant FMU outputs is C x + D u + F d
    problem = load_problem(ACCELEROMETER)
    p = problem.plant
    np.testing.assert_allclose(result.y, result.x @ p.C.T + result.u @ p.D.T + result.d @ p.F.T, atol=1e-12)


def test_c_and_python_fmus_agree(accelerometer_fmus):
    steps = np.full(60, 0.05)
    runs = [cosimulate(accelerometer_fmus / plant, accelerometer_fmus / f"{b}.fmu", steps,
                       plant_x0=[0.3, -0.4], show_progress=False)
            for plant, b in (("plant.fmu", "c"), ("plant_python.fmu", "python"))]
    np.testing.assert_allclose(runs[0].y, runs[1].y, rtol=0, atol=1e-12)
    np.testing.assert_allclose(runs[0].xhat, runs[1].xhat, rtol=0, atol=1e-12)



# -- pole placement ----------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def poles_card():
    return uiofmu.design(load_problem(POLES))


def _pairs(values) -> np.ndarray:
    arr = np.asarray(values, dtype=float).reshape(-1, 2)
    return np.sort_complex(arr[:, 0] + 1j * arr[:, 1])


def test_poles_are_placed_exactly_and_the_fixed_mode_stays(poles_card):
    card = poles_card
    N = np.asarray(card.data["matrices"]["N"])
    np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(N)), [0.2, 0.3, 0.5], atol=1e-12)
    np.testing.assert_allclose(_pairs(card.data["poles"]), [0.2, 0.3, 0.5], atol=1e-12)
    np.testing.assert_allclose(_pairs(card.data["fixed_modes"]), [0.5], atol=1e-12)
    assert card.data["decay_bound"] == 0.5001 and card.data["design_method"] == "pole placement"
    _, V = np.linalg.eig(N)
    assert card.data["overshoot_bound"] == pytest.approx(np.linalg.cond(V), rel=1e-9)
    assert all(c.holds for c in verify(card))
    assert card.has_dhat                                 # no feedthrough: dhat as in every lti-uio card


def test_the_bound_holds_along_a_run(poles_card):
    problem = load_problem(POLES)
    e, N = _errors_through_runtime(poles_card, problem.plant, 40, seed=4)
    bound = poles_card.data["overshoot_bound"] * poles_card.data["decay_bound"] ** np.arange(len(e) - 1)
    assert np.all(np.linalg.norm(e[1:], axis=1) <= bound * np.linalg.norm(e[1]) * (1 + 1e-9) + 1e-12)


def test_complex_poles_with_feedthrough(tmp_path):
    doc = _doc(ACCELEROMETER)
    doc["observer"] = {"family": "lti-uio", "dt": 0.05, "poles": [[0.4, 0.3]]}
    card = uiofmu.design(problem_from_data(doc))
    np.testing.assert_allclose(_pairs(card.data["poles"]), np.sort_complex([0.4 - 0.3j, 0.4 + 0.3j]), atol=1e-12)
    assert card.data["decay_bound"] == pytest.approx(0.5001) and all(c.holds for c in verify(card))


def test_verify_refuses_edited_poles_and_bounds(poles_card):
    data = json.loads(json.dumps(poles_card.data))
    data["poles_placed"] = [[0.1, 0.0], [0.3, 0.0]]
    failed = [c.name for c in verify(card_from_data(data)) if not c.holds]
    assert any("poles_placed" in name for name in failed)      # not the problem's poles
    from uiofmu.families.lti_uio import pole_checks           # nor eigenvalues of the stored N

    assert [c.name.split(":")[0] for c in pole_checks(data) if not c.holds] == ["placed pole 0.1+0j"]
    data = json.loads(json.dumps(poles_card.data))
    data["decay_bound"] = 0.45                             # below the fixed mode 0.5: no certificate
    assert not all(c.holds for c in verify(card_from_data(data)))
    data = json.loads(json.dumps(poles_card.data))
    data["overshoot_bound"] = 0.5 * data["overshoot_bound"]
    assert any("overshoot_bound" in c.name and not c.holds for c in verify(card_from_data(data)))


@pytest.mark.parametrize("poles, message", [
    ([0.2], r"1 pole\(s\) given .* for the 2 assignable mode\(s\) .* fixed modes 0\.5"),
    ([0.2, 0.3, 0.4], r"3 pole\(s\) given .* for the 2 assignable mode\(s\)"),
])
def test_a_wrong_number_of_poles_is_refused_with_its_numbers(tmp_path, cli, poles, message):
    doc = _doc(POLES)
    doc["observer"]["poles"] = poles
    path = tmp_path / "p.toml"
    path.write_text(to_toml(doc))
    res = cli("design", path, "-o", tmp_path / "c.json")
    assert res.code == 2
    assert re.search(message, res.err), res.err


@pytest.mark.parametrize("change, message", [
    ({"poles": [1.2, 0.3]}, r"observer\.poles\[0\]: the pole 1\.2 has modulus 1\.2, expected < 1"),
    ({"poles": [0.2, 0.3], "decay": 0.5}, r"remove observer\.decay"),
    ({"poles": [0.2, [0.3]]}, r"observer\.poles\[1\]: expected a number or an \[re, im\] pair"),
    ({"poles": "fast"}, r"observer\.poles: expected a list"),
])
def test_bad_poles_are_refused(change, message):
    doc = _doc(POLES)
    doc["observer"].update(change)
    with pytest.raises(ProblemError, match=message):
        problem_from_data(doc)


def test_pole_placed_observer_converges_in_co_simulation(tmp_path, cli):
    for argv in (("design", POLES, "-o", tmp_path / "card.json"),
                 ("build", tmp_path / "card.json", "-o", tmp_path / "obs.fmu", "--backend", "c"),
                 ("plant", POLES, "-o", tmp_path / "plant.fmu"),
                 ("cosim", "--plant", tmp_path / "plant.fmu", "--observer", tmp_path / "obs.fmu", "--out",
                  tmp_path / "run", "--t-end", "5")):
        res = cli(*map(str, argv))
        assert res.code == 0, res.err
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["bound_respected"] is True and metrics["certified_decay"] == 0.5001
    assert metrics["final_error_norm"] <= 1e-9 * metrics["initial_error_norm"]


def test_a_statespace_with_d_keeps_its_feedthrough():
    control = pytest.importorskip("control")
    sys = control.ss([[0.5, 0.1], [0.0, 0.4]], [[1.0], [0.5]], [[1.0, 0.0], [0.0, 1.0]], [[0.2], [0.0]], 0.1)
    plant = uiofmu.plant_from_statespace(sys, [[0.0], [1.0]], x0=[1.0, 0.0])
    np.testing.assert_array_equal(plant.D, [[0.2], [0.0]])
    assert plant.feeds_u and not plant.feeds_d
    card = uiofmu.design(uiofmu.make_problem(plant, "lti-uio", decay=0.5))
    np.testing.assert_allclose(card.data["matrices"]["Xu"], np.asarray(card.data["matrices"]["M"]) @ plant.D)
    assert all(c.holds for c in verify(card))
