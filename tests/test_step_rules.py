"""The steps every FMU takes (uiofmu/runtime/step_rules.py), both backends alike.

(a) ``canHandleVariableCommunicationStepSize`` from the descriptors: false for an observer of one period under
the policy ``error`` and for a discrete plant, true for design intervals, the policies ``nearest`` and ``count``,
a continuous kernel and a continuous plant; the modelDescription.xml of real FMUs says so.
(b) A step 1e-10 relative off the design step, and one 3 ulps of a large t off it (beyond STEP_RTOL), are the
design step: the outputs equal those of the exact step; a step 2e-6 relative off is still refused.
(c) A rounding step (1e-12 s after the last design step, as OMSimulator ends a run) is accepted, changes
nothing (outputs, FMU state, the next step's result) and is logged once per instance.
(d) An unknown debug-logging category: fmi2Warning and one log line from both backends, the known ones applied.
(e) The C FMUs in the FMU Compliance Checker and in fmusim: 0 errors, to the stop time; a checker run whose
last step is the design step plus its rounding reaches its stop time.
"""

from __future__ import annotations

import json
import math
import zipfile
from xml.etree import ElementTree

import numpy as np
import pytest
from fmpy import read_model_description

import cfuzz
from conftest import ROOT
from importers import Slave, debug_logging_status
from uiofmu.cosim.native_importers import FIXED_STEP_WARNING, run_compliance_checker, run_fmusim
from uiofmu.fmu.c_backend import c_compiler
from uiofmu.fmu.export import build_observer, build_plant
from uiofmu.problem import load_problem
from uiofmu.runtime.kernels import SCHEDULES
from uiofmu.runtime.step_rules import StepRule, step_rule
from uiofmu.runtime.tolerances import STEP_RTOL, STEP_ULPS, TINY_STEP_RTOL

BACKENDS = ["c", "python"] if c_compiler() else ["python"]


def _observer_spec(schedule: dict) -> dict:
    return {"kind": "observer", "card": {"kernel": "affine", "schedule": schedule}}


# -- (a) the rule and the flag -------------------------------------------------------------------

@pytest.mark.parametrize("schedule, steps, variable", [
    ({"kind": "constant", "dt": 0.1}, (0.1,), False),
    ({"kind": "mode", "dt": 1.0, "modes": 2}, (1.0,), False),
    ({"kind": "window", "dt": 0.5}, (0.5,), False),
    ({"kind": "geometric", "dt": 0.1, "alpha": 0.9}, (0.1,), False),
    ({"kind": "geometric", "dt": 0.1, "alpha": 0.9, "step_policy": "count"}, (0.1,), True),
    ({"kind": "interval", "intervals": [0.2, 0.1]}, (0.2, 0.1), True),
    ({"kind": "interval", "intervals": [0.2]}, (0.2,), False),
    ({"kind": "interval", "intervals": [0.2], "step_policy": "nearest"}, (0.2,), True),
    ({"kind": "continuous", "step": 0.001}, (), True),
])
def test_the_rule_of_each_schedule_kind(schedule, steps, variable):
    rule = step_rule(_observer_spec(schedule))
    assert rule == StepRule(steps, variable)
    assert rule.tiny == (TINY_STEP_RTOL * min(steps) if steps else 0.0)


def test_every_schedule_kind_is_covered():
    assert {"constant", "mode", "window", "geometric", "interval", "continuous"} == set(SCHEDULES)


@pytest.mark.parametrize("spec, steps, variable", [
    ({"kind": "plant", "plant": {"time": "discrete", "dt": 0.1}}, (0.1,), False),
    ({"kind": "plant", "plant": {"time": "continuous"}}, (), True),
    ({"kind": "plant", "plant": {"time": "discrete", "dt": 0.5, "modes": []}}, (0.5,), False),
    ({"kind": "plant", "plant": {"time": "continuous", "parameters": {}}}, (), True),
    ({"kind": "mujoco", "mujoco": {}}, (), True),
])
def test_the_rule_of_each_plant_kind(spec, steps, variable):
    assert step_rule(spec) == StepRule(steps, variable)


