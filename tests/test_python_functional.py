"""Dead-beat functional observers (seed 003) and LPV plants as pythonfmu FMUs (backend "python"), really built and run.

Two designs of :mod:`tests.test_deadbeat_functional`: the paper's example (theta = T x from the state,
formula 11 y_k + 2 y_k+1, no theta input) and THETA_PLANT (theta an input, a formula that depends on
theta). Their observer FMUs, driven through fmpy (:class:`uiofmu.cosim.fmi.Fmu`), equal
:class:`uiofmu.runtime.window.WindowRuntime` bit for bit on random outputs and scheduling values; the
window survives fmi2GetFMUstate / fmi2SetFMUstate and serialisation bit for bit, also half filled (a
NaN theta or y refused, and the run against the runtime with theta an input: tests/test_conformance.py).
The LPV plant FMUs equal :class:`uiofmu.runtime.lpv.LpvPlantRuntime`. The command line makes and runs
the FMUs end to end (``design``, ``build``, ``plant``, ``cosim``, ``validate``), and a second importer,
ecospy, runs the plant and observer loop equal to our master.
"""

from __future__ import annotations

import copy
import csv
import json
import zipfile
from xml.etree import ElementTree

import numpy as np
import pytest
from fmpy.validation import validate_fmu

from conftest import run_cli
from importers import TableInputs, check_state_round_trip, ecospy_equals_master
from test_deadbeat_functional import EXAMPLE, THETA_PLANT
from uiofmu.cosim.fmi import Fmu
from uiofmu.fmu.export import build_observer, build_plant
from uiofmu.problem import problem_from_data, to_toml
from uiofmu.runtime.lpv import LpvPlantRuntime
from uiofmu.runtime.window import WindowRuntime
from uiofmu.synthesis import design

DESIGNS = {"example": EXAMPLE, "theta": THETA_PLANT}
#: Steps of the observer runs against the runtime.
STEPS = 60


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """``built(key)``: ``(problem, card, observer FMU, plant FMU)`` of a design of :data:`DESIGNS`, made once."""
    root = tmp_path_factory.mktemp("functional_python")
    made: dict = {}

    def get(key: str):
        if key not in made:
            problem = problem_from_data(copy.deepcopy(DESIGNS[key]))
            card = design(problem)
            obs = build_observer(card, root / f"obs_{key}.fmu", backend="python")
            plant = build_plant(problem.plant, problem.name, root / f"plant_{key}.fmu", problem.options.step,
                                backend="python")
            made[key] = problem, card, obs, plant
        return made[key]

    return get


def _outputs(source) -> np.ndarray:
    """``gx`` and ``gx_valid`` of an observer FMU or a :class:`WindowRuntime`."""
    if isinstance(source, WindowRuntime):
        return np.concatenate([source.gx(), [1.0 if source.valid else 0.0]])
    return np.concatenate([source.get("gx"), source.get("gx_valid")])


def _inputs(card, steps: int, seed: int):
    """Random ``(y, theta)`` per step."""
    rng = np.random.default_rng(seed)
    return rng.normal(size=(steps, card.dims["p"])) * 3, rng.normal(size=(steps, int(card.schedule["theta"])))


def _drive(target, inputs, t0: float, h: float) -> np.ndarray:
    """Set each step's inputs (theta where the FMU takes it), read the outputs, step; the outputs
    before every step."""
    out, t = [], t0
    runtime = isinstance(target, WindowRuntime)
    for y, theta in zip(*inputs):
        if runtime:
            target.set_y(y)
            target.set_theta(theta)
        else:
            target.set("y", y)
            if target.has("theta"):
                target.set("theta", theta)
        out.append(_outputs(target))
        target.step(h) if runtime else target.step(t, h)
        t += h
    return np.array(out)


@pytest.mark.parametrize("key", DESIGNS)
def test_model_description_declares_the_window_ports(built, key):
    """y (and theta when the formula uses it) in, gx and the Integer gx_valid out, in declaration order;
    gx depends on y (and theta), gx_valid on nothing; fmpy's validation finds nothing."""
    _, card, path, _ = built(key)
    assert validate_fmu(str(path)) == []
    with zipfile.ZipFile(path) as z:
        root = ElementTree.fromstring(z.read("modelDescription.xml"))
    found = [(v.get("name"), v[0].tag, v.get("causality"), v.get("variability"))
             for v in root.find("ModelVariables").findall("ScalarVariable")]
    theta = [("theta[1]", "Real", "input", "continuous")] if key == "theta" else []
    assert found == [("y[1]", "Real", "input", "continuous"), *theta, ("gx[1]", "Real", "output", "continuous"),
                     ("gx_valid[1]", "Integer", "output", "discrete")]
    deps = [u.get("dependencies") for u in root.find("ModelStructure").find("Outputs")]
    assert deps == (["1 2", ""] if key == "theta" else ["1", ""])
    assert float(root.find("DefaultExperiment").get("stepSize")) == card.schedule["dt"]


