"""Observer and plant FMUs really built with pythonfmu and really run by fmpy."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
from fmpy.validation import validate_fmu

import uiofmu
from uiofmu.fmu.export import build_observer, build_plant
from uiofmu.cosim.fmi import Fmu, FmuCallError
from uiofmu.runtime.observer import Runtime
from uiofmu.cosim.validate import validate


@pytest.fixture(scope="module", params=["python", "c"])
def fmus(request, example1_card, example1_path, tmp_path_factory):
    """The same tests for both observer backends: one runtime semantics."""
    card, _ = example1_card
    d = tmp_path_factory.mktemp("fmus")
    obs = build_observer(card, d / "obs.fmu", backend=request.param)
    problem = uiofmu.load_problem(example1_path)
    plant = build_plant(problem.plant, problem.name, d / "plant.fmu", backend="python")
    cont = uiofmu.Plant.create([[0.0, 1.0], [-4.0, -0.4]], [[1.0, 0.0]], [[0.0], [1.0]], [[0.0], [0.5]],
                               time="continuous", x0=[1.0, 0.0])
    cplant = build_plant(cont, "oscillator", d / "cplant.fmu", backend="python")
    return {"card": card, "obs": obs, "plant": plant, "cplant": cplant, "cont": cont, "dir": d,
            "backend": request.param}


def test_validate_fmu_is_empty_for_every_fmu(fmus):
    for key in ("obs", "plant", "cplant"):
        assert validate_fmu(str(fmus[key])) == [], key


def test_observer_equals_runtime(fmus):
    report = validate(fmus["obs"], steps=300, seed=3)
    assert report.ok and report.problems == []
    assert report.max_rel_diff <= 1e-12


def test_continuous_plant_equals_exact_discretisation_on_aperiodic_steps(fmus):
    cont = fmus["cont"]
    rng = np.random.default_rng(5)
    x = cont.x0.copy()
    worst = 0.0
    with Fmu(fmus["cplant"], "p") as fmu:
        fmu.initialize(0.0)
        t = 0.0
        for _ in range(300):
            h = float(rng.uniform(0.001, 0.7))
            u, d = rng.normal(size=1), rng.normal(size=1)
            fmu.set("u", u)
            fmu.set("d", d)
            fmu.step(t, h)
            s = cont.sampled(h)
            x = s.A @ x + s.B @ u + s.E @ d
            t += h
            worst = max(worst, float(np.abs(fmu.get("x") - x).max() / max(1.0, np.abs(x).max())))
            np.testing.assert_allclose(fmu.get("y"), cont.C @ fmu.get("x"), rtol=0, atol=0)
    assert worst <= 1e-9


def _drive(fmu, ys, us, t0, h=0.1):
    out = []
    t = t0
    for y, u in zip(ys, us):
        fmu.set("y", y)
        fmu.set("u", u)
        out.append(np.concatenate([fmu.get("xhat"), fmu.get("r"), fmu.get("dhat")]))
        fmu.step(t, h)
        t += h
    return np.array(out)


def test_state_save_restore_is_bit_identical(fmus):
    rng = np.random.default_rng(0)
    ys, us = rng.normal(size=(40, 1)), rng.normal(size=(40, 1))
    with Fmu(fmus["obs"], "o") as fmu:
        fmu.initialize(0.0, {"xhat0": [0.5, -0.5]})
        _drive(fmu, ys[:10], us[:10], 0.0)
        state = fmu.get_state()
        first = _drive(fmu, ys[10:], us[10:], 1.0)
        fmu.set_state(state)
        second = _drive(fmu, ys[10:], us[10:], 1.0)
        assert first.tobytes() == second.tobytes()
        blob = fmu.serialize(state)
        third_state = fmu.deserialize(blob)
        fmu.set_state(third_state)
        third = _drive(fmu, ys[10:], us[10:], 1.0)
        assert first.tobytes() == third.tobytes()


def test_reset_returns_to_initial_state(fmus):
    rng = np.random.default_rng(1)
    ys, us = rng.normal(size=(20, 1)), rng.normal(size=(20, 1))
    with Fmu(fmus["obs"], "o") as fmu:
        fmu.initialize(0.0)
        first = _drive(fmu, ys, us, 0.0)
        fmu.reset()
        fmu.initialize(0.0)
        assert first.tobytes() == _drive(fmu, ys, us, 0.0).tobytes()


def test_two_instances_are_independent(fmus):
    card = fmus["card"]
    rng = np.random.default_rng(2)
    ya, yb, u = rng.normal(size=(30, 1)), rng.normal(size=(30, 1)), rng.normal(size=(30, 1))
    with Fmu(fmus["obs"], "a") as a, Fmu(fmus["obs"], "b") as b:
        a.initialize(0.0)
        b.initialize(0.0, {"xhat0": [3.0, 3.0]})
        outs_a, outs_b = [], []
        t = 0.0
        for k in range(30):  # interleaved calls
            a.set("y", ya[k])
            a.set("u", u[k])
            b.set("y", yb[k])
            b.set("u", u[k])
            outs_a.append(a.get("xhat"))
            outs_b.append(b.get("xhat"))
            a.step(t, 0.1)
            b.step(t, 0.1)
            t += 0.1
    for ys, x0, outs in ((ya, [0.0, 0.0], outs_a), (yb, [3.0, 3.0], outs_b)):
        rt = Runtime(card, xhat0=x0)
        for k in range(30):
            rt.set_y(ys[k])
            rt.set_u(u[k])
            assert np.array_equal(rt.xhat(), outs[k])
            rt.step(0.1)


@pytest.mark.parametrize("case,fragment", [
    ("nan", "input y[1] = nan"),
    ("inf", "input u[1] = inf"),
    ("zero-step", "expected h > 0"),
    ("negative-step", "expected h > 0"),
    ("wrong-step", "designed for steps of dt = 0.1 s and received h = 0.25 s"),
    ("before-init", "called before fmi2ExitInitializationMode"),
])
def test_bad_calls_give_a_status_and_a_log_line(fmus, case, fragment):
    with Fmu(fmus["obs"], "o") as fmu:
        if case != "before-init":
            fmu.initialize(0.0)
        h = {"zero-step": 0.0, "negative-step": -0.1, "wrong-step": 0.25}.get(case, 0.1)
        if case == "nan":
            fmu.set("y", [float("nan")])
        if case == "inf":
            fmu.set("u", [float("inf")])
        with pytest.raises(FmuCallError) as info:
            fmu.step(0.0, h)
        # a step the design does not allow: fmi2Discard; a bad call: fmi2Error (pythonfmu's binary can only
        # discard, the guard in front of it turns the slave's error line into fmi2Error, as the C backend says)
        expected = 2 if case == "wrong-step" else 3
        assert info.value.status == expected
        assert any(fragment in m for m in info.value.messages), info.value.messages
        if case != "before-init":                      # the instance still works afterwards
            fmu.set("y", [1.0])
            fmu.set("u", [0.0])
            fmu.step(0.0, 0.1)
            assert np.all(np.isfinite(fmu.get("xhat")))


def test_discrete_plant_refuses_other_steps(fmus):
    with Fmu(fmus["plant"], "p") as fmu:
        fmu.initialize(0.0)
        with pytest.raises(FmuCallError) as info:
            fmu.step(0.0, 0.3)
        assert any("steps at dt = 0.1 s and received h = 0.3 s" in m for m in info.value.messages)


def test_validate_command(fmus, cli):
    res = cli("validate", fmus["obs"])
    assert res.code == 0 and "largest difference 0" in res.out
    res = cli("validate", fmus["cplant"])
    assert res.code == 0, res.err
    bad = fmus["dir"] / "broken.fmu"
    bad.write_bytes(b"not a zip")
    res = cli("validate", bad)
    assert res.code == 2 and "not an FMU built by uiofmu" in res.err


def test_setting_an_output_is_refused_with_a_log_line(fmus):
    with Fmu(fmus["obs"], "o") as fmu:
        fmu.initialize(0.0)
        with pytest.raises(FmuCallError) as info:
            fmu.set("xhat", [5.0, 5.0])
        assert info.value.status == 3
        assert any("is an output" in m for m in fmu.messages)
        assert fmu.get("xhat").tolist() == [0.0, 0.0]
        fmu.set("y", [1.0])
        fmu.step(0.0, 0.1)


def test_step_after_terminate_is_refused(fmus):
    with Fmu(fmus["obs"], "o") as fmu:
        fmu.initialize(0.0)
        fmu.slave.terminate()
        with pytest.raises(FmuCallError) as info:
            fmu.step(0.0, 0.1)
        assert any("after fmi2Terminate" in m for m in info.value.messages)


def test_log_lines_reach_the_instance_that_wrote_them(fmus):
    """Observer opened first, plant second: the observer's refusal carries its own log line,
    and the plant's log stays free of it (fmpy's native log proxy holds one callback)."""
    with Fmu(fmus["obs"], "observer") as obs, Fmu(fmus["plant"], "plant") as plant:
        obs.initialize(0.0)
        plant.initialize(0.0)
        with pytest.raises(FmuCallError) as info:
            obs.step(0.0, 0.25)
        assert any("received h = 0.25 s" in m for m in info.value.messages), info.value.messages
        assert any("received h = 0.25 s" in m for m in obs.messages)
        assert not any("received h = 0.25 s" in m for m in plant.messages), plant.messages
        with pytest.raises(FmuCallError) as info:
            plant.step(0.0, 0.3)
        assert any("received h = 0.3 s" in m for m in info.value.messages)
        assert not any("received h = 0.3 s" in m for m in obs.messages)


SCRIPT = """
import sys
from uiofmu.cosim.fmi import Fmu
with Fmu(sys.argv[1], "o") as fmu:
    fmu.initialize(0.0); fmu.set("y", [1.0]); fmu.step(0.0, 0.1)
