"""SSP 1.0 bundles of the loop (``uiofmu ssp``): the SSP schema, the C signal source, and runs in libcosim
(three components: source, plant, observer) against our master."""

from __future__ import annotations

import re
import zipfile

import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu
from fmpy.validation import validate_fmu

from conftest import EXAMPLES
from uiofmu.cosim.master import cosimulate, load_inputs
from uiofmu.cosim.ssp import Connection, write_ssp
from uiofmu.fmu.export import build_plant
from uiofmu.fmu.signal_source import SignalTable, build_source
from uiofmu.problem import load_problem
from uiofmu.runtime.errors import ProblemError

#: Problems and their session card fixtures (conftest.py): Real connections only (lti-uio, ltv-auid), the plant's
#: Integer ``mode`` into the observer (switched), ``theta`` from the source into both (dead-beat functional).
LOOPS = {"example1": ("seed000_example1.toml", "example1_card"),
         "ltv": ("seed000_example1_ltv.toml", "ltv_card"),
         "setup2": ("seed002_setup2.toml", "setup2_card"),
         "needs_theta": ("seed003_needs_theta.toml", "needs_theta_card")}


@pytest.fixture(scope="module")
def loop(observer_fmus, tmp_path_factory):
    """``loop(key)``: ``(card, plant FMU, observer FMU)`` of :data:`LOOPS`, C FMUs built once per module."""
    made = {}

    def get(key):
        if key not in made:
            problem_file, fixture = LOOPS[key]
            card, observer = observer_fmus(fixture, "c")
            problem = load_problem(EXAMPLES / problem_file)
            plant = build_plant(problem.plant, problem.name, tmp_path_factory.mktemp("plants") / f"{key}.fmu",
                                step=problem.options.step, backend="c")
            made[key] = card, plant, observer
        return made[key]

    return get


def run_libcosim(bundle, plant, observer, outputs=("xhat",)):
    """Run an SSP file in libcosim at its default experiment: ``{"x": plant x, name: observer output}``
    at t_1 .. t_K (rows), as libcosim's last-value observer reads them after each step."""
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver

    log_output_level(CosimLogLevel.ERROR)
    execution = CosimExecution.from_ssp_file(str(bundle.path))
    last = CosimObserver.create_last_value()
    execution.add_observer(observer=last)
    index = {s.name.decode(): s.index for s in execution.slave_infos()}
    assert sorted(index) == ["observer", "plant", "source"]

    def refs(path, name):
        return [v.valueReference for v in read_model_description(str(path)).modelVariables
                if v.name.startswith(f"{name}[")]

    reads = [("x", "plant", refs(plant, "x"))] + [(n, "observer", refs(observer, n)) for n in outputs]
    rows = {name: [] for name, _, _ in reads}
    for _ in range(bundle.steps):
        assert execution.step(step_count=1)
        for name, who, vr in reads:
            rows[name].append(last.last_real_values(slave_index=index[who], variable_references=vr))
    return {name: np.array(values) for name, values in rows.items()}


def test_the_bundle_follows_the_ssp_schema(loop, tmp_path):
    from pyssp_standard.ssd import SSD

    card, plant, observer = loop("example1")
    bundle = write_ssp(plant, observer, tmp_path / "loop.ssp")
    with zipfile.ZipFile(bundle.path) as z:
        assert sorted(z.namelist()) == ["SystemStructure.ssd", "resources/observer.fmu", "resources/plant.fmu",
                                        "resources/source.fmu"]
        z.extractall(tmp_path / "unzipped")
    ssd = SSD(tmp_path / "unzipped" / "SystemStructure.ssd", "r")
    ssd.__check_compliance__()                   # raises on any breach of SystemStructureDescription.xsd
    links = {(c.start_element, c.start_connector, c.end_element, c.end_connector) for c in ssd.system.connections}
    assert links == {
        ("plant", "y[1]", "observer", "y[1]"), ("source", "u[1]", "observer", "u[1]"),
        ("source", "u[1]", "plant", "u[1]"), ("source", "d[1]", "plant", "d[1]")}
    md = read_model_description(str(observer)).defaultExperiment
    assert (float(ssd.default_experiment.stop_time), bundle.experiment["stepSize"]) == (float(md.stopTime),
                                                                                         float(md.stepSize))
    assert set(bundle.connections) >= {Connection("plant", "observer", "y[1]")}


