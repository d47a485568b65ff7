"""The C backend: standalone native observer FMUs of the affine kernel, against the reference runtime, in
three importers. What every kernel's FMU owes (its runtime on random steps, state round trips, refusals) is
checked in tests/test_conformance.py."""

from __future__ import annotations

import shutil
import subprocess
import zipfile

import numpy as np
import pytest
from fmpy import read_model_description

from uiofmu.fmu.c_backend import build_host
from uiofmu.cosim.fmi import Fmu, FmuCallError
from uiofmu.runtime.observer import Runtime
from uiofmu.cosim.validate import validate


#: The session card fixture of each family (conftest.py).
CARDS = {"lti-uio": "example1_card", "sampled-data": "building_card", "ltv-auid": "ltv_card"}


@pytest.fixture(scope="module")
def cfmus(observer_fmus):
    """``{family: (card, C observer FMU)}``, the FMUs built once per session (tests/test_conformance.py checks
    each against its runtime, its state round trips and its refusals)."""
    return {family: observer_fmus(name, "c") for family, name in CARDS.items()}


def test_same_interface_as_the_python_backend(cfmus, observer_fmus):
    _, path = cfmus["sampled-data"]
    _, py = observer_fmus(CARDS["sampled-data"], "python")
    a, b = read_model_description(str(path)), read_model_description(str(py))
    key = lambda v: (v.name, v.valueReference, v.causality, v.variability, v.initial,  # noqa: E731
                     None if v.start is None else float(v.start))
    assert [key(v) for v in a.modelVariables] == [key(v) for v in b.modelVariables]


@pytest.mark.parametrize("case,status,fragment", [   # NaN inputs and steps off the design: test_conformance.py
    ("zero-step", 3, "expected h > 0"),
    ("before-init", 3, "called before fmi2ExitInitializationMode"),
    ("after-terminate", 3, "after fmi2Terminate"),
])
def test_bad_calls_return_error_with_a_log_line(cfmus, case, status, fragment):
    _, path = cfmus["sampled-data"]
    with Fmu(path, "o") as fmu:
        if case != "before-init":
            fmu.initialize(0.0)
        if case == "after-terminate":
            fmu.slave.terminate()
        h = {"zero-step": 0.0}.get(case, 600.0)
        with pytest.raises(FmuCallError) as info:
            fmu.step(0.0, h)
        assert info.value.status == status
        assert any(fragment in m for m in info.value.messages), info.value.messages
        if case == "zero-step":                                 # nothing changed; the instance goes on
            fmu.set("y", [22.0])
            fmu.step(0.0, 600.0)


def test_setting_an_output_or_a_fixed_parameter_late_is_an_error(cfmus):
    _, path = cfmus["lti-uio"]
    with Fmu(path, "o") as fmu:
        fmu.initialize(0.0)
        with pytest.raises(FmuCallError) as info:
            fmu.set("xhat", [1.0, 2.0])
        assert info.value.status == 3 and "is an output" in info.value.messages[-1]
        with pytest.raises(FmuCallError) as info:
            fmu.set("xhat0", [1.0, 2.0])
        assert "fixed parameter" in info.value.messages[-1]


def test_many_instances_share_nothing(cfmus):
    card, path = cfmus["ltv-auid"]
    rng = np.random.default_rng(4)
    count, steps = 12, 40
    ys = rng.normal(size=(count, steps, 1))
    us = rng.normal(size=(count, steps, 1))
    fmus = [Fmu(path, f"o{i}") for i in range(count)]
    try:
        for i, f in enumerate(fmus):
            f.initialize(0.0, {"xhat0": [float(i), -float(i)]})
        outs = np.zeros((count, steps, 2))
        for k in range(steps):
            for i, f in enumerate(fmus):
                f.set("y", ys[i, k])
                f.set("u", us[i, k])
                outs[i, k] = f.get("xhat")
                f.step(0.1 * k, 0.1)
    finally:
        for f in fmus:
            f.close()
    for i in range(count):
        rt = Runtime(card, xhat0=[float(i), -float(i)])
        for k in range(steps):
            rt.set_y(ys[i, k])
            rt.set_u(us[i, k])
            np.testing.assert_allclose(outs[i, k], rt.xhat(), rtol=1e-12, atol=1e-14)
            rt.step(0.1)


