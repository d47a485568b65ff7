"""The C backend of linear plant FMUs (uiofmu/fmu/c/kernel_plant.c on the shared FMI 2.0 plumbing).

(a) Equal to the reference runtime (uiofmu/runtime/plant_runtime.py) to 1e-12 relative on random
aperiodic step sequences: several random continuous plants (n up to 6; steps drawn from a few
values, so the cache is hit, and uniformly, so it turns over) and a discrete plant.
(b) A discrete plant refuses another step with fmi2Discard (a log line naming h and dt) and goes
on after a valid one; bad calls (NaN inputs, h <= 0) give fmi2Error with a log line.
(c) FMU states saved and restored bit-identical, through fmpy.
(d) Under ASan and UBSan (tests/c/plant_test.c with the FMU's own sources): a trajectory equal
to the reference, the bad calls, the discard, forged states, every fmi2 function in every state.
(e) fmpy.simulate_fmu runs the default experiment; the model description is a standalone FMU's.
(f) The closed loop of a C plant and a C observer through our master equals the loop with the
pythonfmu plant, for every family.
"""

from __future__ import annotations

import subprocess
import zipfile

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.fmi2 import fmi2LastSuccessfulTime

from conftest import EXAMPLES, ROOT, run_cli
from uiofmu.cosim.fmi import Fmu, FmuCallError
from uiofmu.fmu.c_backend import (HERE, PLANT_KERNELS, REFUSALS_HEADER, c_compiler, fmi_headers, port_header,
                                  refusals_header)
from uiofmu.fmu.export import build_plant
from uiofmu.plant import Plant
from uiofmu.problem import load_problem
from uiofmu.runtime.plant_runtime import PlantRuntime

import cfuzz

pytestmark = pytest.mark.skipif(c_compiler() is None, reason="the C backend needs a C compiler")

RTOL = 1e-12


def random_plant(rng, n: int) -> Plant:
    """A continuous plant with eigenvalues of both signs but a modest norm (the runs stay bounded)."""
    m, q, p = int(rng.integers(0, 3)), int(rng.integers(1, 3)), int(rng.integers(1, n + 1))
    A = rng.normal(size=(n, n)) / np.sqrt(n) - 0.6 * np.eye(n)
    B = rng.normal(size=(n, m)) if m else None
    return Plant.create(A, rng.normal(size=(p, n)), rng.normal(size=(n, q)), B, time="continuous",
                        x0=rng.normal(size=n))


def reference(plant: Plant, steps, u, d):
    """States x_k of the reference runtime (x_0 = x0) with u and d held."""
    rt = PlantRuntime(plant.to_data())
    rt.u[:] = u
    rt.d[:] = d
    out = [rt.x.copy()]
    for h in steps:
        rt.step(float(h))
        out.append(rt.x.copy())
    return np.array(out), rt


def through_fmpy(path, steps, u, d):
    """States x_k and outputs y_k of an FMU, stepped through fmpy."""
    xs, ys = [], []
    with Fmu(path, "plant") as fmu:
        fmu.initialize(0.0)
        fmu.set("u", u)
        fmu.set("d", d)
        t = 0.0
        xs.append(fmu.get("x"))
        ys.append(fmu.get("y"))
        for h in steps:
            fmu.step(t, float(h))
            t += float(h)
            xs.append(fmu.get("x"))
            ys.append(fmu.get("y"))
    return np.array(xs), np.array(ys)


def assert_close(a, b, what):
    scale = max(float(np.max(np.abs(b))), 1e-300)
    np.testing.assert_allclose(a, b, rtol=RTOL, atol=RTOL * scale, err_msg=what)
    return float(np.max(np.abs(a - b)) / scale)


def aperiodic(rng, k: int, few) -> np.ndarray:
    """k steps: half drawn from the few values ``few``, half uniform in [0.01, 3]."""
    drawn = rng.choice(few, size=k)
    uniform = rng.uniform(0.01, 3.0, size=k)
    return np.where(rng.random(k) < 0.5, drawn, uniform)