def test_the_source_fmu_plays_its_table_from_its_resources(tmp_path):
    table = SignalTable([0.0, 0.1, 0.2, 0.3], {"u": [[1.5], [2.5], [-3.25], [4.0]], "mode": [[1], [2], [1], [3]]})
    path = build_source(table, tmp_path / "s.fmu", experiment={"startTime": 0.0, "stopTime": 0.5, "stepSize": 0.05})
    assert validate_fmu(str(path)) == []
    with zipfile.ZipFile(path) as z:
        sources = "".join(z.read(n).decode() for n in z.namelist() if n.startswith("sources/"))
        assert z.read("resources/signals.bin") == table.to_bytes()
    assert "-3.25" not in sources and "1.5" not in sources              # the table is data, never source text
    result = simulate_fmu(str(path), output_interval=0.05, stop_time=0.5)
    expected = [table.at(t) for t in result["time"]]
    assert np.array_equal(result["u[1]"], [e["u"][0] for e in expected])
    assert np.array_equal(result["mode[1]"], [int(e["mode"][0]) for e in expected])
    assert list(result["u[1]"][:3]) == [1.5, 1.5, 2.5]


@pytest.mark.parametrize("values,fragment", [
    ({"u": [[1.0], [np.nan]]}, "u[1] at t = 0.1 s is not finite"),
    ({"mode": [[1], [1.5]]}, "mode[1] = 1.5 at t = 0.1 s is not an fmi2Integer"),
    ({"w": [[1.0], [2.0]]}, "not w"),
])
def test_a_table_the_source_cannot_play_is_refused(values, fragment):
    with pytest.raises(ProblemError, match=re.escape(fragment)):
        SignalTable([0.0, 0.1], values)


def test_the_source_refuses_a_table_that_does_not_fit_it(tmp_path):
    """A table file edited inside the FMU (short, of other sizes) is refused at fmi2Instantiate with a log line."""
    from uiofmu.cosim.fmi import Fmu
    from uiofmu.runtime.errors import FmuError

    table = SignalTable([0.0, 1.0], {"u": [[1.0], [2.0]]})
    path = build_source(table, tmp_path / "s.fmu")
    edited = tmp_path / "edited.fmu"
    with zipfile.ZipFile(path) as z, zipfile.ZipFile(edited, "w") as out:
        for item in z.infolist():
            data = z.read(item)
            out.writestr(item, data[:-8] if item.filename == "resources/signals.bin" else data)
    with pytest.raises(FmuError, match="ends in row 2 of 2"):
        with Fmu(edited, "source") as fmu:
            fmu.initialize(0.0)


@pytest.mark.parametrize("key", list(LOOPS))
def test_libcosim_runs_the_bundle_and_the_plant_is_our_masters(loop, key, tmp_path):
    """The plant's state in libcosim is our master's at every point of the default experiment, with the
    problem's [signals] (measured: bit for bit on these discrete plants; 1.7e-13 relative on a continuous
    plant, whose step libcosim passes as whole nanoseconds)."""
    card, plant, observer = loop(key)
    bundle = write_ssp(plant, observer, tmp_path / "loop.ssp")
    ours = cosimulate(plant, observer, np.full(bundle.steps, bundle.experiment["stepSize"]))
    got = run_libcosim(bundle, plant, observer, outputs=())
    assert got["x"].shape == ours.x[1:].shape
    np.testing.assert_allclose(got["x"], ours.x[1:], rtol=0, atol=1e-12 * np.abs(ours.x).max())


def test_libcosim_reads_the_estimate_before_it_passes_the_new_y(loop, tmp_path):
    """libcosim reads each FMU's outputs right after its step, then passes them on: the observer's state is our
    master's, and its xhat = Xz z + Xy y at t_k+1 carries the y of t_k. Measured here: libcosim's xhat is our
    master's minus Xy (y_k+1 - y_k), to 1e-12."""
    card, plant, observer = loop("example1")
    bundle = write_ssp(plant, observer, tmp_path / "loop.ssp")
    ours = cosimulate(plant, observer, np.full(bundle.steps, bundle.experiment["stepSize"]))
    got = run_libcosim(bundle, plant, observer)
    Xy = np.asarray(card.matrices["Xy"])
    late = ours.xhat[1:] - np.diff(ours.y, axis=0) @ Xy.T
    np.testing.assert_allclose(got["xhat"], late, rtol=0, atol=1e-12 * np.abs(ours.xhat).max())
    assert np.abs(got["xhat"] - ours.xhat[1:]).max() > 0.1          # with a sine u the lag is visible


