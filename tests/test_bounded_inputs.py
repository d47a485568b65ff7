"""Inputs that are bounded before they cost: FMU archives, model descriptions, Integer inputs, step
files and signal parameters (the red team's five findings, each through the real command line).

1. An FMU whose entries unpack to more than uiofmu ever needs (a zip bomb) is refused from its zip
   directory, before anything is extracted.
2. A model description with more variables (or elements, or longer dependency lists) than any FMU
   uiofmu drives is refused before fmpy parses it.
3. A value for an FMI Integer input (``mode``) that is not an fmi2Integer is refused where it is read
   (``[signals]``, a CSV column) and where the master or :meth:`Fmu.set` sets it, never wrapped.
4. A step file's content never appears in a message (the path may name any file).
5. Every number of a signal is bounded, and a run that takes a random term's ``hold`` or a sine's
   argument past the exact integers of a float is refused naming the key.
"""

from __future__ import annotations

import copy
import json
import struct
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import EXAMPLES, run_cli
from uiofmu.cosim import fmi, fmu_cache
from uiofmu.problem import load_problem, to_toml
from uiofmu.runtime.errors import FmuError, ProblemError

SECRET = "root:x:0:0:SECRET-hunter2:/root:/bin/bash"


def _ok(*argv) -> None:
    res = run_cli(*map(str, argv))
    assert res.code == 0, res.err


def _refused(res, *fragments) -> str:
    """A one-line exit 2 holding every fragment; returns the line."""
    assert res.code == 2, (res.code, res.err)
    lines = res.err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in res.err and ": error: " in lines[0], res.err
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])
    return lines[0]


@pytest.fixture(scope="module")
def ex1(tmp_path_factory):
    """Seed 000 Example 1: its card, observer FMU (C backend) and plant FMU."""
    out = tmp_path_factory.mktemp("ex1")
    _ok("design", EXAMPLES / "seed000_example1.toml", "-o", out / "card.json")
    _ok("build", out / "card.json", "-o", out / "observer.fmu")
    _ok("plant", EXAMPLES / "seed000_example1.toml", "-o", out / "plant.fmu")
    return out


@pytest.fixture
def scratch(tmp_path, monkeypatch) -> Path:
    """An empty folder that is the process's temporary folder: where an FMU would be extracted."""
    folder = tmp_path / "tmp"
    folder.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(folder))
    return folder


def _members(fmu: Path) -> dict:
    with zipfile.ZipFile(fmu) as z:
        return {info.filename: z.read(info) for info in z.infolist()}


