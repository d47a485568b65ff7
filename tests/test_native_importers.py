"""Catalogue FMUs alone in the FMU Compliance Checker and in fmusim (``uiofmu/cosim/native_importers.py``).

(a) Two examples of the catalogue (the example 1 observer of one step and its discrete plant; the
building's observer of design intervals and its continuous plant), built as ``make fmus`` builds them,
run in both importers at their DefaultExperiment's step to its stop time: 0 errors, a row at the stop
time, finite outputs; the checker's only warning is the fixed-step one, fmusim's none.
(b) ``make fmus``'s part (:func:`uiofmu.catalogue.run_native_importers`) reports no failure on them,
and prints one ``ok`` line per FMU and importer; a step the observer refuses fails, in one line naming
the FMU and the FMU's own line.
(c) An importer that is absent, not executable or missing a shared library is named, not run, and
``make fmus`` goes on; the importers see ``PATH`` and no Python variable; a non-finite output is an error.

The importers are ``../shared/importers/`` next to the repository, or ``$UIOFMU_FMUCHECK`` and
``$UIOFMU_FMUSIM``; where one is not there or cannot start (fmusim needs libminizip1 and
libsundials-cvode6, see that folder's README), (a) and (b) skip with the reason.
"""

from __future__ import annotations

import dataclasses
import os

import pytest

from cfmu import NEEDS_CC
from conftest import ROOT
from uiofmu import catalogue as cat
from uiofmu.cosim.native_importers import (FIXED_STEP_WARNING, FMUCHECK, FMUSIM, bare_environment,
                                           importer_unavailable, run_compliance_checker, run_fmusim)

RUNS = {"fmuCheck": run_compliance_checker, "fmusim": run_fmusim}
KEYS = ("seed000-example1", "two-room-building")


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """A catalogue of two examples, its four FMUs built as ``make fmus`` builds them: ``(catalogue, paths)``."""
    designs = [d for key in KEYS for d in cat.describe(ROOT, key).designs]
    catalogue = cat.Catalogue(designs)
    return catalogue, cat.build(catalogue, tmp_path_factory.mktemp("native_importers"), ROOT)


def _ran(run):
    if not run.ran:
        pytest.skip(run.unavailable)
    return run


# -- (a) -------------------------------------------------------------------------------------------------------

@NEEDS_CC
@pytest.mark.parametrize("tool", sorted(RUNS))
def test_each_fmu_runs_alone_to_its_stop_time(built, tool, tmp_path):
    catalogue, paths = built
    assert [r.backend for r in catalogue.rows] == ["C"] * 4
    for row in catalogue.rows:
        step, stop = row.experiment["stepSize"], row.experiment["stopTime"]
        run = _ran(RUNS[tool](paths[row.file], step, stop, workdir=tmp_path / row.file))
        assert run.ok and not run.errors, (row.file, run.errors, run.log[-2000:])
        assert run.stop_time == pytest.approx(stop, rel=1e-12), row.file
        assert len(run.rows) >= round(stop / step) + 1, row.file           # a row at every step
        fixed = row.steps.endswith("only")
        if tool == "fmuCheck":
            assert all(FIXED_STEP_WARNING in w for w in run.warnings), run.warnings
            assert bool(run.warnings) is fixed, row.file
        else:
            assert run.warnings == () and run.last_time == stop, row.file   # fmusim ends on the stop time


# -- (b) -------------------------------------------------------------------------------------------------------

def _both_there():
    for tool in (FMUCHECK, FMUSIM):
        if why := importer_unavailable(tool):          # absent, or the loader misses a library it needs
            pytest.skip(why)


@NEEDS_CC
def test_make_fmus_runs_every_fmu_in_both(built, capsys):
    _both_there()
    catalogue, paths = built
    assert cat.run_native_importers(catalogue, paths) == []
    out = capsys.readouterr().out
    assert "not run" not in out and "FAILED" not in out, out
    for row in catalogue.rows:
        for tool in RUNS:
            assert f"  {row.file}: {tool} ok to t = " in out, (row.file, tool, out)


@NEEDS_CC
def test_a_refused_step_fails_make_fmus_in_one_line_naming_the_fmu(built, capsys):
    _both_there()
    catalogue, paths = built
    design = catalogue.designs[0]
    observer = design.observer                                         # h = 0.1 s only
    halved = dataclasses.replace(observer, experiment={**observer.experiment, "stepSize": 0.05})
    failures = cat.run_native_importers(cat.Catalogue([dataclasses.replace(design, observer=halved)]), paths)
    assert [line.split(": ")[:2] for line in failures] == [[observer.file, "fmuCheck"], [observer.file, "fmusim"]]
    for line in failures:
        assert "this observer was designed for steps of dt = 0.1 s and received h = 0.05 s" in line, line
        assert "Discard" in line, line
    out = capsys.readouterr().out
    assert f"  {observer.file}: fmuCheck FAILED" in out and f"  {design.plant.file}: fmusim ok to t = " in out, out


