"""The C FMUs' shared FMI 2.0 plumbing (uiofmu/fmu/c/fmi2_plumbing.c) and its model interface.

(a) Through fmpy's low-level API (FMU2Slave): a step the sampled-data observer refuses
(fmi2Discard), the FMI 2.0 status queries after it (never fmi2Error), then valid steps whose
outputs equal the reference runtime's, as if the refused step had never been asked for.
(b) fmi2SetDebugLogging honours its categories: a category switched off writes nothing, an
unknown one is ignored with fmi2Warning and a log line (the known ones of the call apply).
(c) A second model plugged into the same plumbing (tests/c/kernel_toy.c, driven by
tests/c/plumbing_test.c under ASan and UBSan): Integer get/set, a Real call on an Integer
variable and the other way round, the error state and every call in it, and broken variable
tables refused by fmi2Instantiate. (The state masks of the observer FMUs, every function in every
state, are the fuzzer's scenario "state-masks", run by tests/test_c_hardening.py.)
(d) The generated variable table: one entry per value reference from the card's ports, and a
port the kernel does not implement refused at build time.
"""

from __future__ import annotations

import dataclasses
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.fmi2 import (fmi2DoStepStatus, fmi2LastSuccessfulTime, fmi2PendingStatus,
                       fmi2Terminated)

from uiofmu.fmu.c_backend import HERE, LOG_CATEGORIES, c_sources, design_source, fmi_headers, variable_table
from uiofmu.fmu.export import build_observer
from uiofmu.runtime.card import Card
from uiofmu.runtime.errors import FmuError
from uiofmu.runtime.kernels import KERNELS
from uiofmu.runtime.observer import Runtime
from uiofmu.runtime.ports import PortSpec

import cfuzz
from importers import LINES, Slave, debug_logging_status

ROOT = Path(__file__).resolve().parents[1]
TESTS_C = ROOT / "tests" / "c"

@pytest.fixture(scope="module")
def cfmus(example1_card, building_card, tmp_path_factory):
    d = tmp_path_factory.mktemp("plumbing")
    cards = {"lti-uio": example1_card[0], "sampled-data": building_card[0]}
    return {k: (card, build_observer(card, d / f"{k}.fmu", backend="c")) for k, card in cards.items()}


# -- (a) a refused step, the status queries, a master going on -------------------------------

def test_status_queries_after_a_refused_step_then_valid_steps(cfmus):
    card, path = cfmus["sampled-data"]
    assert card.schedule["kind"] == "interval" and card.schedule.get("step_policy", "error") == "error"
    rt = Runtime(card)
    rng = np.random.default_rng(15)
    steps = rt.schedule.admissible_steps()
    slave = Slave(path, "refused")
    fmu = slave.fmu
    y, u = slave.vector("y"), slave.vector("u")
    outs = slave.vector("xhat") + slave.vector("r") + slave.vector("dhat")
    try:
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        t = 0.0

        def step_both(h):
            yk, uk = rng.normal(22.0, 1.0, size=rt.p), rng.normal(size=rt.m)
            fmu.setReal(y, list(yk))
            fmu.setReal(u, list(uk))
            rt.set_y(yk)
            rt.set_u(uk)
            got = np.array(fmu.getReal(outs))
            want = np.concatenate([rt.xhat(), rt.residual(), rt.dhat()])
            np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * np.abs(want).max())
            fmu.doStep(t, h)
            rt.step(h)
            return t + h

        for _ in range(6):
            t = step_both(float(steps[int(rng.integers(len(steps)))]))
        bad = 0.75 * float(steps[0])                               # between design intervals: refused
        assert slave.status("doStep", t, bad) == (2, None)
        assert any(s == 2 and c == "logStatusDiscard" and "is not one of the design intervals" in m
                   for s, c, m in slave.lines())
        assert slave.status("getRealStatus", fmi2LastSuccessfulTime) == (0, t)
        # a step refused for ever: fmi2Terminated asks the master to end (fmpy would repeat the step otherwise)
        assert slave.status("getBooleanStatus", fmi2Terminated) == (0, True)
        # no step is ever pending: "fmi2Discard is returned also if the slave is not able to return the
        # required status information" (FMI 2.0.x, 2.1.3)
        assert slave.status("getStatus", fmi2DoStepStatus)[0] == 2
        assert slave.status("getStringStatus", fmi2PendingStatus)[0] == 2
        assert any("no fmi2DoStep is pending" in m for _, _, m in slave.lines())
        for call, kind in (("getRealStatus", fmi2Terminated), ("getBooleanStatus", fmi2LastSuccessfulTime),
                           ("getIntegerStatus", fmi2DoStepStatus), ("getStatus", 9)):
            assert slave.status(call, kind)[0] == 3, (call, kind)    # a kind of another type, or none
        assert slave.lines()[-1][1] == "logStatusError"
        for _ in range(25):                                         # the master goes on with valid steps
            t = step_both(float(steps[int(rng.integers(len(steps)))]))
        assert slave.status("getRealStatus", fmi2LastSuccessfulTime) == (0, t)
        assert slave.status("getBooleanStatus", fmi2Terminated) == (0, False)   # it took the other steps
        fmu.terminate()
    finally:
        slave.close()


