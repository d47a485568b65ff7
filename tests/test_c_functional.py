"""The C backend of dead-beat functional observers and LPV plants (seed 003): kernel_window.c and
kernel_lpv.c against the Python references (uiofmu.runtime.window, uiofmu.runtime.lpv).

(a) The C window observer FMU equals WindowRuntime (gx to 1e-12, gx_valid exactly) over 60 steps of
random y and theta, for the paper's example (no theta port) and for THETA_PLANT (a formula in theta).
(b) FMU states (get/set, serialise/deserialise) mid-window (window not yet full) and after the ring
wrapped restore bit-identical runs; the window in the image is the runtime's, oldest first; forged
bytes (k, phase, a non-finite or not-yet-filled window entry, a theta the design has no port for,
another design's GUID, a short image) are refused with fmi2Error and a log line.
(c) A NaN or infinite y or theta refuses the step with fmi2Error and a log line naming it; a step
other than dt is discarded (fmi2Discard) with a log line; nothing changes and the run goes on.
(d) The C LPV plant equals LpvPlantRuntime: kind state (the example's nonlinear, unstable plant;
small x0 and inputs, 10 steps; theta = T x an output) and kind input (THETA_PLANT, 60 steps); its
state round-trips and forged states are refused; NaN d or theta refused.
(e) Plant and observer FMUs in closed loop through uiofmu.cosim.master.cosimulate: gx equals G x of
the point delay steps back from the first full window on (relative 1e-9).
(f) fmi2Instantiate refuses hand-edited, inconsistent design data of both kernels.
(g) Random call sequences (odd inputs and steps, byte-flipped and cut state images, resets,
calls in the wrong state) get statuses up to fmi2Error, never fmi2Fatal or a crash.
(h) (a)-(d) and (g) again with the FMUs' own C sources compiled under ASan and UBSan, run through
fmpy in a Python with the sanitizer runtimes preloaded: no report (the helpers of cfmu.py, as
test_c_switched.py runs its own). For that the checks take an FMU's path, and this file is a
script as well (``python tests/test_c_functional.py observer|plant FMU DATA.json``).
"""

from __future__ import annotations

import copy
import math
import shutil
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description

sys.path.insert(0, str(Path(__file__).resolve().parent))

from cfmu import (NEEDS_CC, check_restores, check_sanitized, discarded, random_calls, refused,  # noqa: E402
                  refused_edits, run_plant, script_main)
from test_c_hardening import _layout, _with_double  # noqa: E402
from test_deadbeat_functional import EXAMPLE, THETA_PLANT  # noqa: E402
from uiofmu.cosim.fmi import Fmu  # noqa: E402
from uiofmu.cosim.inputs import CsvInputs  # noqa: E402
from uiofmu.cosim.master import cosimulate  # noqa: E402
from uiofmu.fmu import c_backend  # noqa: E402
from uiofmu.fmu.export import build_observer, build_plant  # noqa: E402
from uiofmu.problem import problem_from_data  # noqa: E402
from uiofmu.runtime.lpv import LpvPlantRuntime  # noqa: E402
from uiofmu.runtime.window import WindowRuntime  # noqa: E402
from uiofmu.synthesis import design  # noqa: E402

pytestmark = NEEDS_CC
STEPS = 60
RTOL = 1e-12

PROBLEMS = {"example": EXAMPLE, "theta-plant": THETA_PLANT}


def assert_rows_close(a, b, what, rtol=RTOL):
    """Each row of ``a`` equals that of ``b`` to ``rtol`` relative to the row's largest entry (an
    unstable plant's state spans many orders of magnitude)."""
    a, b = np.atleast_2d(np.asarray(a, dtype=float)), np.atleast_2d(np.asarray(b, dtype=float))
    assert a.shape == b.shape, what
    scale = 1.0 + np.abs(b).max(axis=1, keepdims=True)
    err = np.abs(a - b) / scale
    assert np.all(err <= rtol), f"{what}: max relative error {err.max():.3g} at row {int(err.max(axis=1).argmax())}"


# -- the observer -----------------------------------------------------------------------------------

def observer_inputs(card, seed: int, steps: int = STEPS):
    """Random y and theta for ``steps`` steps."""
    rng = np.random.default_rng(seed)
    return rng.normal(size=(steps, card.dims["p"])) * 3, rng.uniform(-1.5, 1.5, size=(steps, card.schedule["theta"]))


def _outputs(fmu):
    return np.concatenate([fmu.get("gx"), fmu.get("gx_valid")])