def _write_fmu(path: Path, members: dict, zeros: int = 0) -> Path:
    """An FMU of ``members`` plus, when ``zeros``, an entry ``resources/zeros.bin`` of that many zero bytes
    deflated from a stream of 4 MiB chunks (a few kB in the archive)."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for name, data in members.items():
            z.writestr(name, data)
        if zeros:
            info = zipfile.ZipInfo("resources/zeros.bin")
            info.compress_type = zipfile.ZIP_DEFLATED
            chunk = bytes(4 * 2**20)
            with z.open(info, "w", force_zip64=True) as f:
                for start in range(0, zeros, len(chunk)):
                    f.write(chunk[:min(len(chunk), zeros - start)])
    return path


def _declare_size(path: Path, name: str, size: int) -> None:
    """Make the zip directory and local header of entry ``name`` declare ``size`` unpacked bytes (< 4 GiB)."""
    data = bytearray(path.read_bytes())
    with zipfile.ZipFile(path) as z:
        local = z.getinfo(name).header_offset
    struct.pack_into("<I", data, local + 22, size)
    at = data.find(b"PK\x01\x02")                          # the directory: records of 46 bytes and the name
    while data[at + 46:at + 46 + struct.unpack_from("<H", data, at + 28)[0]] != name.encode():
        at = data.find(b"PK\x01\x02", at + 4)
        assert at > 0
    struct.pack_into("<I", data, at + 24, size)
    path.write_bytes(bytes(data))


def _cosim(ex1, observer, out, *extra):
    return run_cli("cosim", "--plant", ex1 / "plant.fmu", "--observer", observer, "--t-end", "1", "--out", out,
                   *map(str, extra))


# -- 1. archives --------------------------------------------------------------------------------

def test_an_entry_declaring_3_gib_is_refused_by_the_default_limit(ex1, tmp_path, scratch):
    """The default MAX_ENTRY_BYTES refuses an entry from the size its directory declares: nothing is read."""
    bomb = _write_fmu(tmp_path / "bomb.fmu", {**_members(ex1 / "observer.fmu"), "resources/big.bin": bytes(1024)})
    _declare_size(bomb, "resources/big.bin", 3 * 2**30)
    start = time.perf_counter()
    for res in (run_cli("validate", bomb, "--steps", "3"), _cosim(ex1, bomb, tmp_path / "run")):
        _refused(res, "'resources/big.bin' unpacks to 3221225472 bytes", f"limit of {fmi.MAX_ENTRY_BYTES}",
                 "uiofmu.cosim.fmi.MAX_ENTRY_BYTES")
    assert time.perf_counter() - start < 10
    assert not list(scratch.iterdir()) and not (tmp_path / "run").exists()


def test_deflated_zeros_are_refused_by_their_ratio_before_extraction(ex1, tmp_path, scratch):
    """64 MiB of zeros deflate to about 64 kB: the default MAX_RATIO refuses the entry, validate and cosim
    exit 2 within seconds, and nothing is extracted (before: the whole entry was written to disk)."""
    bomb = _write_fmu(tmp_path / "bomb.fmu", _members(ex1 / "observer.fmu"), zeros=64 * 2**20)
    assert bomb.stat().st_size < 2**20
    start = time.perf_counter()
    for res in (run_cli("validate", bomb, "--steps", "3"), _cosim(ex1, bomb, tmp_path / "run")):
        line = _refused(res, "'resources/zeros.bin' unpacks to 67108864 bytes", "a compression ratio of",
                        f"limit of {fmi.MAX_RATIO} (uiofmu.cosim.fmi.MAX_RATIO)")
        assert int(line.split("a compression ratio of ")[1].split()[0]) > 500, line
    assert time.perf_counter() - start < 10
    assert not list(scratch.iterdir()) and not (tmp_path / "run").exists()


@pytest.mark.parametrize("limits,fragment", [
    ({"MAX_RATIO": 10**6, "MAX_UNPACKED_BYTES": 32 * 2**20}, "the FMU unpacks to 67"),
    ({"MAX_RATIO": 10**6, "MAX_ENTRY_BYTES": 32 * 2**20}, "'resources/zeros.bin' unpacks to 67108864 bytes"),
])
def test_lowered_size_limits_refuse_a_stream_of_zeros(ex1, tmp_path, scratch, monkeypatch, limits, fragment):
    bomb = _write_fmu(tmp_path / "bomb.fmu", _members(ex1 / "observer.fmu"), zeros=64 * 2**20)
    for name, value in limits.items():
        monkeypatch.setattr(fmi, name, value)
    limit = [n for n in limits if n != "MAX_RATIO"][0]
    _refused(_cosim(ex1, bomb, tmp_path / "run"), fragment, f"limit of {32 * 2**20} (uiofmu.cosim.fmi.{limit})")
    assert not list(scratch.iterdir())


def test_the_untouched_fmu_passes_the_limits(ex1, scratch):
    assert run_cli("validate", ex1 / "observer.fmu", "--steps", "3").code == 0
    # the extracted copy is kept for the process in its private folder, which goes at exit (test_fmu_cache.py)
    assert not [p for p in scratch.iterdir() if p != fmu_cache.folder()]


@pytest.mark.parametrize("entries", [10_001, 65_600])       # 65,600: a zip64 end record holds the count
def test_an_archive_of_too_many_entries_is_refused_from_its_end_record(tmp_path, entries):
    path = tmp_path / "many.fmu"
    with zipfile.ZipFile(path, "w") as z:
        for i in range(entries):
            z.writestr(f"e{i}", b"")
    assert fmi._declared_entries(path)[0] == entries
    with pytest.raises(FmuError, match=rf"declares {entries} entries, more than the limit of 10000 "
                                       r"\(uiofmu.cosim.fmi.MAX_ENTRIES\)"):
        fmi.check_archive(path)


def test_an_end_record_that_understates_its_entries_is_refused_by_its_directory_size(tmp_path):
    """200,000 entries whose end record says 1: zipfile would parse the whole directory (1.5 s, 100 MB)
    before the entry count is seen; its declared size is refused first, at once."""
    path = tmp_path / "many.fmu"
    with zipfile.ZipFile(path, "w") as z:
        for i in range(200_000):
            z.writestr(f"e{i}", b"")
    data = bytearray(path.read_bytes())
    at = data.rfind(b"PK\x05\x06")
    struct.pack_into("<HH", data, at + 8, 1, 1)
    path.write_bytes(bytes(data))
    began = time.perf_counter()
    with pytest.raises(FmuError, match=r"central directory has \d+ bytes, more than the limit of 5120000 "
                                       r"\(uiofmu.cosim.fmi.MAX_DIRECTORY_BYTES\)"):
        fmi.check_archive(path)
    assert time.perf_counter() - began < 0.1


# -- 2. model descriptions ----------------------------------------------------------------------

def _with_variables(ex1, path: Path, count: int, description=None) -> Path:
    """The observer FMU with ``count`` local variables added to its model description (or the description
    ``description(xml)`` returns)."""
    members = _members(ex1 / "observer.fmu")
    xml = members["modelDescription.xml"].decode()
    extra = "".join(f'<ScalarVariable name="junk[{k + 1}]" valueReference="{1000 + k}" causality="local" '
                    f'variability="continuous" initial="calculated"><Real /></ScalarVariable>' for k in range(count))
    xml = xml.replace("</ModelVariables>", extra + "</ModelVariables>")
    members["modelDescription.xml"] = (description(xml) if description else xml).encode()
    return _write_fmu(path, members)


def test_validate_refuses_more_variables_than_a_uiofmu_fmu_has(ex1, tmp_path, scratch):
    """16,001 variables: fmpy's name check alone took 19 s there (1.2 ms a variable); refused at once."""
    fmu = _with_variables(ex1, tmp_path / "many.fmu", fmi.MAX_OWN_VARIABLES - 7)      # the FMU has 8
    start = time.perf_counter()
    _refused(run_cli("validate", fmu, "--steps", "3"), f"has {fmi.MAX_OWN_VARIABLES + 1} ScalarVariables",
             f"limit of {fmi.MAX_OWN_VARIABLES} (uiofmu.cosim.fmi.MAX_OWN_VARIABLES)")
    assert time.perf_counter() - start < 5
    assert not list(scratch.iterdir())


