"""The MuJoCo quarter-car: linearisation, plant FMU against MuJoCo and the exact model, observers."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
from fmpy.validation import validate_fmu

import uiofmu
from uiofmu.fmu.export import build_observer
from uiofmu.cosim.fmi import Fmu
from uiofmu.mujoco_plant import build_mujoco_plant, linearize, load_spec
from uiofmu.runtime.mujoco_runtime import MujocoRuntime
from uiofmu.problem import problem_from_data
from uiofmu.cosim.validate import validate
from tests.conftest import ROOT

pytestmark = pytest.mark.mujoco

FOLDER = ROOT / "plants" / "quarter_car"


@pytest.fixture(scope="module")
def spec():
    return load_spec(FOLDER)


@pytest.fixture(scope="module", params=["c", "python"])
def plant_fmu(spec, tmp_path_factory, request):
    """The plant FMU of each backend (C, the default: libmujoco inside; python: pythonfmu)."""
    return build_mujoco_plant(spec, tmp_path_factory.mktemp("mj") / "qc.fmu", backend=request.param)


def test_linearisation_matches_finite_differences_and_the_committed_problem(spec):
    lin = linearize(spec)
    assert lin.mismatch < 1e-9
    committed = uiofmu.load_problem(FOLDER).plant
    for name in ("A", "B", "E", "C"):
        np.testing.assert_allclose(getattr(committed, name), getattr(lin, name), rtol=1e-12, atol=0)
    ms, mw, ks, cs, kt, ct = 250.0, 35.0, 16000.0, 1000.0, 160000.0, 50.0
    expect = [[0, 0, 1, 0], [0, 0, 0, 1], [-ks / ms, ks / ms, -cs / ms, cs / ms],
              [ks / mw, -(ks + kt) / mw, cs / mw, -(cs + ct) / mw]]
    np.testing.assert_allclose(lin.A, expect, rtol=1e-12)


def test_plant_fmu_is_valid_and_identical_to_mujoco(plant_fmu):
    assert validate_fmu(str(plant_fmu)) == []
    report = validate(plant_fmu, steps=150, seed=2)
    assert report.ok and report.max_abs_diff == 0.0


def test_plant_fmu_against_exact_discretisation_on_aperiodic_steps(plant_fmu):
    plant = uiofmu.load_problem(FOLDER).plant
    rng = np.random.default_rng(0)
    x, worst, t = plant.x0.copy(), 0.0, 0.0
    with Fmu(plant_fmu, "q") as fmu:
        fmu.initialize(0.0)
        for _ in range(300):
            h = float(rng.choice([0.005, 0.01, 0.0137, 0.02, 0.05]))
            u, d = rng.normal(size=1) * 200, rng.normal(size=1) * 400
            fmu.set("u", u)
            fmu.set("d", d)
            fmu.step(t, h)
            t += h
            s = plant.sampled(h)
            x = s.A @ x + s.B @ u + s.E @ d
            worst = max(worst, float(np.abs(fmu.get("x") - x).max() / np.abs(x).max()))
    assert worst < 2e-9              # measured 9.4e-10 with RK4 substeps of 1e-4 s


def test_parameters_and_reset(spec, plant_fmu):
    params = {"m_body": 300.0, "k_susp": 20000.0}
    ref = MujocoRuntime(spec.mujoco, FOLDER)
    for name, value in params.items():
        ref.params[ref.param_names.index(name)] = value
    ref.apply_parameters()
    ref.reset()
    with Fmu(plant_fmu, "q") as fmu:
        fmu.initialize(0.0, {k: [v] for k, v in params.items()})
        first = []
        for k in range(20):
            fmu.set("d", [100.0])
            ref.d[:] = [100.0]
            fmu.step(0.01 * k, 0.01)
            ref.step(0.01)
            first.append(fmu.get("x"))
            np.testing.assert_array_equal(first[-1], ref.x)
        fmu.reset()
        fmu.initialize(0.0)
        np.testing.assert_array_equal(fmu.get("x"), spec.mujoco["x0"])


def test_a_step_of_too_many_mujoco_steps_is_refused_not_run(plant_fmu):
    """h = 1e300 (about 1e304 MuJoCo steps) is answered at once with fmi2Discard and the longest step
    accepted; nothing changed, so the next step goes through."""
    import time

    from uiofmu.cosim.fmi import FmuCallError
    from uiofmu.runtime.mujoco_runtime import MAX_SUBSTEPS

    with Fmu(plant_fmu, "q") as fmu:
        fmu.initialize(0.0)
        x0 = fmu.get("x").copy()
        start, began = len(fmu.messages), time.perf_counter()
        with pytest.raises(FmuCallError) as info:
            fmu.step(0.0, 1e300)
        assert info.value.status == 2 and time.perf_counter() - began < 2.0
        log = " ".join(fmu.messages[start:])
        assert f"more than the {MAX_SUBSTEPS} a step may take" in log, log
        np.testing.assert_array_equal(fmu.get("x"), x0)
        fmu.step(0.0, 0.01)


def test_bad_spec_exits_2(tmp_path, cli):
    (tmp_path / "model.xml").write_text((FOLDER / "model.xml").read_text())
    text = (FOLDER / "mujoco.toml").read_text().replace('d = ["road"]', 'd = ["pothole"]')
    (tmp_path / "mujoco.toml").write_text(text)
    res = cli("plant", tmp_path, "-o", tmp_path / "x.fmu")
    assert res.code == 2 and "the MJCF model has no actuator named 'pothole'" in res.err


@pytest.mark.parametrize("family,steps", [("sampled-data", "choice:0.005,0.01,0.02,0.03,0.04,0.05"),
                                          ("ltv-auid", "fixed:0.01")])
def test_observers_converge_against_mujoco(plant_fmu, tmp_path, cli, family, steps):
    data = copy.deepcopy(uiofmu.load_problem(FOLDER).data)
    if family == "ltv-auid":
        data["observer"] = {"family": "ltv-auid", "dt": 0.01, "alpha": 0.95, "eta": 0.3, "mu": 1.0}
    card = uiofmu.design(problem_from_data(data))
    obs = build_observer(card, tmp_path / "obs.fmu")
    res = cli("cosim", "--plant", plant_fmu, "--observer", obs, "--steps", steps, "--t-end", "3", "--seed", "5",
              "--out", tmp_path / "run")
    assert res.code == 0, res.err
    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert m["final_error_norm"] < 1e-8 * m["initial_error_norm"] * 1e3      # measured about 1e-11 m
    assert m["dhat_rms_error_second_half"][0] < 0.1                          # N, against a 400 N road force
    assert m["step_min"] < m["step_max"] or family == "ltv-auid"


def test_the_mujoco_plant_runs_its_default_experiment_in_fmpy(tmp_path, cli):
    """`uiofmu plant plants/quarter_car` gives the FMU the step of its linearised problem's
    observer (the first design interval, 0.005 s) over 200 steps, which fmpy runs as it is."""
    from fmpy import read_model_description, simulate_fmu

    res = cli("plant", FOLDER, "-o", tmp_path / "qc.fmu")
    assert res.code == 0, res.err
    exp = read_model_description(str(tmp_path / "qc.fmu")).defaultExperiment
    assert float(exp.stepSize) == 0.005 and float(exp.stopTime) == 200 * 0.005
    result = simulate_fmu(str(tmp_path / "qc.fmu"))
    assert len(result) == 201 and abs(result["time"][-1] - 1.0) < 1e-9