"""


@pytest.mark.valgrind
def test_a_closed_pythonfmu_instance_leaves_a_clean_heap_at_exit(example1_card, tmp_path):
    """pythonfmu 0.7.0 binaries free their interpreter state at exit and then write into it
    from a library destructor (glibc then aborts at exit, now and then). After ``Fmu.close``
    valgrind sees no access to freed memory at exit (its exit status is the program's, so the
    report is read)."""
    obs = build_observer(example1_card[0], tmp_path / "obs.fmu", backend="python")
    script = tmp_path / "open_close.py"
    script.write_text(SCRIPT)
    env = {**os.environ, "PYTHONMALLOC": "malloc"}
    proc = subprocess.run(["valgrind", "--quiet", sys.executable, str(script), str(obs)],
                          capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "finalizePythonInterpreter" not in proc.stderr, proc.stderr[-4000:]
    assert "free'd" not in proc.stderr, proc.stderr[-4000:]


def test_every_fmu_runs_its_default_experiment_in_fmpy(fmus):
    """``<DefaultExperiment>`` with a step the FMU accepts: fmpy's simulate_fmu runs it as it is
    (the observer's dt; the discrete plant's dt), with the observer's stop time long enough for
    its certified bound to fall to 1e-3, or 1000 steps (fmpy doubles the step of longer runs)."""
    from fmpy import read_model_description, simulate_fmu

    card = fmus["card"]
    for key in ("obs", "plant"):
        exp = read_model_description(str(fmus[key])).defaultExperiment
        assert exp is not None and float(exp.startTime) == 0.0 and float(exp.stepSize) == card.dt, key
        result = simulate_fmu(str(fmus[key]))
        assert len(result) == round(float(exp.stopTime) / card.dt) + 1, key
    steps = round(float(read_model_description(str(fmus["obs"])).defaultExperiment.stopTime) / card.dt)
    assert steps == 1000 or card.data["overshoot_bound"] * card.data["decay_bound"] ** steps <= 1.01e-3


def test_outputs_declare_their_dependencies(fmus):
    """The observer's outputs depend on y (it feeds y through), the plant's on no input; every
    output is calculated and an initial unknown."""
    from fmpy import read_model_description

    for key, expected in (("obs", {"y"}), ("plant", set())):
        md = read_model_description(str(fmus[key]))
        assert md.outputs and {o.variable.name for o in md.outputs} == {
            v.name for v in md.modelVariables if v.causality == "output"}
        for out in md.outputs:
            assert out.variable.initial == "calculated" and out.variable.start is None
            assert {d.name.split("[")[0] for d in out.dependencies} == expected, (key, out.variable.name)
        assert {u.variable.name for u in md.initialUnknowns} == {o.variable.name for o in md.outputs}