def test_cosim_refuses_more_variables_than_the_default_limit(ex1, tmp_path, scratch):
    """100,001 variables in a 15 MB description: counted by expat and refused before fmpy builds an object
    for each (cosim accepted it in 3.6 s and 310 MB before; 1,000,000 took 25 s and 2.5 GB)."""
    fmu = _with_variables(ex1, tmp_path / "many.fmu", fmi.MAX_VARIABLES - 7)
    start = time.perf_counter()
    _refused(_cosim(ex1, fmu, tmp_path / "run"), f"has {fmi.MAX_VARIABLES + 1} ScalarVariables",
             f"limit of {fmi.MAX_VARIABLES} (uiofmu.cosim.fmi.MAX_VARIABLES)")
    assert time.perf_counter() - start < 10
    assert not list(scratch.iterdir()) and not (tmp_path / "run").exists()


def test_a_dependency_list_longer_than_the_variable_limit_is_refused(ex1, tmp_path, monkeypatch):
    """fmpy splits a dependencies attribute at once: it may not list more entries than there can be variables."""
    monkeypatch.setattr(fmi, "MAX_VARIABLES", 50)
    fmu = _with_variables(ex1, tmp_path / "deps.fmu", 0, lambda xml: xml.replace(
        'dependencies="3"', 'dependencies="' + " ".join(["3"] * 51) + '"', 1))
    _refused(_cosim(ex1, fmu, tmp_path / "run"), "a dependencies list of modelDescription.xml has 51 entries",
             "limit of 50 (uiofmu.cosim.fmi.MAX_VARIABLES)")


@pytest.mark.parametrize("name,value,fragment", [
    ("MAX_ELEMENTS", 20, "modelDescription.xml has 21 elements"),
    ("MAX_DEPENDENCIES", 3, "the dependency lists of modelDescription.xml have at least 4 entries"),
    ("MAX_DESCRIPTION_BYTES", 1000, "modelDescription.xml has "),
])
def test_lowered_description_limits(ex1, tmp_path, monkeypatch, name, value, fragment):
    monkeypatch.setattr(fmi, name, value)
    _refused(_cosim(ex1, ex1 / "observer.fmu", tmp_path / "run"), fragment,
             f"limit of {value} (uiofmu.cosim.fmi.{name})")