def _observe(fmu, rt, card, ys, thetas, k0=0, t0=0.0):
    """Steps k0.. of the inputs on the FMU (and the runtime): ``gx, gx_valid`` at each point (the
    inputs of the point set) before its step, and after the last step."""
    h = card.schedule["dt"]
    uses = fmu.has("theta")
    got, want = [], []
    for k in range(k0, len(ys)):
        fmu.set("y", ys[k])
        if uses:
            fmu.set("theta", thetas[k])
        got.append(_outputs(fmu))
        if rt is not None:
            rt.set_y(ys[k])
            if uses:
                rt.set_theta(thetas[k])
            want.append(np.concatenate([rt.gx(), [float(rt.valid)]]))
            rt.step(h)
        fmu.step(t0 + (k - k0) * h, h)
    got.append(_outputs(fmu))
    if rt is not None:
        want.append(np.concatenate([rt.gx(), [float(rt.valid)]]))
    return np.array(got), np.array(want)


def _window_at(card):
    """Indices of the doubles of the window image: (ys, thetas, y, theta) start offsets."""
    W, p, s = card.schedule["length"] - 1, card.dims["p"], card.schedule["theta"]
    return 2, 2 + W * p, 2 + W * (p + s), 2 + W * (p + s) + p


def check_observer(path, card) -> None:
    """(a), (b), (c) for the C window observer FMU at ``path`` of ``card``."""
    h, L = card.schedule["dt"], card.schedule["length"]
    uses = card.schedule["uses_theta"]
    ys, thetas = observer_inputs(card, 5)
    # (a) equal to the runtime
    with Fmu(path, "observer") as fmu:
        assert fmu.integer("gx_valid") and fmu.has("theta") == uses
        fmu.initialize(0.0)
        got, want = _observe(fmu, WindowRuntime(card), card, ys, thetas)
    assert np.array_equal(got[:, -1], want[:, -1]), "gx_valid"
    assert not got[:L - 1].any() and got[L - 1:, -1].all(), "gx and gx_valid 0 until the window is full"
    assert_rows_close(got[:, :-1], want[:, :-1], f"{card.name}: C window observer against the runtime")
    assert np.abs(got[L:, :-1]).max() > 1e-3, "a formula that gives nothing"
    # (c) bad inputs and steps, then the run goes on
    with Fmu(path, "observer") as fmu:
        fmu.initialize(0.0)
        rt = WindowRuntime(card)
        _observe(fmu, rt, card, ys[:10], thetas)
        before = _outputs(fmu)
        bad_inputs = [("y", v) for v in (math.nan, math.inf, -math.inf)]
        bad_inputs += [("theta", v) for v in (math.nan, math.inf)] if uses else []
        for name, value in bad_inputs:
            fmu.set(name, [value])
            word = "nan" if math.isnan(value) else "inf"
            refused(lambda: fmu.step(10 * h, h), f"input {name}[1] = ", word, "not finite")
            fmu.set(name, ys[10] if name == "y" else thetas[10])
            assert np.array_equal(_outputs(fmu)[-1:], before[-1:]), "a refused step changed k"
        for bad_h in (h / 2, 2 * h, h * (1 + 1e-3)):
            discarded(lambda: fmu.step(10 * h, bad_h), f"dt = {h!r}", "received h")
        got, want = _observe(fmu, rt, card, ys[:20], thetas, k0=10, t0=10 * h)
        assert_rows_close(got, want, "after the refused steps")
    # (b) states: mid-window (k = 2 < L - 1) and after the ring wrapped (k = 30)
    for at in (min(2, L - 2), 30):
        _check_states(path, card, ys, thetas, at)
    random_calls(path, card.schedule["dt"], 1)