def test_the_estimate_converges_in_libcosim_with_held_inputs(loop, tmp_path):
    """With an input table of held values (a step of u at 3 s), y settles and the estimate read in libcosim
    converges: its error falls below 1e-3 of its first value over the default experiment."""
    card, plant, observer = loop("example1")
    csv = tmp_path / "inputs.csv"
    csv.write_text("time,u[1],d[1]\n0,1,0.5\n3,-1,0.5\n", encoding="utf-8")
    inputs = load_inputs(csv, plant, observer)
    bundle = write_ssp(plant, observer, tmp_path / "loop.ssp", inputs)
    assert bundle.table.times.tolist() == [0.0, 3.0]
    got = run_libcosim(bundle, plant, observer)
    error = np.linalg.norm(got["xhat"] - got["x"], axis=1)
    assert error[0] > 1.0 and error[-1] < 1e-3 * error[0]
    ours = cosimulate(plant, observer, np.full(bundle.steps, bundle.experiment["stepSize"]), inputs)
    np.testing.assert_allclose(got["x"], ours.x[1:], rtol=0, atol=1e-12 * np.abs(ours.x).max())


def test_uiofmu_ssp_from_a_problem(cli, tmp_path):
    res = cli("ssp", EXAMPLES / "seed000_example1.toml", "-o", tmp_path / "loop.ssp")
    assert res.code == 0, res.err
    assert "source (plays u[1], d[1], 696 rows), plant, observer; 4 connections" in res.out
    assert zipfile.is_zipfile(tmp_path / "loop.ssp")


@pytest.mark.parametrize("args,fragment", [
    (["--plant", "p.fmu"], "give a PROBLEM (designed and built here) or both --plant"),
    (["problem.toml", "--plant", "p.fmu", "--observer", "o.fmu"], "not both"),
])
def test_uiofmu_ssp_needs_a_problem_or_a_pair(cli, tmp_path, args, fragment):
    res = cli("ssp", *args, "-o", tmp_path / "loop.ssp")
    assert res.code == 2 and fragment in res.err and "Traceback" not in res.err
    assert not (tmp_path / "loop.ssp").exists()


@pytest.mark.parametrize("table,fragment", [
    ("time,u[1],d[1]\n0,1,x\n", "line 2 has a non-numeric value"),
    ("time,u[1],d[1],mode[1]\n0,1,2,1\n", "unknown column 'mode[1]'"),
    ("time,u[1]\n0,1\n", "missing column(s) d[1]"),
    ("time,u[1],d[1]\n1,1,2\n0,1,2\n", "times must not decrease"),
])
def test_uiofmu_ssp_refuses_a_bad_input_table(loop, cli, tmp_path, table, fragment):
    _, plant, observer = loop("example1")
    csv = tmp_path / "inputs.csv"
    csv.write_text(table, encoding="utf-8")
    res = cli("ssp", "--plant", plant, "--observer", observer, "--inputs", csv, "-o", tmp_path / "loop.ssp")
    assert res.code == 2, res.err
    assert fragment in res.err and res.err.count("\n") == 1
    assert not (tmp_path / "loop.ssp").exists()


def test_uiofmu_ssp_refuses_a_bad_problem(cli, tmp_path):
    problem = tmp_path / "p.toml"
    problem.write_text('[plant]\ntime = "continuous"\nA = [[1.0]]\n', encoding="utf-8")
    res = cli("ssp", problem, "-o", tmp_path / "loop.ssp")
    assert res.code == 2 and "plant.C" in res.err and res.err.count("\n") == 1


# -- the source's C kernel under the sanitizers, in uiofmu's C host (no Python in the process) --------------------