@pytest.mark.parametrize("seed", range(6))
def test_continuous_plants_equal_the_reference_runtime(tmp_path, seed):
    rng = np.random.default_rng(seed)
    plant = random_plant(rng, n=seed + 1)
    steps = aperiodic(rng, 120, [0.1, 0.25, 1.0, 2.5])
    u, d = rng.normal(size=plant.m), rng.normal(size=plant.q)
    fmu = build_plant(plant, f"random{seed}", tmp_path / "p.fmu", backend="c")
    x, y = through_fmpy(fmu, steps, u, d)
    want, _ = reference(plant, steps, u, d)
    assert_close(x, want, f"seed {seed}: x")
    assert_close(y, want @ plant.C.T, f"seed {seed}: y")


def test_a_stiff_plant_with_large_steps_equals_the_reference(tmp_path):
    """Large h |A| (many squarings, the degree-13 approximant) still agrees."""
    A = np.array([[-50.0, 3.0, 0.0], [0.0, -0.5, 1.0], [0.0, -1.0, -0.2]])
    plant = Plant.create(A, [[1.0, 0.0, 1.0]], [[1.0], [0.0], [1.0]], [[0.0], [1.0], [0.5]], time="continuous",
                         x0=[1.0, -2.0, 0.5])
    steps = np.array([0.001, 0.02, 0.3, 5.0, 40.0, 0.5, 5.0, 1e-6, 3.0])
    x, _ = through_fmpy(build_plant(plant, "stiff", tmp_path / "p.fmu", backend="c"), steps, [0.4], [-0.3])
    want, _ = reference(plant, steps, [0.4], [-0.3])
    assert_close(x, want, "stiff plant")


def test_the_building_and_a_discrete_plant_equal_the_python_plant_fmu(tmp_path):
    building = aperiodic(np.random.default_rng(1), 80, [1.0, 2.0, 3.0]) * 300.0   # 300, 600, 900 s and 3 .. 900 s
    for path, steps in ((ROOT / "plants" / "two_room_building", building), (EXAMPLES / "seed000_example1.toml", None)):
        problem = load_problem(path)
        plant = problem.plant
        if steps is None:
            steps = np.full(60, plant.dt)
        rng = np.random.default_rng(3)
        u, d = rng.normal(size=plant.m), rng.normal(size=plant.q)
        c = build_plant(plant, problem.name, tmp_path / f"{problem.name}_c.fmu", backend="c")
        py = build_plant(plant, problem.name, tmp_path / f"{problem.name}_py.fmu", backend="python")
        xc, yc = through_fmpy(c, steps, u, d)
        xp, yp = through_fmpy(py, steps, u, d)
        assert_close(xc, xp, f"{problem.name}: x")
        assert_close(yc, yp, f"{problem.name}: y")


@pytest.fixture(scope="module")
def discrete_fmu(tmp_path_factory):
    plant = load_problem(EXAMPLES / "seed000_example1.toml").plant
    return plant, build_plant(plant, "discrete", tmp_path_factory.mktemp("discrete") / "p.fmu", backend="c")


def test_a_discrete_plant_refuses_another_step_and_goes_on(discrete_fmu):
    plant, path = discrete_fmu
    rng = np.random.default_rng(0)
    u, d = rng.normal(size=plant.m), rng.normal(size=plant.q)
    want, _ = reference(plant, [plant.dt] * 3, u, d)
    with Fmu(path, "plant") as fmu:
        fmu.initialize(0.0)
        fmu.set("u", u)
        fmu.set("d", d)
        fmu.step(0.0, plant.dt)
        with pytest.raises(FmuCallError) as info:
            fmu.step(plant.dt, 1.5 * plant.dt)
        assert info.value.status == 2  # fmi2Discard
        line = " ".join(info.value.messages)
        assert f"dt = {plant.dt!r} s" in line and f"h = {1.5 * plant.dt!r} s" in line, line
        assert fmu.slave.getRealStatus(fmi2LastSuccessfulTime) == pytest.approx(plant.dt)
        np.testing.assert_array_equal(fmu.get("x"), want[1])
        fmu.step(plant.dt, plant.dt * (1 + 1e-8))   # within STEP_RTOL: dt
        fmu.step(2 * plant.dt, plant.dt)
        assert_close(fmu.get("x"), want[3], "after the discard")