def test_a_description_that_is_not_xml_is_refused_before_fmpy(ex1, tmp_path):
    fmu = _with_variables(ex1, tmp_path / "bad.fmu", 0, lambda xml: xml.replace("</ModelVariables>", "<", 1))
    _refused(_cosim(ex1, fmu, tmp_path / "run"), "modelDescription.xml is not well-formed XML",
             "(not well-formed (invalid token): line 2, column")


# -- 3. Integer inputs ---------------------------------------------------------------------------

def _switched(out: Path, mode: float) -> Path:
    """Seed 002's three modes with the plant's mode from ``[signals] mode = constant``: the problem file."""
    data = copy.deepcopy(load_problem(EXAMPLES / "seed002_three_modes.toml").data)
    data["plant"]["switching"] = {"rule": "input"}
    data["signals"]["mode"] = [[{"kind": "constant", "value": mode}]]
    path = out / "problem.toml"
    path.write_text(to_toml(data))
    return path


@pytest.fixture(scope="module")
def switched(tmp_path_factory):
    """The plant FMU of seed 002's three modes driven by its mode input (its signals do not enter the plant)."""
    out = tmp_path_factory.mktemp("switched")
    _ok("plant", _switched(out, 2.0), "-o", out / "plant.fmu")
    return out


@pytest.mark.parametrize("mode", [4294967298.0, 2147483648.0])
def test_a_mode_signal_outside_fmi2integer_is_refused(switched, tmp_path, mode):
    """4294967298 wrapped to mode 2 (and 2147483648 to -2147483648) and ran without a word."""
    problem = _switched(tmp_path, mode)
    _ok("design", problem, "-o", tmp_path / "card.json")
    _ok("build", tmp_path / "card.json", "-o", tmp_path / "observer.fmu")
    res = run_cli("cosim", "--plant", switched / "plant.fmu", "--observer", tmp_path / "observer.fmu", "--t-end", "1",
                  "--out", tmp_path / "run")
    _refused(res, f"signals.mode[0] at t = 0 s: {mode!r} is not an fmi2Integer",
             "expected an integer from -2147483648 to 2147483647")
    assert not (tmp_path / "run").exists()


def test_a_mode_signal_of_1e300_is_refused_by_its_bound(tmp_path):
    res = run_cli("design", _switched(tmp_path, 1e300), "-o", tmp_path / "card.json")
    _refused(res, "signals.mode[0][0].value: expected a value in [-1e+100, 1e+100], found 1e+300")


@pytest.fixture(scope="module")
def switched_fmus(switched):
    """The observer of the switched plant above (mode 2 in its signals)."""
    _ok("design", switched / "problem.toml", "-o", switched / "card.json")
    _ok("build", switched / "card.json", "-o", switched / "observer.fmu")
    return switched


@pytest.mark.parametrize("cell,shown", [("4294967298", "4294967298.0"), ("2147483648", "2147483648.0"),
                                        ("-2147483649", "-2147483649.0"), ("2.5", "2.5"), ("1e300", "1e+300")])
def test_a_mode_column_outside_fmi2integer_is_refused(switched_fmus, tmp_path, cell, shown):
    table = tmp_path / "inputs.csv"
    table.write_text(f"time,u[1],d[1],mode[1]\n0,0.5,0.1,2\n\n0.5,0.5,0.1,{cell}\n")
    res = run_cli("cosim", "--plant", switched_fmus / "plant.fmu", "--observer", switched_fmus / "observer.fmu",
                  "--t-end", "1", "--out", tmp_path / "run", "--inputs", table)
    _refused(res, f"--inputs {table}: line 4, column mode[1] (t = 0.5 s): {shown} is not an fmi2Integer")
    assert not (tmp_path / "run").exists()


class _ModeSource:
    """An input source from Python without ``key``: the master's guard names the input and the time."""

    sizes = {"u": 1, "d": 1, "mode": 1}

    def values(self, t):
        return {"u": np.zeros(1), "d": np.zeros(1), "mode": np.array([2.0 if t < 0.45 else 2.0**32 + 2])}