def _host_run(cfmus, family, tmp_path, wrapper=(), refused_at=None):
    card, path = cfmus[family]
    unzip = tmp_path / family
    with zipfile.ZipFile(path) as z:
        z.extractall(unzip)
    md = read_model_description(str(path))
    host = build_host(tmp_path / "host")
    rt = Runtime(card)
    rng = np.random.default_rng(21)
    steps = rt.schedule.admissible_steps()
    rows, expect = [], []
    for k in range(60):
        h = float(steps[int(rng.integers(len(steps)))]) if k != refused_at else 0.75 * steps[0]
        y, u = rng.normal(size=rt.p), rng.normal(size=rt.m)
        rt.set_y(y)
        rt.set_u(u)
        expect.append(np.concatenate([rt.xhat(), rt.residual()]))
        if k != refused_at:
            rt.step(h)
        rows.append(" ".join(repr(float(v)) for v in [h, *y, *u]))
    (tmp_path / "steps.txt").write_text("\n".join(rows) + "\n")
    refs = {v.name: v.valueReference for v in md.modelVariables}
    ins = [refs[f"y[{i + 1}]"] for i in range(rt.p)] + [refs[f"u[{i + 1}]"] for i in range(rt.m)]
    outs = [refs[f"xhat[{i + 1}]"] for i in range(rt.n)] + [refs[f"r[{i + 1}]"] for i in range(rt.p)]
    cmd = [*wrapper, str(host), str(unzip / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so"),
           md.guid, (unzip / "resources").as_uri(), ",".join(map(str, ins)) or "-", ",".join(map(str, outs)),
           str(tmp_path / "steps.txt")]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    return proc, np.array(expect)


@pytest.mark.parametrize("family", ["sampled-data", "ltv-auid"])
def test_c_host_without_python(cfmus, family, tmp_path):
    proc, expect = _host_run(cfmus, family, tmp_path)
    assert proc.returncode == 0, proc.stderr
    got = np.array([[float(v) for v in line.split()] for line in proc.stdout.splitlines()])
    np.testing.assert_allclose(got, expect, rtol=1e-12, atol=1e-12 * np.abs(expect).max())


VALGRIND = ("valgrind", "--error-exitcode=3", "--leak-check=full", "--errors-for-leak-kinds=definite", "--quiet")


@pytest.mark.valgrind
def test_c_host_under_valgrind(cfmus, tmp_path):
    proc, _ = _host_run(cfmus, "ltv-auid", tmp_path, wrapper=VALGRIND)
    assert proc.returncode == 0, proc.stderr
    assert "ERROR SUMMARY" not in proc.stderr or "0 errors" in proc.stderr


@pytest.mark.valgrind
def test_c_host_under_valgrind_with_a_refused_step(cfmus, tmp_path):
    """A step outside the design intervals: fmi2Discard with its log line, no memory error or leak."""
    proc, _ = _host_run(cfmus, "sampled-data", tmp_path, wrapper=VALGRIND, refused_at=20)
    assert proc.returncode == 2, proc.stderr          # the host's own status for a refused step (3 = valgrind)
    assert "is not one of the design intervals" in proc.stderr
    assert "fmi2DoStep returned 2 at row 20" in proc.stderr
    assert "definitely lost" not in proc.stderr


def test_libcosimpy_runs_the_c_fmu(cfmus):
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    log_output_level(CosimLogLevel.ERROR)
    card, path = cfmus["lti-uio"]
    md = read_model_description(str(path))
    refs = {v.name: v.valueReference for v in md.modelVariables}
    ex = CosimExecution.from_step_size(step_size=int(round(card.dt * 1e9)))
    idx = ex.add_local_slave(local_slave=CosimLocalSlave(fmu_path=str(path), instance_name="observer"))
    obs = CosimObserver.create_last_value()
    ex.add_observer(observer=obs)
    ex.real_initial_value(slave_index=idx, variable_reference=refs["y[1]"], value=1.0)
    assert ex.step(step_count=25)
    got = obs.last_real_values(slave_index=idx, variable_references=[refs["xhat[1]"], refs["xhat[2]"]])
    rt = Runtime(card)
    rt.set_y([1.0])
    for _ in range(25):
        rt.step(card.dt)
    np.testing.assert_allclose(got, rt.xhat(), rtol=1e-12)


@pytest.mark.cmake
def test_fmpy_compile_rebuilds_from_sources(cfmus, tmp_path):
    """The binary removed, fmpy's build (cmake, its own FMI headers) makes a new one from sources/."""
    from fmpy import extract
    from fmpy.build import build_platform_binary
    from fmpy.util import create_zip_archive

    _, path = cfmus["ltv-auid"]
    unzip = tmp_path / "unzip"
    extract(str(path), unzipdir=str(unzip))
    shutil.rmtree(unzip / "binaries")
    build_platform_binary(unzipdir=str(unzip))
    rebuilt = tmp_path / "rebuilt.fmu"
    create_zip_archive(str(rebuilt), str(unzip))
    assert validate(rebuilt, steps=100).ok


def test_build_defaults_to_c(example1_card, cli, tmp_path):
    _, card_path = example1_card
    res = cli("build", card_path, "-o", tmp_path / "o.fmu")
    assert res.code == 0 and "(c backend)" in res.out
    assert read_model_description(str(tmp_path / "o.fmu")).coSimulation.needsExecutionTool is False