def _check_states(path, card, ys, thetas, at: int) -> None:
    h, L = card.schedule["dt"], card.schedule["length"]
    W, p, s = L - 1, card.dims["p"], card.schedule["theta"]
    with Fmu(path, "observer") as a, Fmu(path, "observer") as b:
        a.initialize(0.0)
        rt = WindowRuntime(card)
        _observe(a, rt, card, ys[:at], thetas)
        a.set("y", ys[at])                      # an input set but not yet stepped travels too

        def run(fmu):
            return _observe(fmu, None, card, ys[:at + 12], thetas, at, at * h)[0]

        def restored(fmu):
            assert np.array_equal(fmu.get("y"), ys[at])

        blob, after = check_restores(a, b, run, restored)
        # the window in the image is the runtime's, oldest first, bit for bit
        _, data = _layout(blob)
        values = np.frombuffer(blob[data:], dtype="<f8")
        assert values.size == 2 + W * (p + s) + p + s
        assert values[0] == at and values[1] == 2
        ref = rt.get_state()
        assert np.array_equal(values[2:2 + W * p], ref["ys"]), "the window's outputs"
        assert np.array_equal(values[2 + W * p:2 + W * (p + s)], ref["thetas"]), "the window's theta"
        assert np.array_equal(values[2 + W * (p + s):2 + W * (p + s) + p], ys[at])
        # forged images
        y0, th0, _, th_in = _window_at(card)
        forged = [(0, -1.0, "k = -1"), (0, 0.5, "k = 0.5"), (0, math.nan, "k = nan"), (0, 2.0 ** 60, "k = "),
                  (1, 7.0, "phase = 7"), (1, 0.0, "before initialisation ended"),
                  (y0 + W * p - 1, math.nan, "ys["), (y0 + W * p - 1, math.inf, "is not finite")]
        if s:
            forged.append((th0 + W * s - 1, math.nan, "thetas["))
        if at < W:                              # the oldest point is not yet filled
            forged.append((y0, 1.0, "not yet filled"))
        if not card.schedule["uses_theta"]:
            forged += [(th0 + W * s - 1, 0.5, "no theta input"), (th_in, 0.5, "no theta input")]
        for index, value, word in forged:
            refused(lambda: b.deserialize(_with_double(blob, index, value)), word)
        refused(lambda: b.deserialize(blob[:-8]))
        b.set_state(b.deserialize(blob))        # the genuine image still restores the same run
        assert np.array_equal(after, run(b)), "after the refused states"


# -- the plant --------------------------------------------------------------------------------------

def plant_setup(data: dict):
    """Steps, x0 and the inputs of a plant run: kind state (the nonlinear unstable example) small and
    short, kind input the full 60 steps."""
    rng = np.random.default_rng(11)
    n, q, s = len(data["A"]), len(data["E"][0]), len(data["scheduling"])
    state = data["theta"]["kind"] == "state"
    steps, scale = (10, 0.05) if state else (STEPS, 1.0)
    return (steps, rng.normal(size=n) * scale, rng.normal(size=(steps, q)) * scale,
            rng.uniform(-0.5, 0.5, size=(steps, s)))


def _plant_run(fmu, rt, data, ds, thetas, k0=0, t0=0.0):
    """Steps k0.. on the FMU (and the runtime): ``y, x, theta`` before each step and after the last."""
    inputs = fmu.ports("input")

    def feed(k):
        fmu.set("d", ds[k])
        if "theta" in inputs:
            fmu.set("theta", thetas[k])
        if rt is not None:
            rt.d[:] = ds[k]
            rt.theta_in[:] = thetas[k] if rt.kind == "input" else 0.0

    return run_plant(fmu, rt, data["dt"], range(k0, len(ds)), t0, feed, ("y", "x", "theta"),
                     lambda r: [r.y(), r.x, r.theta()])


def check_plant(path, data: dict) -> None:
    """(d) for the C LPV plant FMU at ``path`` of ``data`` (LpvPlant.to_data())."""
    kind, h = data["theta"]["kind"], data["dt"]
    steps, x0, ds, thetas = plant_setup(data)
    with Fmu(path, "plant") as fmu:
        n, p, q, s = len(data["A"]), len(data["C"]), len(data["E"][0]), len(data["scheduling"])
        ports = [("x0", n), ("d", q), *([("theta", s)] if kind == "input" else []), ("y", p), ("x", n),
                 *([("theta", s)] if kind == "state" else [])]          # lpv_plant_ports, in its order
        names = [v.name for v in fmu.description.modelVariables]
        assert names == [f"{name}[{i + 1}]" for name, size in ports for i in range(size)], names
        fmu.initialize(0.0, {"x0": x0})
        rt = LpvPlantRuntime(data)
        rt.x0 = x0.copy()
        rt.reset()
        got, want = _plant_run(fmu, rt, data, ds, thetas)
    assert_rows_close(got, want, f"C LPV plant (theta from the {kind}) against the runtime")
    # states: the same run after a restore, in the same and another instance
    half = steps // 2
    with Fmu(path, "plant") as a, Fmu(path, "plant") as b:
        a.initialize(0.0, {"x0": x0})
        _plant_run(a, None, data, ds[:half], thetas)
        blob, _ = check_restores(a, b, lambda fmu: _plant_run(fmu, None, data, ds, thetas, half, half * h)[0])
        n, q = len(data["A"]), len(data["E"][0])
        forged = [(0, 5.0, "phase = 5"), (1, math.nan, "x0[1]"), (1 + n, math.inf, "x[1]"),
                  (0, 1.0, "before initialisation ended")]
        if kind == "state":
            forged.append((1 + 2 * n + q, 0.25, "theta[1] = 0.25"))
        for index, value, word in forged:
            refused(lambda: b.deserialize(_with_double(blob, index, value)), word)
        if kind == "input":                     # an input theta travels with the state as it is
            b.set_state(b.deserialize(_with_double(blob, 1 + 2 * n + q, 0.25)))
            assert b.get("theta")[0] == 0.25
    # non-finite inputs and other steps: refused, nothing changes
    with Fmu(path, "plant") as fmu:
        fmu.initialize(0.0, {"x0": x0})
        x = fmu.get("x")
        for name in ("d", "theta") if kind == "input" else ("d",):
            fmu.set(name, [math.nan])
            refused(lambda: fmu.step(0.0, h), f"input {name}[1] = nan", "not finite")
            fmu.set(name, [0.0])
        discarded(lambda: fmu.step(0.0, h / 2), f"dt = {h!r}", f"h = {h / 2!r}")
        assert np.array_equal(fmu.get("x"), x)
        fmu.step(0.0, h)
    random_calls(path, data["dt"], 2)