@pytest.mark.parametrize("key", ["example"])        # theta as an input: test_conformance.py
def test_observer_equals_the_window_runtime(built, key):
    """Bit for bit over 60 steps of random y, gx_valid 0 until the window is full."""
    _, card, path, _ = built(key)
    h = card.schedule["dt"]
    inputs = _inputs(card, STEPS, seed=1)
    with Fmu(path, "observer") as fmu:
        fmu.initialize(0.0)
        got = _drive(fmu, inputs, 0.0, h)
    ref = _drive(WindowRuntime(card), inputs, 0.0, h)
    np.testing.assert_array_equal(got, ref)
    L = card.schedule["length"]
    assert got[:L - 1].tolist() == [[0.0, 0.0]] * (L - 1) and np.all(got[L - 1:, 1] == 1.0)
    assert np.all(got[L - 1:, 0] != 0.0)


@pytest.mark.parametrize("key", DESIGNS)
@pytest.mark.parametrize("after", [2, 25])
def test_state_save_restore_and_serialisation_are_bit_exact(built, key, after):
    """Saved after ``after`` steps (2: the window half filled; 25: full), restored in the same instance
    and deserialised in another: the next 20 steps are identical, the state serialises to the same
    bytes, and it holds the window of the runtime driven with the same inputs."""
    _, card, path, _ = built(key)
    h = card.schedule["dt"]
    inputs = _inputs(card, after + 20, seed=5)
    first, rest = tuple(v[:after] for v in inputs), tuple(v[after:] for v in inputs)
    rt = WindowRuntime(card)
    _drive(rt, first, 0.0, h)
    with Fmu(path, "a") as a, Fmu(path, "b") as b:
        _, blob, once = check_state_round_trip(a, b, _drive, first, rest, h)
        saved = json.loads(blob)["model"]["runtime"]
        assert saved["k"] == after and (saved["k"] >= card.schedule["length"] - 1) == (after == 25)
        expected = rt.get_state()
        if not a.has("theta"):       # the FMU without a theta input never sets it: zeros in its window
            expected["thetas"] = [0.0] * len(expected["thetas"])
            expected["theta"] = [0.0] * len(expected["theta"])
        assert saved == expected
    np.testing.assert_array_equal(_drive(rt, rest, after * h, h), once)


# -- LPV plants -----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("key, steps, size", [("example", 10, 0.01), ("theta", 60, 1.0)])
def test_lpv_plant_equals_the_runtime(built, key, steps, size):
    """x, y and theta bit for bit. The example's plant (theta = T x: the nonlinear system (17), unstable)
    from a small state with small inputs over 10 steps; THETA_PLANT (theta an input) over 60."""
    problem, _, _, path = built(key)
    data = problem.plant.to_data()
    rt = LpvPlantRuntime(data)
    rng = np.random.default_rng(17)
    rt.x0 = size * rng.normal(size=rt.n)
    rt.reset()
    h = rt.dt
    with Fmu(path, "plant") as fmu:
        assert validate_fmu(str(path)) == []
        assert fmu.has("theta") and (fmu.ports("input").get("theta") == 1) == (key == "theta")
        fmu.initialize(0.0, {"x0": rt.x0})
        t = 0.0
        for k in range(steps):
            rt.d[:] = size * rng.uniform(-1.0, 1.0, size=rt.q)
            fmu.set("d", rt.d)
            if rt.kind == "input":
                rt.theta_in[:] = rng.uniform(-0.5, 0.5, size=rt.s)
                fmu.set("theta", rt.theta_in)
            for name, want in (("x", rt.x), ("y", rt.y()), ("theta", rt.theta())):
                np.testing.assert_array_equal(fmu.get(name), want, err_msg=f"{name} at step {k}")
            fmu.step(t, h)
            rt.step(h)
            t += h
        np.testing.assert_array_equal(fmu.get("x"), rt.x)
    if key == "example":                          # (17) itself: x2+ = 3 x1^2 + 2 x1 x2 + x3 + d
        assert np.all(np.isfinite(rt.x)) and np.abs(rt.x).max() > 10 * size


# -- the command line ------------------------------------------------------------------------------------------
def _cli(*argv):
    result = run_cli(*argv)
    assert result.code == 0, f"uiofmu {' '.join(map(str, argv))} exited {result.code}:\n{result.err}"
    return result