def test_the_master_and_fmu_set_guard_integer_inputs(switched_fmus):
    from uiofmu.cosim.master import cosimulate

    with pytest.raises(ProblemError, match=r"the input mode\[1\] at t = 0.5 s: 4294967298.0 is not an fmi2Integer"):
        cosimulate(switched_fmus / "plant.fmu", switched_fmus / "observer.fmu", np.full(10, 0.1), _ModeSource(),
                   show_progress=False)
    with fmi.Fmu(switched_fmus / "observer.fmu", "observer") as obs:
        obs.initialize(0.0)
        for bad in (2**32 + 2, 2.5, float("nan"), 10**400):
            with pytest.raises(FmuError, match=r"Integer input mode"):
                obs.set("mode", [bad])
        obs.set("mode", [3])
        assert obs.get("mode").tolist() == [3.0]


# -- 4. step files -------------------------------------------------------------------------------

def test_a_step_file_is_never_quoted(ex1, tmp_path):
    """``--steps file:../secret``: the message names the path and the line, never what the file holds."""
    secret = tmp_path / "secret"
    secret.write_text(SECRET + "\n0.1\n")
    (tmp_path / "work").mkdir()
    res = run_cli("cosim", "--plant", ex1 / "plant.fmu", "--observer", ex1 / "observer.fmu", "--out",
                  tmp_path / "run", "--steps", f"file:{tmp_path / 'work' / '..' / 'secret'}")
    line = _refused(res, "line 1 of", "secret", "must be a number")
    assert "hunter2" not in line and "root:x" not in line and "SECRET" not in line
    (tmp_path / "neg").write_text("0.1\n-7.5 # a negative step\n")
    with pytest.raises(ProblemError, match=r"line 2 of .*neg .*must be > 0$") as info:
        from uiofmu.cosim.steps import step_sequence

        step_sequence(f"file:{tmp_path / 'neg'}", 1.0)
    assert "7.5" not in str(info.value)


def test_a_campaign_step_file_is_never_quoted(ex1, tmp_path):
    (tmp_path / "secret").write_text(SECRET + "\n")
    spec = tmp_path / "campaign" / "spec.toml"
    spec.parent.mkdir()
    spec.write_text(f'[campaign]\nobserver = "{ex1 / "observer.fmu"}"\nplant = "{ex1 / "plant.fmu"}"\nruns = 1\n'
                    '[axes]\nsteps = "file:../secret"\n')
    line = _refused(run_cli("campaign", spec, "--out", tmp_path / "out"), "axes.steps[0]", "line 1 of")
    assert "hunter2" not in line and "root:x" not in line


# -- 5. signal parameters ------------------------------------------------------------------------

@pytest.mark.parametrize("term,fragment", [
    ({"kind": "sine", "amplitude": 1.0, "frequency_hz": 1e308}, "signals.d[0][0].frequency_hz: expected a value in "
                                                                "[-1e+100, 1e+100], found 1e+308"),
    ({"kind": "sine", "amplitude": 1.0, "omega": -1e300}, "signals.d[0][0].omega: expected a value in"),
    ({"kind": "sine", "amplitude": float("inf"), "omega": 1.0}, "signals.d[0][0].amplitude: expected a finite "
                                                                "number, found inf"),
    ({"kind": "step", "time": 1.0, "value": 1.0, "initial": -1e101}, "signals.d[0][0].initial: expected a value in"),
    ({"kind": "random", "seed": 2**60, "std": 1.0, "hold": 1.0}, "signals.d[0][0].seed: expected a non-negative "
                                                                  "integer of at most 9007199254740992"),
    ({"kind": "random", "seed": 1, "std": 1e300, "hold": 1.0}, "signals.d[0][0].std: expected a value in [0, 1e+100]"),
    ({"kind": "random", "seed": 1, "std": 1.0, "hold": 0.0}, "signals.d[0][0].hold: expected a value in (0, 1e+100]"),
])
def test_signal_numbers_are_bounded_where_they_are_read(term, fragment):
    from uiofmu.signals import parse_signals

    with pytest.raises(ProblemError) as info:
        parse_signals([[term]], "signals.d", 1)
    assert fragment in str(info.value), str(info.value)