# -- the tests --------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def cards():
    return {name: design(problem_from_data(copy.deepcopy(data))) for name, data in PROBLEMS.items()}


def lpv_plant(name: str):
    return problem_from_data(copy.deepcopy(PROBLEMS[name])).plant


@pytest.fixture(scope="module")
def fmus(cards, tmp_path_factory):
    """``fmus(kind, name)``: the C observer (kind ``"observer"``) or LPV plant (``"plant"``) FMU of a design of
    :data:`PROBLEMS`, built once per module (the tests that edit one unzip a copy)."""
    root = tmp_path_factory.mktemp("c_functional")
    made: dict = {}

    def get(kind: str, name: str):
        if (kind, name) not in made:
            path = root / f"{kind}-{name}.fmu"
            made[kind, name] = (build_observer(cards[name], path, backend="c") if kind == "observer"
                                else build_plant(lpv_plant(name), "lpv", path, backend="c"))
        return made[kind, name]

    return get


def test_the_designs_are_the_two_kinds(cards):
    assert not cards["example"].schedule["uses_theta"] and cards["theta-plant"].schedule["uses_theta"]
    assert cards["theta-plant"].matrices["Fexp"].any()
    assert lpv_plant("example").theta["kind"] == "state" and lpv_plant("theta-plant").theta["kind"] == "input"


@pytest.mark.parametrize("name", ["example"])      # theta as an input (and the sanitized runs): test_conformance.py
def test_the_c_window_observer_equals_the_runtime(cards, fmus, name):
    card = cards[name]
    path = fmus("observer", name)
    with zipfile.ZipFile(path) as z:
        assert "sources/kernel_window.c" in z.namelist()
        assert b"kernel_affine" not in z.read("modelDescription.xml")
    check_observer(path, card)


def test_a_state_of_another_design_is_refused(cards, fmus):
    paths = {name: fmus("observer", name) for name in cards}
    with Fmu(paths["example"], "a") as a, Fmu(paths["theta-plant"], "b") as b:
        a.initialize(0.0)
        b.initialize(0.0)
        blob = a.serialize(a.get_state())
        refused(lambda: b.deserialize(blob))


@pytest.mark.parametrize("name", list(PROBLEMS))
def test_the_c_lpv_plant_equals_the_runtime(fmus, name):
    plant = lpv_plant(name)
    path = fmus("plant", name)
    md = read_model_description(str(path))
    assert "LPV plant" in md.description
    with zipfile.ZipFile(path) as z:
        assert "sources/kernel_lpv.c" in z.namelist()
    check_plant(path, plant.to_data())


def test_the_d_feedthrough_of_an_lpv_plant(tmp_path):
    """A plant with D(theta) != 0: y depends on d at the same point (and declares it)."""
    data = copy.deepcopy(THETA_PLANT)
    data["plant"]["D"] = [[0.5]]
    data["plant"]["scheduling"][0]["D"] = [[-2.0]]
    data["plant"]["scheduling"][0]["C"] = [[0.0, 1.0, 0.0]]
    plant = problem_from_data(data).plant
    path = build_plant(plant, "feed", tmp_path / "p.fmu", backend="c")
    md = read_model_description(str(path))
    (y,) = [u for u in md.outputs if u.variable.name == "y[1]"]
    assert {d.name for d in y.dependencies} == {"d[1]", "theta[1]"}
    check_plant(path, plant.to_data())
    with Fmu(path, "p") as fmu:                 # y moves with d and theta at the same point
        fmu.initialize(0.0, {"x0": [1.0, 2.0, 3.0]})
        fmu.set("d", [1.0])
        fmu.set("theta", [0.5])
        assert fmu.get("y")[0] == pytest.approx(1.0 + 0.5 * 2.0 + 0.5 - 2.0 * 0.5, rel=1e-15)