def test_take_snaps_within_ulps_of_t_and_passes_rounding():
    rule = StepRule((0.1, 0.3), True)
    t = 1e9
    off = 0.1 + 3 * math.ulp(t)
    assert abs(off - 0.1) > STEP_RTOL * 0.1                 # beyond the relative tolerance
    assert rule.take(t, off) == 0.1 and rule.take(t, 0.3 - 2 * math.ulp(t)) == 0.3
    assert rule.take(t, 0.1 + (STEP_ULPS + 1) * math.ulp(t)) == 0.1 + (STEP_ULPS + 1) * math.ulp(t)
    assert rule.take(0.0, 0.1 + 1e-12) == 0.1 + 1e-12       # at t = 0 only the model's tolerance applies
    assert rule.take(1e16, 0.5) == 0.5 and rule.take(1e308, 0.2) == 0.2   # a time that does not resolve the step
    assert rule.take(5.0, 1e-12) is None and rule.take(5.0, 1e-10) is None
    assert rule.take(5.0, 2e-10) == 2e-10                   # above 1e-9 of the shortest step: a step
    assert StepRule((), True).take(5.0, 1e-12) == 1e-12     # a kernel of any step takes it as a step


@pytest.fixture(scope="module")
def fmus(example1_card, building_card, tmp_path_factory):
    """(role, backend) -> FMU: the example 1 observer (h = 0.1 s only) and its discrete plant, the building's
    observer (design intervals) and its continuous plant."""
    d = tmp_path_factory.mktemp("step_rules")
    out = {}
    for backend in BACKENDS:
        out["fixed", backend] = build_observer(example1_card[0], d / f"fixed_{backend}.fmu", backend=backend)
        out["intervals", backend] = build_observer(building_card[0], d / f"intervals_{backend}.fmu",
                                                   backend=backend)
        problem = load_problem(ROOT / "examples" / "seed000_example1.toml")
        out["discrete plant", backend] = build_plant(problem.plant, "ex1", d / f"dplant_{backend}.fmu",
                                                     backend=backend)
        problem = load_problem(ROOT / "plants" / "two_room_building" / "problem.toml")
        out["continuous plant", backend] = build_plant(problem.plant, "bld", d / f"cplant_{backend}.fmu", step=600.0,
                                                       backend=backend)
    return out


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("role, variable", [("fixed", False), ("intervals", True), ("discrete plant", False),
                                            ("continuous plant", True)])
def test_model_descriptions_say_which_steps(fmus, role, backend, variable):
    cs = read_model_description(str(fmus[role, backend])).coSimulation
    assert cs.canHandleVariableCommunicationStepSize is variable
    spec = zipfile.ZipFile(fmus[role, backend]).read("resources/model.json")
    assert step_rule(json.loads(spec)).variable is variable


def test_the_count_policy_declares_variable_steps(ltv_card, tmp_path):
    card = cfuzz.with_step_policy(ltv_card[0], "count")
    for backend in BACKENDS:
        path = build_observer(card, tmp_path / f"count_{backend}.fmu", backend=backend)
        assert read_model_description(str(path)).coSimulation.canHandleVariableCommunicationStepSize is True


# -- (b), (c): steps within rounding, in fmpy ----------------------------------------------------

def _start(path, name: str, t0: float = 0.0) -> Slave:
    s = Slave(path, name)
    s.fmu.setupExperiment(startTime=t0)
    s.fmu.enterInitializationMode()
    s.fmu.exitInitializationMode()
    return s


def _drive(s: Slave, k: int, t: float, h: float) -> int:
    """Inputs of step k set; fmi2DoStep(t, h); its status."""
    refs = [v.valueReference for v in s.md.modelVariables if v.causality == "input" and v.type == "Real"]
    if refs:
        s.fmu.setReal(refs, [math.sin(0.7 * k + i) for i in range(len(refs))])
    return s.status("doStep", t, h)[0]