@pytest.fixture(scope="module")
def sanitized_source(tmp_path_factory):
    """``(table, run)``: a signal source of a random table compiled with ASan and UBSan, and ``run(data, steps)``
    that instantiates it in the sanitized C host on a resource folder holding ``data`` as its table file (the
    folder's name has a space: the URI escapes it) and steps it; returns the finished process."""
    import subprocess

    from cfuzz import SANITIZER_FLAGS
    from uiofmu.fmu.c_backend import HERE, fmi_headers

    rng = np.random.default_rng(5)
    times = np.concatenate([[0.0], np.cumsum(rng.uniform(0.05, 0.4, 30))])
    table = SignalTable(times, {"u": rng.normal(size=(31, 2)), "d": rng.normal(size=(31, 1)),
                                "mode": rng.integers(1, 4, size=(31, 1))})
    work = tmp_path_factory.mktemp("source_asan")
    path = build_source(table, work / "s.fmu")
    src = work / "src"
    src.mkdir()
    with zipfile.ZipFile(path) as z:
        for name in z.namelist():
            if name.startswith("sources/"):
                (src / name[len("sources/"):]).write_bytes(z.read(name))
        guid = read_model_description(str(path)).guid
    lib, host = work / "source.so", work / "host"
    for cmd in (["gcc", "-std=c99", *SANITIZER_FLAGS, "-Wall", "-Wextra", "-shared", "-fPIC", f"-I{src}", "-o",
                 str(lib), *map(str, sorted(src.glob("*.c"))), "-lm"],
                ["gcc", "-std=c99", *SANITIZER_FLAGS, "-Wall", f"-I{fmi_headers()}", "-o", str(host),
                 str(HERE / "fmu_host.c"), "-ldl"]):
        proc = subprocess.run(cmd, capture_output=True, text=True)
        assert proc.returncode == 0 and proc.stderr.strip() == "", proc.stderr

    def run(data: bytes, steps):
        resources = work / "res dir"
        resources.mkdir(exist_ok=True)
        (resources / "signals.bin").write_bytes(data)
        steps_file = work / "steps.txt"
        steps_file.write_text("".join(f"{float(h)!r}\n" for h in steps), encoding="utf-8")
        uri = "file://" + str(resources).replace(" ", "%20")
        outs = ",".join(str(v.valueReference) for v in read_model_description(str(path)).modelVariables
                        if v.type == "Real")
        return subprocess.run([str(host), str(lib), guid, uri, "-", outs, str(steps_file)], capture_output=True,
                              text=True, timeout=120)

    return table, run


def test_the_source_under_asan_and_ubsan_plays_its_table(sanitized_source):
    from cfuzz import SANITIZER_MARKS

    table, run = sanitized_source
    steps = np.random.default_rng(3).uniform(0.01, 0.3, 60)
    proc = run(table.to_bytes(), steps)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert not any(mark in proc.stderr for mark in SANITIZER_MARKS), proc.stderr[-3000:]
    got = np.array([[float(v) for v in line.split()] for line in proc.stdout.splitlines()])
    times = np.concatenate([[0.0], np.cumsum(steps)[:-1]])
    want = np.array([np.concatenate([table.at(t)["u"], table.at(t)["d"]]) for t in times])
    assert np.array_equal(got, want)


@pytest.mark.parametrize("damage,fragment", [
    (lambda b: b"XXXXXXXX" + b[8:], "is not a signal table"),
    (lambda b: b[:-8], "ends in row 31 of 31"),
    (lambda b: b + b"\0", "is longer than its 31 rows"),
    (lambda b: b[:24 + 8] + np.float64(np.nan).tobytes() + b[24 + 16:], "row 1, column 1: nan is not finite"),
    (lambda b: b[:24 + 5 * 8] + np.float64(-1.0).tobytes() + b[24 + 6 * 8:], "row 2: time -1.0 is before"),
    (lambda b: b[:24 + 4 * 8] + np.float64(1.5).tobytes() + b[24 + 5 * 8:], "row 1: mode 1.5 is not an fmi2Integer"),
    (lambda b: b[:16] + np.uint64(3).tobytes() + b[24:], "has 3 value columns, this source plays 4"),
])
def test_the_source_refuses_a_damaged_table_at_instantiation(sanitized_source, damage, fragment):
    from cfuzz import SANITIZER_MARKS

    table, run = sanitized_source
    proc = run(damage(table.to_bytes()), [0.1])
    assert proc.returncode == 2 and "fmi2Instantiate failed" in proc.stderr
    assert fragment in proc.stderr, proc.stderr[-3000:]
    assert not any(mark in proc.stderr for mark in SANITIZER_MARKS), proc.stderr[-3000:]


def test_the_source_kernel_compiles_warning_free_with_the_strict_flags(tmp_path):
    import subprocess

    from uiofmu.fmu.c_backend import HERE, REFUSALS_HEADER, fmi_headers, port_header, refusals_header
    from uiofmu.fmu.signal_source import SOURCE_KERNEL

    (tmp_path / SOURCE_KERNEL.ports_header).write_text(port_header(SOURCE_KERNEL))
    (tmp_path / REFUSALS_HEADER).write_text(refusals_header())
    proc = subprocess.run(["gcc", "-std=c99", "-Wall", "-Wextra", "-Wpedantic", "-Wshadow", "-Wconversion",
                           "-Wno-sign-conversion", f"-I{HERE}", f"-I{tmp_path}", f"-I{fmi_headers()}", "-c", "-o",
                           str(tmp_path / "k.o"), str(HERE / SOURCE_KERNEL.source)], capture_output=True, text=True)
    assert proc.returncode == 0 and proc.stderr.strip() == "", proc.stderr