@pytest.mark.parametrize("term,fragment", [
    ({"kind": "random", "seed": 1, "std": 1.0, "hold": 1e-320}, "signals.d[0][0].hold = 9.99989e-321 s: the run to "
                                                                "t = 10 s spans inf hold intervals, more than"),
    ({"kind": "random", "seed": 1, "std": 1.0, "hold": 1e-16}, "spans 1e+17 hold intervals, more than "
                                                               "9007199254740992 (2**53"),
    ({"kind": "sine", "amplitude": 1.0, "frequency_hz": 1e90}, "signals.d[0][0]: omega t + phase reaches 6.28e+91 rad "
                                                               "by t = 10 s"),
])
def test_a_run_too_long_for_a_term_is_refused_naming_it(term, fragment):
    from uiofmu.cosim.inputs import SignalInputs
    from uiofmu.signals import parse_signals

    d = parse_signals([[term]], "signals.d", 1)
    inputs = SignalInputs((), d)
    times = np.linspace(0.0, 10.0, 11)
    for evaluate in (lambda: inputs.values_at(times), lambda: inputs.values(10.0)):
        with pytest.raises(ProblemError) as info:
            evaluate()
        assert fragment in str(info.value), str(info.value)
    assert np.isfinite(inputs.values_at(times[:1])["d"]).all()          # t = 0 alone is fine


def test_a_denormal_hold_is_an_exit_2_of_cosim(ex1, tmp_path):
    """``hold = 1e-320`` exited 1 (OverflowError in the hold index); now one line naming the key."""
    data = copy.deepcopy(load_problem(EXAMPLES / "seed000_example1.toml").data)
    data["signals"]["d"] = [[{"kind": "random", "seed": 1, "std": 1.0, "hold": 1e-320}]]
    problem = tmp_path / "p.toml"
    problem.write_text(to_toml(data))
    _ok("design", problem, "-o", tmp_path / "card.json")
    _ok("build", tmp_path / "card.json", "-o", tmp_path / "observer.fmu")
    res = run_cli("cosim", "--plant", ex1 / "plant.fmu", "--observer", tmp_path / "observer.fmu", "--t-end", "1",
                  "--out", tmp_path / "run")
    _refused(res, "signals.d[0][0].hold = 9.99989e-321 s", "hold intervals, more than 9007199254740992")
    assert json.loads((tmp_path / "card.json").read_text())["problem"]["signals"]["d"][0][0]["hold"] == 1e-320


def test_a_plant_real_output_fed_to_an_integer_input_is_checked():
    """A vector the plant gives as Real and the observer takes as Integer is converted at each step: an
    integral value is copied, another refused naming the output and the time (it was rounded, or overflowed)."""
    from types import SimpleNamespace

    from uiofmu.cosim.master import _Loop

    real, integer = np.array([[2.0, 7.0], [2.0, 2.0**32 + 2]]), np.zeros((2, 1), dtype=np.intc)
    loop = SimpleNamespace(conversions=[("mode", ("Real", 1, 1), ("Integer", 0, 1))], times=[0.0, 0.1],
                           buffers={"Real": (real, None), "Integer": (integer, None)})
    assert _Loop._convert(loop, None, None, None, 0) == 0 and integer[0, 0] == 7
    with pytest.raises(FmuError, match=r"the plant's output mode\[1\], an Integer input of the observer, at t = 0.1 s: "
                                       r"4294967298.0 is not an fmi2Integer"):
        _Loop._convert(loop, None, None, None, 1)


def test_a_matplotlib_setting_it_refuses_is_exit_2_not_a_bug(ex1, tmp_path):
    """``MPLBACKEND=bogus``: matplotlib refuses it on import; cosim says so in one line (exit 2);
    with --no-report (no matplotlib) the same run goes through."""
    import os
    import subprocess
    import sys

    env = {**os.environ, "MPLBACKEND": "bogus"}
    argv = [sys.executable, "-m", "uiofmu", "cosim", "--plant", str(ex1 / "plant.fmu"), "--observer",
            str(ex1 / "observer.fmu")]
    res = subprocess.run([*argv, "--out", str(tmp_path / "run")], capture_output=True, text=True, env=env,
                         timeout=120)
    res.code, res.err = res.returncode, res.stderr
    _refused(res, "matplotlib refuses its settings", "unset MPLBACKEND")
    ok = subprocess.run([*argv, "--out", str(tmp_path / "quiet"), "--no-report"], capture_output=True, text=True,
                        env=env, timeout=120)
    assert ok.returncode == 0, ok.stderr