def test_a_refused_step_leaves_the_instance_bit_for_bit_where_it_was(cfmus):
    """Twin instances, one of which is refused a step (and asked the status queries) in the middle:
    the same outputs, bit for bit, before and after."""
    _, path = cfmus["lti-uio"]
    a, b = Slave(path, "a"), Slave(path, "b")
    rng = np.random.default_rng(3)
    try:
        for s in (a, b):
            s.fmu.setupExperiment(startTime=0.0)
            s.fmu.enterInitializationMode()
            s.fmu.exitInitializationMode()
        outs = a.vector("xhat") + a.vector("r")
        for k in range(40):
            y, u = list(rng.normal(size=1)), list(rng.normal(size=1))
            if k == 20:
                assert a.status("doStep", 2.0, 0.25) == (2, None)
                assert a.status("getRealStatus", fmi2LastSuccessfulTime) == (0, 2.0)
                assert a.status("getBooleanStatus", fmi2Terminated) == (0, True)
            for s in (a, b):
                s.fmu.setReal(s.vector("y"), y)
                s.fmu.setReal(s.vector("u"), u)
            assert a.fmu.getReal(outs) == b.fmu.getReal(outs)
            for s in (a, b):
                s.fmu.doStep(0.1 * k, 0.1)
    finally:
        a.close()
        b.close()


# -- (b) log categories ----------------------------------------------------------------------

def test_debug_logging_honours_its_categories(cfmus):
    _, path = cfmus["lti-uio"]
    s = Slave(path, "logging", logging_on=False)
    fmu = s.fmu

    def new_lines(action):
        before = len(s.lines())
        action()
        return s.lines()[before:]

    def refused_step():                                          # fmi2Discard
        assert s.status("doStep", 0.0, 0.25)[0] == 2

    def bad_reference():                                         # fmi2Error
        assert s.status("getReal", [10_000])[0] == 3

    try:
        assert s.lines() == []                                   # loggingOn = false: no logEvents line
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        assert s.lines() == []
        assert [c for _, c, _ in new_lines(refused_step)] == ["logStatusDiscard"]   # status categories are on
        assert [c for _, c, _ in new_lines(bad_reference)] == ["logStatusError"]
        fmu.setDebugLogging(True, ["logStatusError"])            # only errors
        assert new_lines(refused_step) == []
        assert [c for _, c, _ in new_lines(bad_reference)] == ["logStatusError"]
        fmu.setDebugLogging(True, [])                            # everything
        lines = new_lines(lambda: fmu.setFMUstate(fmu.getFMUstate()))
        assert [c for _, c, _ in lines] == ["logEvents"] and "step complete" in lines[0][2]
        fmu.setDebugLogging(False, ["logStatusDiscard", "logEvents"])   # those off, the rest kept
        assert new_lines(refused_step) == []
        assert new_lines(lambda: fmu.setFMUstate(fmu.getFMUstate())) == []
        assert [c for _, c, _ in new_lines(bad_reference)] == ["logStatusError"]
        lines = new_lines(lambda: s.status("setDebugLogging", True, ["logStatusError", "logVerbose"]))
        assert len(lines) == 1 and lines[0][:2] == (1, "logStatusWarning")    # fmi2Warning: ignored
        assert 'categories[1] = "logVerbose" is not a log category of this FMU' in lines[0][2]
        assert new_lines(refused_step) == []                     # the known one applied: only errors
        assert [c for _, c, _ in new_lines(bad_reference)] == ["logStatusError"]
        assert new_lines(lambda: s.status("setDebugLogging", True, ["logVerbose"])) == []   # warnings are off
        assert debug_logging_status(fmu, True, ["logVerbose"]) == 1
        assert new_lines(bad_reference) == []                    # no known category named: nothing on
        fmu.setDebugLogging(False, [])                           # nothing at all
        assert new_lines(refused_step) == [] and new_lines(bad_reference) == []
        assert new_lines(lambda: s.status("setDebugLogging", True, ["nonsense"])) == []
        assert {c for _, _, c, _ in LINES} <= set(LOG_CATEGORIES)
    finally:
        s.close()


def test_model_description_declares_categories_the_fmu_honours(cfmus):
    _, path = cfmus["lti-uio"]
    assert {c.name for c in read_model_description(str(path)).logCategories} <= set(LOG_CATEGORIES)