@NEEDS_CC
@pytest.mark.parametrize("tool", sorted(RUNS))
def test_a_refused_step_is_an_error_and_the_run_stops_short(built, tool, tmp_path):
    catalogue, paths = built
    observer = catalogue.designs[0].observer
    run = _ran(RUNS[tool](paths[observer.file], 0.05, 1.0, workdir=tmp_path))
    assert not run.ok and not run.reached_stop and run.last_time < 0.1
    assert "received h = 0.05 s" in run.problem() and "Discard" in run.problem()


# -- (c) -------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("tool", sorted(RUNS))
def test_an_absent_importer_is_named_and_not_run(tool, monkeypatch, tmp_path):
    variable = {"fmuCheck": FMUCHECK, "fmusim": FMUSIM}[tool][1]
    monkeypatch.setenv(variable, str(tmp_path / "nowhere"))
    run = RUNS[tool](tmp_path / "any.fmu", 0.1, 1.0)
    assert not run.ran and not run.ok and run.errors == ()
    assert run.unavailable == f"{tmp_path / 'nowhere'} is not there (set ${variable}, or see " \
                              "../shared/importers/README.md)"
    assert run.problem() == f"not run: {run.unavailable}"


def test_make_fmus_goes_on_without_them(monkeypatch, tmp_path, capsys):
    for _, variable in (FMUCHECK, FMUSIM):
        monkeypatch.setenv(variable, str(tmp_path / "nowhere"))
    catalogue = cat.Catalogue([cat.design_example(cat.EXAMPLES[0], ROOT)])
    paths = {row.file: tmp_path / row.file for row in catalogue.rows}
    assert cat.run_native_importers(catalogue, paths) == []
    out = capsys.readouterr().out
    assert out.count(" not run: ") == 2 and "fmuCheck not run" in out and "fmusim not run" in out, out


def _program(path, text: str, mode: int = 0o755):
    path.write_text(text)
    path.chmod(mode)
    return path


def test_an_importer_that_cannot_start_is_named(monkeypatch, tmp_path):
    monkeypatch.setenv(FMUSIM[1], str(_program(tmp_path / "fmusim", "#!/bin/sh\nexit 0\n", 0o644)))
    assert run_fmusim(tmp_path / "any.fmu", 0.1, 1.0).unavailable == f"{tmp_path / 'fmusim'} is not executable"
    loader = ("fmusim: error while loading shared libraries: libsundials_cvode.so.6: cannot open shared object "
              "file: No such file or directory")
    monkeypatch.setenv(FMUSIM[1], str(_program(tmp_path / "fmusim2", f"#!/bin/sh\necho '{loader}' >&2\nexit 127\n")))
    run = run_fmusim(tmp_path / "any.fmu", 0.1, 1.0)
    assert run.unavailable == f"{tmp_path / 'fmusim2'} cannot start: {loader}"


def test_the_importers_see_path_and_no_python_variable(monkeypatch, tmp_path):
    monkeypatch.setenv("PYTHONPATH", str(ROOT))
    monkeypatch.setenv("VIRTUAL_ENV", str(ROOT / ".venv"))
    monkeypatch.setenv(FMUCHECK[1], str(_program(tmp_path / "fmuCheck", "#!/bin/sh\nenv\n")))
    run = run_compliance_checker(tmp_path / "any.fmu", 0.1, 1.0, workdir=tmp_path)
    assert bare_environment() == {"PATH": os.environ["PATH"]}
    assert f"PATH={os.environ['PATH']}" in run.log.splitlines()
    assert "PYTHON" not in run.log and "VIRTUAL_ENV" not in run.log, run.log
    assert not run.ok and "the checker wrote no summary (it stopped early)" in run.errors


def test_a_non_finite_output_is_an_error(monkeypatch, tmp_path):
    script = ('#!/bin/sh\nwhile [ $# -gt 0 ]; do [ "$1" = --output-file ] && out=$2; shift; done\n'
              'printf \'"time","x[1]"\\n0,1\\n0.1,nan\\n\' > "$out"\n')
    monkeypatch.setenv(FMUSIM[1], str(_program(tmp_path / "fmusim", script)))
    run = run_fmusim(tmp_path / "any.fmu", 0.1, 0.1, workdir=tmp_path / "run")
    assert run.times == (0.0, 0.1) and run.reached_stop
    assert run.errors == ("the output x[1] is nan at t = 0.1",) and not run.ok