def test_command_line_end_to_end(tmp_path):
    """THETA_PLANT with ``[signals] theta`` and ``d`` random: design, build and plant (python backend),
    cosim writes gx, gx_true and gx_valid, exact from the first full window; validate passes on both."""
    doc = copy.deepcopy(THETA_PLANT)
    doc["signals"] = {"d": [[{"kind": "random", "seed": 1, "std": 1.0, "hold": 0.5}]],
                      "theta": [[{"kind": "random", "seed": 2, "std": 0.3, "hold": 0.5}]]}
    problem = tmp_path / "needs_theta.toml"
    problem.write_text(to_toml(doc, "THETA_PLANT of tests/test_deadbeat_functional.py with random signals"))
    card, obs, plant, out = (tmp_path / n for n in ("card.json", "obs.fmu", "plant.fmu", "run"))
    res = _cli("design", problem, "-o", card)
    assert "formula          (G x)_1 at k = " in res.out and "(r = 1, K = 2)" in res.out
    assert "python backend" in _cli("build", card, "-o", obs, "--backend", "python").out
    res = _cli("plant", problem, "-o", plant, "--backend", "python")
    assert "LPV plant (1 scheduling component(s), theta from the input) FMU (python backend)" in res.out
    res = _cli("cosim", "--plant", plant, "--observer", obs, "--out", out, "--t-end", "15")
    assert "exact from step      3 (the first full window)" in res.out, res.out
    with open(out / "results.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert {"gx[1]", "gx_true[1]", "gx_valid", "d[1]", "x[1]"} <= set(rows[0])
    assert len(rows) == 31
    valid = [r for r in rows if r["gx_valid"] == "1.0"]
    assert len(valid) == 31 - 3 and all(r["gx_valid"] == "0.0" for r in rows[:3])
    for r in valid:                                       # delay 0: G x of the same point
        gx, true = float(r["gx[1]"]), float(r["gx_true[1]"])
        x = np.array([float(r[f"x[{i}]"]) for i in (1, 2, 3)])
        assert true == pytest.approx(float(np.dot(THETA_PLANT["observer"]["G"][0], x)), rel=1e-14, abs=1e-14)
        assert abs(gx - true) <= 1e-9 * max(1.0, abs(true))
    assert len({r["d[1]"] for r in rows}) > 20                       # a random unknown input
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["exact_from_first_full_window"] is True
    assert metrics["valid_from"] == metrics["steps_to_exact"] == 3 and metrics["window"] == 4
    drawn = (out / "report.png").read_bytes()
    (out / "report.png").unlink()
    _cli("report", out)                                   # the same figure, from results.csv and metrics.json
    assert (out / "report.png").read_bytes() == drawn
    for fmu, kind in ((obs, "observer"), (plant, "plant")):
        res = _cli("validate", fmu, "--steps", "100")
        assert f"{kind} FMU" in res.out and "validate_fmu         no problem" in res.out
        report = json.loads(_cli("validate", fmu, "--steps", "100", "--json").out)
        assert report["ok"] and report["steps"] == 100 and report["max_abs_diff"] == 0.0


def test_validate_covers_the_state_scheduled_plant_and_observer(built):
    """The example's FMUs: the observer against the runtime, the nonlinear plant (17) in episodes that
    restart before its state leaves every bound (no NaN, so nothing is hidden)."""
    from uiofmu.cosim.validate import validate

    _, _, obs, plant = built("example")
    for path in (obs, plant):
        report = validate(path, steps=120, seed=4)
        assert report.ok and report.steps == 120 and report.max_abs_diff == 0.0, report.to_data()
        assert report.scale > 1.0 if path == plant else True


# -- a second importer ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("key, K, size", [("example", 10, 1e-3), ("theta", 40, 1.0)])
def test_ecospy_runs_the_functional_loop_equal_to_our_master(built, key, K, size):
    """ecospy connects the plant's y to the observer (and nothing else: the example's theta is the
    plant's own, THETA_PLANT's comes from the input source on both FMUs); gx and x equal our master's,
    and gx is G x of ``delay`` steps back from the first full window on.

    The source's theta reaches the observer one step late in ecospy (its sets are applied just before
    the next doStep), so gx at t_k+1 is computed with theta(t_k) there; THETA_PLANT's formula uses
    theta at lags 1 and 2 only (what the window holds), which is why the two importers agree."""
    _, card, observer, plant = built(key)
    assert not card.matrices["Fexp"][:, -1].any()            # no theta of the current point
    h = card.schedule["dt"]
    rng = np.random.default_rng(3)
    table = {"d": size * rng.uniform(-1.0, 1.0, size=(K + 1, 1))}
    if key == "theta":
        table["theta"] = rng.uniform(-0.5, 0.5, size=(K + 1, 1))
    ours, theirs = ecospy_equals_master(plant, observer, h, K, TableInputs(h, table), fed={"y": 1}, estimate="gx",
                                        what=key)
    L, delay = card.schedule["length"], card.schedule["delay"]
    G = np.array(DESIGNS[key]["observer"]["G"])
    want = theirs.x[L - 1 - delay:K + 1 - delay] @ G.T
    assert np.abs(theirs.xhat[L - 1:] - want).max() <= 1e-9 * max(1.0, np.abs(want).max())
    assert np.abs(want).max() > 0 and not theirs.xhat[:L - 1].any()
    assert ours.metrics["exact_from_first_full_window"]