def _outputs(s: Slave) -> np.ndarray:
    refs = [v.valueReference for v in s.md.modelVariables if v.causality == "output" and v.type == "Real"]
    return np.array(s.fmu.getReal(refs))


def _state(s: Slave) -> bytes:
    state = s.fmu.getFMUstate()
    try:
        return bytes(s.fmu.serializeFMUstate(state))
    finally:
        s.fmu.freeFMUstate(state)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("role", ["fixed", "discrete plant"])
def test_a_step_within_rounding_is_the_design_step(fmus, role, backend):
    path = fmus[role, backend]
    H = 0.1
    exact, near = _start(path, f"exact-{role}-{backend}"), _start(path, f"near-{role}-{backend}")
    try:
        for k in range(5):
            assert _drive(exact, k, k * H, H) == 0
            assert _drive(near, k, k * H, H * (1 + (-1) ** k * 1e-10)) == 0
            np.testing.assert_array_equal(_outputs(near), _outputs(exact))
        assert _drive(near, 5, 5 * H, H * (1 + 2 * STEP_RTOL)) == 2      # fmi2Discard: not the design step
    finally:
        exact.close()
        near.close()
    t0 = 1e9                                                          # ulp(t) = 1.2e-7 s
    h = H + 3 * math.ulp(t0)
    assert abs(h - H) > STEP_RTOL * H
    exact, near = _start(path, f"exact-t-{role}-{backend}", t0), _start(path, f"near-t-{role}-{backend}", t0)
    try:
        for k in range(3):
            assert _drive(exact, k, t0 + k * H, H) == 0
            assert _drive(near, k, t0 + k * H, h) == 0
            np.testing.assert_array_equal(_outputs(near), _outputs(exact))
    finally:
        exact.close()
        near.close()


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("role, H", [("fixed", 0.1), ("intervals", 600.0), ("discrete plant", 0.1)])
def test_a_final_rounding_step_is_accepted_and_changes_nothing(fmus, role, H, backend):
    path = fmus[role, backend]
    a, b = _start(path, f"rounding-{role}-{backend}"), _start(path, f"plain-{role}-{backend}")
    try:
        for k in range(4):
            assert _drive(a, k, k * H, H) == 0 and _drive(b, k, k * H, H) == 0
        before, state = _outputs(a), _state(a)
        lines = len(a.lines())
        for tiny in (1e-12, 1.4e-12 * H / 0.1):
            assert a.status("doStep", 4 * H, tiny)[0] == 0
            np.testing.assert_array_equal(_outputs(a), before)
            assert _state(a) == state
        noted = a.lines()[lines:]
        assert len(noted) == 1 and noted[0][0] == 1, noted
        assert noted[0][2] == (f"t = {4 * H!r}: step h = 1e-12 s is rounding (at most {TINY_STEP_RTOL * H:.3g} s, "
                               "1e-9 of the shortest step this FMU takes): accepted, the state unchanged (noted once)")
        assert _drive(a, 4, 4 * H, H) == 0 and _drive(b, 4, 4 * H, H) == 0  # the run goes on as if untouched
        np.testing.assert_array_equal(_outputs(a), _outputs(b))
    finally:
        a.close()
        b.close()


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_continuous_plant_takes_a_short_step_as_a_step(fmus, backend):
    s = _start(fmus["continuous plant", backend], f"short-{backend}")
    try:
        assert _drive(s, 0, 0.0, 600.0) == 0
        lines = len(s.lines())
        assert s.status("doStep", 600.0, 1e-12)[0] == 0
        assert not [line for line in s.lines()[lines:] if "rounding" in line[2]]
    finally:
        s.close()


# -- (d) an unknown debug-logging category -------------------------------------------------------