@pytest.mark.parametrize("bad", ["nan-u", "inf-d", "h0", "hneg"])
def test_bad_calls_give_fmi2_error_with_a_log_line(tmp_path, bad):
    plant = load_problem(ROOT / "plants" / "two_room_building").plant
    path = build_plant(plant, "building", tmp_path / "p.fmu", backend="c")
    with Fmu(path, "plant") as fmu:
        fmu.initialize(0.0)
        fmu.step(0.0, 600.0)
        x = fmu.get("x")
        h = {"h0": 0.0, "hneg": -600.0}.get(bad, 600.0)
        if bad == "nan-u":
            fmu.set("u", [np.nan])
        if bad == "inf-d":
            fmu.set("d", [np.inf])
        with pytest.raises(FmuCallError) as info:
            fmu.step(600.0, h)
        assert info.value.status == 3  # fmi2Error
        line = " ".join(info.value.messages)
        word = {"nan-u": "input u[1] = nan is not finite", "inf-d": "input d[1] = inf is not finite"}.get(bad, "h")
        assert word in line, line
        np.testing.assert_array_equal(fmu.get("x"), x)  # nothing changed
        fmu.set("u", [0.0])
        fmu.set("d", [0.0])
        fmu.step(600.0, 600.0)  # and it goes on


@pytest.mark.parametrize("which", ["continuous", "discrete"])
def test_fmu_state_round_trips_are_bit_identical(tmp_path, which, discrete_fmu):
    if which == "discrete":
        plant, path = discrete_fmu
        steps = [plant.dt] * 8
    else:
        plant = random_plant(np.random.default_rng(7), 4)
        path = build_plant(plant, "rt", tmp_path / "p.fmu", backend="c")
        steps = [0.3, 0.7, 0.3, 1.1, 0.05, 0.3, 2.0, 0.7]
    with Fmu(path, "a") as a, Fmu(path, "b") as b:
        # a runs a perturbed plant, b the design model: b restored from a's state runs a's plant, since the
        # state carries the mismatch and the restore perturbs the matrices again (the exponentials of b's
        # design matrices, cached for the same steps, forgotten)
        a.initialize(0.0, {"mismatch": [0.03], "mismatch_seed": [11]})
        b.initialize(0.0)
        b.set("u", np.ones(plant.m))
        b.set("d", -np.ones(plant.q))
        for k, h in enumerate(steps):
            b.step(sum(steps[:k]), h)
        a.set("u", np.ones(plant.m))
        a.set("d", -np.ones(plant.q))
        t = 0.0
        for h in steps[:4]:
            a.step(t, h)
            t += h
        state = a.get_state()
        blob = a.serialize(state)
        outs = []
        for h in steps[4:]:
            a.step(t, h)
            t += h
            outs.append(np.concatenate([a.get("x"), a.get("y")]))
        a.set_state(state)
        b.set_state(b.deserialize(blob))
        assert b.serialize(b.get_state()) == blob
        t -= sum(steps[4:])
        for k, h in enumerate(steps[4:]):
            a.step(t, h)
            b.step(t, h)
            t += h
            for f in (a, b):
                np.testing.assert_array_equal(np.concatenate([f.get("x"), f.get("y")]), outs[k])
        forged = bytearray(blob)
        at = len(blob) - 8 * (3 + 2 * plant.n + plant.m + plant.q)   # the phase, first of the kernel's doubles
        forged[at:at + 8] = np.float64(9.0).tobytes()
        with pytest.raises(FmuCallError) as info:
            b.deserialize(bytes(forged))
        assert "phase" in " ".join(info.value.messages)
        forged = bytearray(blob)
        forged[-16:-8] = np.float64(-0.03).tobytes()                 # mismatch, after d[q]
        with pytest.raises(FmuCallError) as info:
            b.deserialize(bytes(forged))
        assert "mismatch = -0.03" in " ".join(info.value.messages)