@pytest.mark.parametrize("name,steps", [("example", 8), ("theta-plant", STEPS)])
def test_closed_loop_gives_g_x_from_the_first_full_window(cards, fmus, tmp_path, name, steps):
    card = cards[name]
    plant = lpv_plant(name)
    h, delay, L = card.schedule["dt"], card.schedule["delay"], card.schedule["length"]
    obs, pl = fmus("observer", name), fmus("plant", name)
    rng = np.random.default_rng(21)
    by_input = plant.theta["kind"] == "input"
    rows = ["time,d[1]" + (",theta[1]" if by_input else "")]
    for k in range(steps + 1):
        values = [k * h, 0.05 * rng.normal()] + ([rng.uniform(-0.5, 0.5)] if by_input else [])
        rows.append(",".join(map(repr, values)))
    table = tmp_path / "inputs.csv"
    table.write_text("\n".join(rows) + "\n")
    sizes = {"d": 1, **({"theta": 1} if by_input else {})}
    result = cosimulate(pl, obs, np.full(steps, h), CsvInputs(table, sizes), plant_x0=rng.normal(size=3) * 0.01,
                        show_progress=False)
    metrics = result.metrics
    assert metrics["valid_from"] == L - 1 and metrics["steps_to_exact"] == L - 1
    assert metrics["exact_from_first_full_window"]
    G = np.array(PROBLEMS[name]["observer"]["G"], dtype=float)
    gx = result.functional["gx"]
    valid = result.functional["valid"]
    assert not valid[:L - 1].any() and valid[L - 1:].all()
    for k in range(L - 1, steps + 1):
        want = G @ result.x[k - delay]
        assert np.abs(gx[k] - want).max() <= 1e-9 * max(1.0, np.abs(want).max()), k
    assert np.abs(gx[L - 1:]).max() > 1e-6


#: Hand edits of the design_data.c of each kernel and the words of fmi2Instantiate's refusal.
WINDOW_EDITS = [(".length = 4, .delay = 0", ".length = 5, .delay = 0", "F: 3 terms of 1 x 5 (p L) need 15 numbers"),
                (".length = 4, .delay = 0", ".length = 4, .delay = 4", "delay = 4 is out of range"),
                (".length = 4, .delay = 0", ".length = 0, .delay = 0", "window length L = 0"),
                (".uses_theta = 1", ".uses_theta = 0", "but the design does not use theta"),
                (".terms = 3", ".terms = 2", "F: 2 terms"),
                (".dt = 0.5", ".dt = -0.5", "expected a finite period"),
                ("m_Fexp[] = {0, 0, 0, 0, 0, 1", "m_Fexp[] = {0, 0, 0, 0, 0, 65", "Fexp[5] = 65 is not a power")]
LPV_EDITS = [(".s = 1", ".s = 2", "plant A: 3 blocks of 3 x 3 need 27 numbers"),
             (".kind = UIOFMU_THETA_INPUT", ".kind = 7", "theta kind 7"),
             (".p = 1", ".p = 0", "plant p = 0 is out of range"),
             ("m_T[] = {0.0, 0.0, 0.0}", "m_T[] = {1.0, 0.0, 0.0}", "but theta is an input")]


def test_instantiate_refuses_inconsistent_design_data(cards, fmus, tmp_path):
    card = cards["theta-plant"]
    refused_edits(fmus("observer", "theta-plant"), c_backend.c_kernel(card), WINDOW_EDITS, tmp_path, "window")
    plant = lpv_plant("theta-plant")
    refused_edits(fmus("plant", "theta-plant"), c_backend.plant_kernel(plant.to_data()), LPV_EDITS, tmp_path, "lpv")


@pytest.mark.skipif(not shutil.which("gcc"), reason="the sanitizers need gcc")
def test_the_observers_and_plants_under_asan_and_ubsan(cards, tmp_path):
    check_sanitized(__file__, cards, {name: lpv_plant(name) for name in cards}, tmp_path)


if __name__ == "__main__":
    sys.exit(script_main(sys.argv[1:], check_observer, check_plant))
