"""The MuJoCo quarter-car as a C FMU (``c/kernel_mujoco.c``): what it ships, that it runs with no Python in
the host process, and that it is the pythonfmu plant's twin.

(a) ``binaries/linux64/`` holds the model's binary and the mujoco wheel's ``libmujoco.so.X``, which the
binary needs through the run path ``$ORIGIN`` (readelf), and nothing of Python; ``resources/`` the MJCF.
(b) In fmpy, on random aperiodic runs with the same inputs and parameters, its outputs equal the pythonfmu
plant's (``--backend python``) to 1e-12 (they agree to the last bit).
(c) uiofmu's C host (dlopen, no Python) runs it, the resource location given as ``file:///``,
``file://localhost/``, a plain path or percent-encoded, equal to the reference runtime; a location it cannot
read is refused at fmi2Instantiate with a log line. The FMU Compliance Checker and fmusim run its default
experiment in an environment without Python variables: 0 errors, to the stop time.
(d) States: get, set and serialise round trips; a corrupt state (a NaN in qpos, a negative time, an
unknown phase, truncated) is refused with fmi2Error and a log line, and changes nothing.
(e) Under ASan and UBSan (the kernel, plumbing and design data instrumented; libmujoco is the wheel's
and is not), random call sequences through fmpy report nothing.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from fmpy import read_model_description  # noqa: E402

from cfmu import NEEDS_CC, random_calls, run_sanitized, script_main  # noqa: E402
from conftest import ROOT  # noqa: E402
from importers import check_state_round_trip  # noqa: E402
from uiofmu.cosim.fmi import Fmu, FmuCallError  # noqa: E402
from uiofmu.cosim.native_importers import bare_environment, run_compliance_checker, run_fmusim  # noqa: E402
from uiofmu.fmu.c_backend import build_host  # noqa: E402
from uiofmu.runtime.ports import plant_experiment  # noqa: E402

pytestmark = [pytest.mark.mujoco, NEEDS_CC]

FOLDER = ROOT / "plants" / "quarter_car"
STEP = 0.005
ERROR = 3
#: Physical parameters and an initial state a master sets before initialisation ends.
PARAMETERS = {"m_body": [240.0], "k_susp": [15000.0], "c_tyre": [80.0], "x0": [0.02, 0.01, -0.1, 0.3]}


@pytest.fixture(scope="module")
def spec():
    pytest.importorskip("mujoco")
    from uiofmu.mujoco_plant import load_spec

    return load_spec(FOLDER)


@pytest.fixture(scope="module")
def fmus(spec, tmp_path_factory):
    """The quarter-car plant FMU of each backend, with the default experiment of ``uiofmu plant``."""
    from uiofmu.mujoco_plant import build_mujoco_plant

    out = tmp_path_factory.mktemp("mujoco_c")
    return {backend: build_mujoco_plant(spec, out / f"qc_{backend}.fmu", step=STEP, backend=backend)
            for backend in ("c", "python")}


def _run(path, hs, us, ds, parameters=None) -> np.ndarray:
    """The outputs ``y`` and ``x`` at each communication point of one run through fmpy."""
    with Fmu(path, "plant") as fmu:
        fmu.initialize(0.0, parameters)
        rows, t = [np.concatenate([fmu.get("y"), fmu.get("x")])], 0.0
        for h, u, d in zip(hs, us, ds):
            fmu.set("u", [u])
            fmu.set("d", [d])
            fmu.step(t, h)
            t += h
            rows.append(np.concatenate([fmu.get("y"), fmu.get("x")]))
    return np.array(rows)


# -- (a) what it ships ----------------------------------------------------------------------------------------

def test_it_ships_libmujoco_next_to_its_binary_and_the_mjcf_in_its_resources(fmus, tmp_path):
    import mujoco

    library = next(Path(mujoco.__file__).parent.glob("libmujoco.so.*"))
    md = read_model_description(str(fmus["c"]))
    ident = md.coSimulation.modelIdentifier
    with zipfile.ZipFile(fmus["c"]) as z:
        names = set(z.namelist())
        description = z.read("modelDescription.xml")
        z.extractall(tmp_path)
    assert {f"binaries/linux64/{ident}.so", f"binaries/linux64/{library.name}", "resources/model.xml",
            "resources/model.json"} <= names
    assert (tmp_path / "binaries" / "linux64" / library.name).read_bytes() == library.read_bytes()
    assert (tmp_path / "resources" / "model.xml").read_bytes() == (FOLDER / "model.xml").read_bytes()
    assert b"<SourceFiles" not in description              # the sources need libmujoco to build
    assert md.generationTool.startswith("uiofmu") and "C backend" in md.description
    if shutil.which("readelf") is None:
        pytest.skip("readelf (binutils) is not installed: the run path is not read back")
    dynamic = subprocess.run(["readelf", "-d", str(tmp_path / "binaries" / "linux64" / f"{ident}.so")],
                             capture_output=True, text=True, check=True).stdout
    assert f"Shared library: [{library.name}]" in dynamic
    assert "Library runpath: [$ORIGIN]" in dynamic or "Library rpath: [$ORIGIN]" in dynamic
    assert "python" not in dynamic.lower()


@pytest.mark.parametrize("backend", [None, "c", "python"])
def test_uiofmu_plant_picks_c_and_keeps_pythonfmu_on_request(tmp_path, cli, backend):
    out = tmp_path / "qc.fmu"
    res = cli("plant", FOLDER, "-o", out, *(["--backend", backend] if backend else []))
    assert res.code == 0, res.err
    md = read_model_description(str(out))
    with zipfile.ZipFile(out) as z:
        ships_mujoco = any(name.startswith("binaries/linux64/libmujoco.so.") for name in z.namelist())
    c = backend != "python"
    assert ships_mujoco is c and md.generationTool.startswith("uiofmu") is c
    assert f"{'c' if c else 'python'} backend) written to {out}" in res.out


def test_it_declares_what_the_pythonfmu_plant_declares(fmus):
    c, py = (read_model_description(str(fmus[b])) for b in ("c", "python"))
    def variables(md):
        return [(v.name, v.valueReference, v.causality, v.variability, v.type, v.description,
                 None if v.start is None else float(v.start)) for v in md.modelVariables]

    assert variables(c) == variables(py)
    assert c.coSimulation.canHandleVariableCommunicationStepSize
    assert (c.defaultExperiment.stepSize, c.defaultExperiment.stopTime) == \
        (py.defaultExperiment.stepSize, py.defaultExperiment.stopTime)


# -- (b) the pythonfmu plant's twin ---------------------------------------------------------------------------

@pytest.mark.parametrize("seed", [1, 2])
def test_equal_to_the_pythonfmu_plant_on_random_aperiodic_runs(fmus, seed):
    rng = np.random.default_rng(seed)
    K = 250
    hs = rng.uniform(1e-5, 0.03, K)                  # rests of every length after the 1e-4 s substeps
    hs[::17] = rng.choice([1e-9, 1e-4, 0.0137], size=hs[::17].size)
    us, ds = rng.normal(0.0, 300.0, K), rng.normal(0.0, 500.0, K)
    parameters = PARAMETERS if seed == 1 else None
    c, py = _run(fmus["c"], hs, us, ds, parameters), _run(fmus["python"], hs, us, ds, parameters)
    assert np.all(np.isfinite(c)) and np.abs(c).max() > 1e-3           # the road moves it
    np.testing.assert_allclose(c, py, rtol=0.0, atol=1e-12)


def test_where_mujoco_resets_a_blown_up_simulation_both_do_and_the_c_plant_says_so(fmus, tmp_path, monkeypatch):
    """A road force of 1e12 N: MuJoCo resets the simulation (its warning, in both); the C plant's step
    returns fmi2OK with a warning line naming what MuJoCo said."""
    monkeypatch.chdir(tmp_path)                       # MuJoCo's default handler writes MUJOCO_LOG.TXT here
    hs, us, ds = [0.01] * 6, [0.0] * 6, [0.0, 0.0, 1e12, 1e12, 0.0, 0.0]
    c, py = _run(fmus["c"], hs, us, ds), _run(fmus["python"], hs, us, ds)
    np.testing.assert_array_equal(c, py)
    with Fmu(fmus["c"], "plant") as fmu:
        fmu.initialize(0.0)
        _drive(fmu, ([0.0] * 3, [0.0, 1e12, 0.0]), 0.0, 0.01)
        log = " ".join(fmu.messages)
    assert "t = 0.01: MuJoCo warned" in log and "The simulation is unstable" in log, log


# -- (c) no Python in the host --------------------------------------------------------------------------------

def _host(fmu: Path, tmp_path: Path, location, mjcf=None) -> tuple:
    """uiofmu's C host on the C FMU (extracted under a folder with a space in its name), its resource
    location ``location(resources folder)``; the reference runtime's y and x over the same steps. ``mjcf``:
    the text the FMU's MJCF is replaced with after the reference has loaded the original."""
    from uiofmu.runtime.mujoco_runtime import MujocoRuntime

    unzip = tmp_path / "the fmu"
    with zipfile.ZipFile(fmu) as z:
        z.extractall(unzip)
    md = read_model_description(str(fmu))
    refs = {v.name: v.valueReference for v in md.modelVariables}
    rt = MujocoRuntime(_spec_of(unzip), unzip / "resources")
    if mjcf is not None:
        (unzip / "resources" / "model.xml").write_text(mjcf)
    rng = np.random.default_rng(4)
    rows, expect = [], []
    for _ in range(80):
        h, u, d = float(rng.uniform(1e-4, 0.02)), float(rng.normal(0, 200)), float(rng.normal(0, 400))
        expect.append(np.concatenate([rt.y(), rt.x]))
        rt.u[:], rt.d[:] = [u], [d]
        rt.step(h)
        rows.append(f"{h!r} {u!r} {d!r}")
    (tmp_path / "steps.txt").write_text("\n".join(rows) + "\n")
    outs = [refs[f"y[{i}]"] for i in (1, 2, 3)] + [refs[f"x[{i}]"] for i in (1, 2, 3, 4)]
    host = build_host(tmp_path / "host")
    cmd = [str(host), str(unzip / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so"), md.guid,
           location(unzip / "resources"), f"{refs['u[1]']},{refs['d[1]']}", ",".join(map(str, outs)),
           str(tmp_path / "steps.txt")]
    return subprocess.run(cmd, capture_output=True, text=True, env=bare_environment()), \
        np.array(expect)


def _spec_of(unzip: Path) -> dict:
    import json

    return json.loads((unzip / "resources" / "model.json").read_text())["mujoco"]


@pytest.mark.parametrize("location", [
    lambda p: p.as_uri(),                                             # file:///...%20... (percent-encoded)
    lambda p: "file://localhost" + p.as_uri()[len("file://"):],
    lambda p: "file:" + p.as_uri()[len("file://"):] + "/",
    lambda p: str(p),                                                 # a plain path, as some importers pass
], ids=["file-uri", "localhost", "file-colon", "path"])
def test_the_c_host_runs_it_without_python(fmus, tmp_path, location):
    proc, expect = _host(fmus["c"], tmp_path, location)
    assert proc.returncode == 0, proc.stderr
    got = np.array([[float(v) for v in line.split()] for line in proc.stdout.splitlines()])
    np.testing.assert_allclose(got, expect, rtol=0.0, atol=1e-12)


@pytest.mark.parametrize("location, words", [
    (lambda p: "http://example.org/resources", "is no file URI or absolute path of this machine"),
    (lambda p: "file://elsewhere/resources", "is no file URI or absolute path of this machine"),
    (lambda p: p.as_uri() + "%2", "has a bad percent escape"),
    (lambda p: p.parent.as_uri(), "MuJoCo cannot load"),
], ids=["http", "another-host", "bad-escape", "no-mjcf"])
def test_a_resource_location_it_cannot_read_is_refused_at_instantiation(fmus, tmp_path, location, words):
    proc, _ = _host(fmus["c"], tmp_path, location)
    assert proc.returncode == 2 and "fmi2Instantiate failed" in proc.stderr, proc.stderr
    assert words in proc.stderr, proc.stderr


def test_an_mjcf_edited_after_the_build_is_refused_at_instantiation(fmus, tmp_path):
    """A third body with a joint: the model's sizes differ from those its indices were resolved in."""
    text = (FOLDER / "model.xml").read_text().replace("</worldbody>", '<body name="extra" pos="0 0 2"><joint '
                                                      'name="extra_z" type="slide"/><geom type="sphere" size="0.1"/>'
                                                      '</body></worldbody>')
    proc, _ = _host(fmus["c"], tmp_path, lambda p: p.as_uri(), mjcf=text)
    assert proc.returncode == 2 and "fmi2Instantiate failed" in proc.stderr, proc.stderr
    assert "has nq = 3, the FMU was built for 2 (the MJCF was changed after the build)" in proc.stderr, proc.stderr


def test_the_kernel_and_the_builder_name_the_same_mjcf_file():
    from uiofmu.fmu.mujoco_c import MJCF_FILE

    header = (ROOT / "uiofmu" / "fmu" / "c" / "kernel_mujoco.h").read_text()
    assert f'#define UIOFMU_MJCF_FILE "{MJCF_FILE}"' in header


def _alone(run):
    """A native importer's run of the default experiment: 0 errors or warnings, 201 finite rows to t = 1 s."""
    if not run.ran:
        pytest.skip(run.unavailable)
    assert not run.errors and not run.warnings, run.log[-2000:]
    assert len(run.rows) == 201 and run.last_time == pytest.approx(1.0, rel=1e-12)


def test_the_compliance_checker_runs_its_default_experiment(fmus, tmp_path):
    _alone(run_compliance_checker(fmus["c"], STEP, 1.0, workdir=tmp_path))


def test_fmusim_runs_its_default_experiment(fmus, tmp_path):
    _alone(run_fmusim(fmus["c"], STEP, 1.0, workdir=tmp_path))


# -- (d) states -----------------------------------------------------------------------------------------------

def _drive(fmu, inputs, t0, h):
    us, ds = inputs
    out = []
    for k, (u, d) in enumerate(zip(us, ds)):
        fmu.set("u", [u])
        fmu.set("d", [d])
        fmu.step(t0 + k * h, h)
        out.append(np.concatenate([fmu.get("y"), fmu.get("x")]))
    return np.array(out)


def test_states_round_trip(fmus):
    rng = np.random.default_rng(9)
    first = (rng.normal(0, 200, 30), rng.normal(0, 400, 30))
    rest = (rng.normal(0, 200, 40), rng.normal(0, 400, 40))
    with Fmu(fmus["c"], "a") as a, Fmu(fmus["c"], "b") as b:
        check_state_round_trip(a, b, _drive, first, rest, 0.0073)


#: Edits of a serialised state (its doubles are the last ones, in the kernel's order: phase, time, x0[4],
#: params[6], u, d, qpos[2], qvel[2], ctrl[2]; 20 in all) and the words of their refusal.
CORRUPT = {
    "qpos nan": (lambda b: _put(b, 14, float("nan")), "qpos[1] = nan is not finite"),
    "time < 0": (lambda b: _put(b, 1, -1.0), "time = -1.0: expected a finite time >= 0"),
    "phase": (lambda b: _put(b, 0, 7.0), "phase = 7.0 is none of"),
    "params inf": (lambda b: _put(b, 6, float("inf")), "params[1] = inf is not finite"),
    "truncated": (lambda b: b[:-8], ""),
}


def _put(blob: bytes, index: int, value: float) -> bytes:
    at = len(blob) - 20 * 8 + index * 8
    return blob[:at] + np.float64(value).tobytes() + blob[at + 8:]


@pytest.mark.parametrize("edit", list(CORRUPT))
def test_a_corrupt_state_is_refused_and_changes_nothing(fmus, edit):
    change, words = CORRUPT[edit]
    with Fmu(fmus["c"], "a") as fmu:
        fmu.initialize(0.0)
        _drive(fmu, ([50.0] * 10, [100.0] * 10), 0.0, 0.01)
        blob = fmu.serialize(fmu.get_state())
        assert len(fmu.serialize(fmu.get_state())) == len(blob)
        _drive(fmu, ([0.0] * 3, [300.0] * 3), 0.1, 0.01)
        before, start = fmu.serialize(fmu.get_state()), len(fmu.messages)
        with pytest.raises(FmuCallError) as info:
            fmu.set_state(fmu.deserialize(change(blob)))
        assert info.value.status == ERROR
        log = " ".join(fmu.messages[start:])
        assert words in log and "fmi2" in log, log
        assert fmu.serialize(fmu.get_state()) == before              # nothing changed
        _drive(fmu, ([0.0], [0.0]), 0.13, 0.01)                       # and it steps on


# -- (e) sanitizers -------------------------------------------------------------------------------------------

def check_plant(fmu, data) -> None:
    """Random call sequences (odd inputs, odd steps, states flipped and truncated, resets) and a plain run."""
    import tempfile

    os.chdir(tempfile.mkdtemp())                      # MuJoCo's default handler writes MUJOCO_LOG.TXT there
    for seed in range(3):
        random_calls(fmu, 0.01, seed, calls=300)
    with Fmu(fmu, "plain") as f:
        f.initialize(0.0)
        out = _drive(f, ([100.0] * 50, [-200.0] * 50), 0.0, 0.0123)
        assert np.all(np.isfinite(out))


def test_random_calls_under_the_sanitizers(spec, tmp_path):
    from cfuzz import SANITIZER_FLAGS
    from uiofmu.fmu.mujoco_c import build_c_mujoco_plant

    fmu = build_c_mujoco_plant(spec, tmp_path / "sanitized.fmu", "sanitized_plant", plant_experiment(STEP),
                               list(SANITIZER_FLAGS))
    with zipfile.ZipFile(fmu) as z:                                      # really instrumented
        assert b"__asan_" in z.read("binaries/linux64/sanitized_plant.so")
    run_sanitized(__file__, "plant", fmu, {}, tmp_path)


if __name__ == "__main__":
    sys.exit(script_main(sys.argv[1:], None, check_plant))