# -- under the sanitizers ------------------------------------------------------------------------

def sanitized(fmu, work) -> object:
    """tests/c/plant_test.c compiled with the FMU's sources under ASan and UBSan."""
    src = work / "src"
    with zipfile.ZipFile(fmu) as z:
        for name in z.namelist():
            if name.startswith("sources/"):
                (src / name[len("sources/"):]).parent.mkdir(parents=True, exist_ok=True)
                (src / name[len("sources/"):]).write_bytes(z.read(name))
    exe = work / "plant_test"
    files = [ROOT / "tests" / "c" / "plant_test.c",
             *(src / n for n in ("fmi2_plumbing.c", "kernel_util.c", "kernel_plant.c", "design_data.c"))]
    proc = subprocess.run(["gcc", "-std=c99", *cfuzz.SANITIZER_FLAGS, "-Wall", "-Wextra", f"-I{src}", "-o", str(exe),
                           *map(str, files), "-lm"], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.strip() == "", f"compiler warnings:\n{proc.stderr}"
    return exe


def _clean(proc):
    assert proc.returncode == 0, proc.stderr[-4000:]
    for mark in cfuzz.SANITIZER_MARKS:
        assert mark not in proc.stderr, proc.stderr[-4000:]


@pytest.mark.parametrize("which", ["continuous", "discrete"])
def test_the_plant_under_asan_and_ubsan(tmp_path, which, discrete_fmu):
    if which == "discrete":
        plant, fmu = discrete_fmu
        steps, other = [plant.dt] * 20, 1.5 * plant.dt
    else:
        plant = random_plant(np.random.default_rng(11), 5)
        fmu = build_plant(plant, "asan", tmp_path / "p.fmu", backend="c")
        steps, other = list(aperiodic(np.random.default_rng(2), 40, [0.1, 0.5, 2.0])), 0.0
    exe = sanitized(fmu, tmp_path)
    proc = subprocess.run([str(exe), "trajectory", *map(repr, map(float, steps))], capture_output=True, text=True,
                          timeout=120)
    _clean(proc)
    got = np.array([[float(v) for v in line.split()[1:]] for line in proc.stdout.splitlines() if line.startswith("x")])
    u = np.array([0.3 * (i + 1) - 0.5 for i in range(plant.m)])
    d = np.array([0.2 - 0.1 * (i + 1) for i in range(plant.q)])
    want, _ = reference(plant, steps, u, d)
    assert_close(got, want[1:], f"{which} plant under the sanitizers")
    proc = subprocess.run([str(exe), "scenario", repr(float(steps[0])), repr(other)], capture_output=True, text=True,
                          timeout=120)
    _clean(proc)
    assert "failures=0" in proc.stderr


@pytest.mark.parametrize("source", ["kernel_plant.c", "kernel_util.c"])
def test_the_kernel_compiles_warning_free_with_the_strict_flags(tmp_path, source):
    kernel = PLANT_KERNELS["linear"]
    (tmp_path / kernel.ports_header).write_text(port_header(kernel))    # the generated port ids and tables
    (tmp_path / REFUSALS_HEADER).write_text(refusals_header())          # and refusals
    proc = subprocess.run(["gcc", "-std=c99", "-Wall", "-Wextra", "-Wpedantic", "-Wshadow", "-Wconversion",
                           "-Wno-sign-conversion", f"-I{HERE}", f"-I{tmp_path}", f"-I{fmi_headers()}", "-c", "-o",
                           str(tmp_path / "k.o"), str(HERE / source)], capture_output=True, text=True)
    assert proc.returncode == 0 and proc.stderr.strip() == "", proc.stderr


# -- as an FMU ------------------------------------------------------------------------------------

def test_the_model_description_is_a_standalone_fmus(discrete_fmu):
    _, path = discrete_fmu
    md = read_model_description(str(path))
    assert md.coSimulation.needsExecutionTool is False
    assert md.generationTool.startswith("uiofmu") and "C backend" in md.description
    with zipfile.ZipFile(path) as z:
        names = set(z.namelist())
        xml = z.read("modelDescription.xml").decode()
    assert {"sources/kernel_plant.c", "sources/kernel_util.c", "sources/fmi2_plumbing.c", "sources/design_data.c",
            f"binaries/linux64/{md.coSimulation.modelIdentifier}.so", "resources/model.json"} <= names
    assert '<File name="kernel_plant.c" />' in xml and '<File name="kernel_util.c" />' in xml
    assert "<DefaultExperiment" in xml
    assert [v.name for v in md.modelVariables if v.causality == "output"][:1] == ["y[1]"]
    assert all(u.dependencies == [] for u in md.outputs)  # y = C x: no feedthrough


def test_the_cli_builds_c_plants_by_default_and_python_ones_on_request(tmp_path):
    res = run_cli("plant", EXAMPLES / "seed000_example1.toml", "-o", tmp_path / "c.fmu")
    assert res.code == 0 and "(c backend)" in res.out
    assert "C backend" in read_model_description(str(tmp_path / "c.fmu")).description
    res = run_cli("plant", EXAMPLES / "seed000_example1.toml", "-o", tmp_path / "py.fmu", "--backend", "python")
    assert res.code == 0 and "(python backend)" in res.out
    assert read_model_description(str(tmp_path / "py.fmu")).generationTool.startswith("PythonFMU")


def test_fmpy_simulate_fmu_runs_the_default_experiment(tmp_path):
    from fmpy import simulate_fmu

    path = build_plant(load_problem(ROOT / "plants" / "two_room_building").plant, "building", tmp_path / "p.fmu",
                       step=600.0, backend="c")
    ex = read_model_description(str(path)).defaultExperiment
    result = simulate_fmu(str(path))
    assert result["time"][-1] == pytest.approx(float(ex.stopTime))
    assert np.all(np.isfinite(result["x[1]"]))


#: family -> problem
FAMILIES = {
    "lti-uio": EXAMPLES / "seed000_example1.toml",
    "ltv-auid": EXAMPLES / "seed000_example1_ltv.toml",
    "sampled-data": ROOT / "plants" / "two_room_building",
}


@pytest.mark.parametrize("family", FAMILIES)
def test_closed_loop_with_the_c_plant_equals_the_pythonfmu_plant(tmp_path, family):
    from uiofmu.cosim.master import cosimulate, default_inputs, observer_card
    from uiofmu.runtime.observer import Runtime
    from uiofmu.runtime.card import read_card

    problem = FAMILIES[family]
    for argv in (("design", problem, "-o", tmp_path / "card.json"),
                 ("build", tmp_path / "card.json", "-o", tmp_path / "obs.fmu", "--backend", "c"),
                 ("plant", problem, "-o", tmp_path / "plant_c.fmu", "--backend", "c"),
                 ("plant", problem, "-o", tmp_path / "plant_py.fmu", "--backend", "python")):
        res = run_cli(*argv)
        assert res.code == 0, res.err
    card = read_card(tmp_path / "card.json")
    admissible = Runtime(card).schedule.admissible_steps()
    rng = np.random.default_rng(5)
    steps = rng.choice(admissible, size=120)    # aperiodic where the design allows it
    inputs = default_inputs(observer_card(tmp_path / "obs.fmu"))
    c = cosimulate(tmp_path / "plant_c.fmu", tmp_path / "obs.fmu", steps, inputs, show_progress=False)
    py = cosimulate(tmp_path / "plant_py.fmu", tmp_path / "obs.fmu", steps, inputs, show_progress=False)
    np.testing.assert_array_equal(c.times, py.times)
    for name in ("x", "y", "xhat"):
        assert_close(getattr(c, name), getattr(py, name), f"{family}: {name}")