# -- (c) a second model on the same plumbing, under the sanitizers ---------------------------

SANITIZE = cfuzz.SANITIZER_FLAGS


def _toy(tmp_path, table: int = 0) -> Path:
    exe = tmp_path / f"plumbing_test_{table}"
    cmd = ["gcc", "-std=c99", *SANITIZE, "-Wall", "-Wextra", f"-DTOY_TABLE={table}", f"-I{HERE}",
           f"-I{fmi_headers()}", "-o", str(exe), str(TESTS_C / "plumbing_test.c"), str(TESTS_C / "kernel_toy.c"),
           str(HERE / "fmi2_plumbing.c"), "-lm"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    return exe


def _run(*cmd):
    proc = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, env=cfuzz._env(), timeout=120)
    assert not any(mark in proc.stderr for mark in cfuzz.SANITIZER_MARKS), proc.stderr[-3000:]
    return proc


def test_a_second_kernel_plugs_into_the_plumbing(tmp_path):
    proc = _run(_toy(tmp_path), "run")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "plumbing_test run: 0 failed checks" in proc.stdout


def test_a_kernel_can_give_the_storage_of_its_real_variables_instead_of_get_and_set(tmp_path):
    proc = _run(_toy(tmp_path, 9), "run")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "plumbing_test run: 0 failed checks" in proc.stdout


def test_the_plumbing_applies_the_step_rule(tmp_path):
    proc = _run(_toy(tmp_path), "steps")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "plumbing_test steps: 0 failed checks" in proc.stdout


@pytest.mark.parametrize("table,fragment", [
    (1, "value reference 2: element 1 of port u, expected element 0"),
    (2, "value reference 1 (mode[1]) is listed as an input Real, the kernel's port is an input Integer"),
    (3, "value reference 5: port 8 is none of the toy kernel's"),
    (4, "port u has 2 elements in this design, the variable table lists 1"),
    (5, "value reference 4: element 2 of port u, which has 2 in this design"),
    (6, "admissible step 1 = 1e-12: expected a finite step above 2.5e-10"),
    (7, "value reference 0 (x0[1]) is a Real the kernel cannot get or set"),
    (8, "the toy kernel has no storage for value reference 4"),
])
def test_instantiate_refuses_a_broken_variable_table(tmp_path, table, fragment):
    proc = _run(_toy(tmp_path, table), "refused", fragment)
    assert proc.returncode == 0, proc.stderr[-3000:]


# -- (d) the generated table -----------------------------------------------------------------

def test_the_table_has_one_entry_per_value_reference(cfmus):
    card, path = cfmus["sampled-data"]
    text = design_source(card, "1" * 8, "obs")
    refs = {v.name: v.valueReference for v in read_model_description(str(path)).modelVariables}
    rows = variable_table(card)
    assert len(rows) == len(refs) == sum(p.size for p in card.ports)
    assert rows[refs["h_prev0[1]"]] == "    {UIOFMU_AFFINE_H_PREV0, 0, UIOFMU_PARAMETER, UIOFMU_REAL},"
    assert rows[refs["xhat[2]"]] == "    {UIOFMU_AFFINE_XHAT, 1, UIOFMU_OUTPUT, UIOFMU_REAL},"
    assert all(row in text for row in rows) and f".nvariables = {len(rows)}," in text
    assert c_sources(card) == ["fmi2_plumbing.c", "kernel_util.c", "kernel_affine.c", "design_data.c"]


@pytest.mark.parametrize("ports,fragment", [
    ([PortSpec("theta", 1, "input", "scheduling parameter")], "the C affine kernel has no port 'theta'"),
    ([PortSpec("xhat", 2, "input", "estimate")], "port xhat: declared an input Real, the C affine kernel implements "
                                                 "an output Real"),
    ([PortSpec("y", 1, "input", "measurement", type="Integer")], "port y: declared an input Integer"),
])
def test_a_port_the_kernel_does_not_implement_is_refused_at_build_time(example1_card, monkeypatch, ports, fragment):
    card = example1_card[0]
    declared = card.ports
    monkeypatch.setattr(Card, "ports", property(lambda self: [*declared, *ports]))
    with pytest.raises(FmuError, match=re.escape(fragment)):
        design_source(card, "1" * 8, "obs")


def test_a_kernel_without_c_code_is_refused_at_build_time(example1_card, monkeypatch, tmp_path):
    unknown = dataclasses.replace(KERNELS["affine"], name="no-such-kernel", c_kernel="no-such-kernel")
    monkeypatch.setattr(Card, "stepper", property(lambda self: unknown))
    with pytest.raises(FmuError, match="the C backend has no kernel 'no-such-kernel'"):
        build_observer(example1_card[0], tmp_path / "o.fmu", backend="c")