@pytest.mark.parametrize("backend", BACKENDS)
def test_an_unknown_log_category_is_ignored_with_a_warning(fmus, backend):
    s = Slave(fmus["fixed", backend], f"categories-{backend}", logging_on=True)
    try:
        lines = len(s.lines())
        assert debug_logging_status(s.fmu, True, ["logStatusError", "logNoSuchCategory"]) == 1
        new = s.lines()[lines:]
        assert len(new) == 1 and new[0][0] == 1, new
        assert 'categories[1] = "logNoSuchCategory" is not a log category of this FMU' in new[0][2]
        assert new[0][2].endswith("ignored")
        lines = len(s.lines())
        s.fmu.setDebugLogging(True, [])
        s.fmu.setupExperiment(startTime=0.0)
        s.fmu.enterInitializationMode()
        s.fmu.exitInitializationMode()
        assert s.status("doStep", 0.0, 0.25)[0] == 2             # refused: its discard line is still logged
        assert any(line[0] == 2 for line in s.lines()[lines:])
        assert debug_logging_status(s.fmu, True, ["logStatusError"]) == 0
    finally:
        s.close()


@pytest.mark.parametrize("backend", BACKENDS)
def test_every_declared_log_category_is_known(fmus, backend):
    path = fmus["fixed", backend]
    with zipfile.ZipFile(path) as z:
        root = ElementTree.fromstring(z.read("modelDescription.xml"))
    declared = [c.get("name") for c in root.iter("Category")]
    assert len(declared) >= 4
    s = Slave(path, f"declared-{backend}")
    try:
        for name in declared:
            assert debug_logging_status(s.fmu, True, [name]) == 0, name
        assert debug_logging_status(s.fmu, True, declared) == 0
    finally:
        s.close()


# -- (e) the native importers ----------------------------------------------------------------------

def _needs_c():
    if not BACKENDS[0] == "c":
        pytest.skip("needs a C compiler")


def _check(fmu, h: float, stop: float, tmp_path):
    """The checker's run: it ran, 0 errors (the FMU's lines included), its only warning the fixed-step one."""
    run = run_compliance_checker(fmu, h, stop, workdir=tmp_path)
    if not run.ran:
        pytest.skip(run.unavailable)
    assert not run.errors, run.log[-2000:]
    assert all(FIXED_STEP_WARNING in line for line in run.warnings), run.warnings
    return run


@pytest.mark.parametrize("role, h, variable", [("fixed", 0.1, False), ("intervals", 600.0, True),
                                               ("discrete plant", 0.1, False), ("continuous plant", 600.0, True)])
def test_the_compliance_checker_runs_them_to_their_stop_time(fmus, role, h, variable, tmp_path):
    _needs_c()
    run = _check(fmus[role, "c"], h, 10 * h, tmp_path)
    assert bool(run.warnings) is (not variable)
    assert run.reached_stop and run.last_time >= 10 * h * (1 - 1e-12)


def test_the_checker_ends_on_the_stop_time_within_rounding(fmus, tmp_path):
    _needs_c()
    stop = 6000.000001                                            # the last step: 600 s and its rounding
    run = _check(fmus["intervals", "c"], 600.0, stop, tmp_path)
    assert run.last_time == pytest.approx(stop, rel=1e-15)


@pytest.mark.parametrize("role, h", [("fixed", 0.1), ("intervals", 600.0), ("discrete plant", 0.1),
                                     ("continuous plant", 600.0)])
def test_fmusim_runs_them_to_their_stop_time(fmus, role, h, tmp_path):
    _needs_c()
    run = run_fmusim(fmus[role, "c"], h, 10 * h, workdir=tmp_path)
    if not run.ran:
        pytest.skip(run.unavailable)
    assert not run.errors and not run.warnings, run.log[-2000:]
    assert len(run.rows) == 11 and run.last_time == pytest.approx(10 * h, rel=1e-12)
