"""The C backend of the delayed UIO (seed 001) and its plant: kernel_delayed.c and kernel_parametric.c against
the Python references (uiofmu.runtime.delayed.DelayedRuntime, uiofmu.runtime.parametric_plant), on the short
problem (``conftest.DELAYED_SHORT``: delay 0.1 s, valid from 0.1 s).

(a) The C observer FMU equals DelayedRuntime to 1e-12 (relative to 1 + |value|) on every output over 250
random aperiodic steps (0.5 to 1.5 ms) fed by the plant's runtime: through start-up, the prediction, the
observer's start and its valid stretches (about 0.25 s). Longer runs drift apart as the runtime drifts from
itself: one ulp of y moves its thetahat by 2e-12 over 300 steps (its (34) takes differences of terms 100
times larger). Its notes (validity lost, once) are the runtime's, word for word.
(b) FMU states with a full delay buffer: get/set and serialise/deserialise restore bit-identical runs; the
buffer in the image is the runtime's (times, y, ydot, u of each point, oldest first); forged images (t, k,
the flags, the buffer's count, times out of order or after t, a value past the points used, a non-finite
estimate, a state before initialisation that has run) are refused with fmi2Error and a log line.
(c) A NaN or infinite input refuses the step with fmi2Error naming it; a step needing too many substeps, a
time t + h past the largest double, and steps so short the buffer would overflow are discarded with the
runtime's messages; nothing changes and the run goes on equal to the runtime.
(d) fmi2Instantiate refuses hand-edited, inconsistent design data; the kernel compiles warning-free with the
strict flags.
(e) Random call sequences (odd inputs and steps, byte-flipped and cut state images, resets, calls in the
wrong state) get statuses up to fmi2Error, never fmi2Fatal or a crash.
(f) The C plant equals ParametricPlantRuntime to 1e-12 (x, y, ydot) on random inputs, aperiodic steps and a
theta set as its parameter; its states restore the same run and forged ones are refused; a NaN u is refused
and a step needing too many substeps discarded, with the runtime's message; random calls.
(g) (a)-(c), (e) and (f) again with the FMUs' own C sources compiled under ASan and UBSan, run through fmpy in
a Python with the sanitizer runtimes preloaded: no report (cfmu.check_sanitized; this file is a script as well,
``python tests/test_c_delayed.py observer|plant FMU DATA.json``).
"""

from __future__ import annotations

import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from cfmu import (NEEDS_CC, check_restores, check_sanitized, discarded, random_calls, refused,  # noqa: E402
                  refused_edits, script_main)
from test_c_hardening import _layout, _with_double  # noqa: E402
from uiofmu.cosim.fmi import Fmu  # noqa: E402
from uiofmu.fmu import c_backend  # noqa: E402
from uiofmu.problem import problem_from_data  # noqa: E402
from uiofmu.runtime.delayed import DelayedRuntime, buffer_rows  # noqa: E402
from uiofmu.runtime.parametric_plant import ParametricPlantRuntime  # noqa: E402
from uiofmu.runtime.schedules import StepRejected  # noqa: E402

pytestmark = NEEDS_CC
H = 1e-3
STEPS = 250
RTOL = 1e-12
OUTPUTS = ("xhat", "thetahat", "r", "sigma_min", "valid")
#: The doubles of the image before the vectors: t, k, phase, running, noted, the buffer's points used.
SCALARS = 6


def plant_of(card) -> ParametricPlantRuntime:
    """The runtime of the card's plant (its problem's)."""
    return ParametricPlantRuntime(problem_from_data(card.data["problem"]).plant.to_data())


def plan(steps: int, seed: int):
    """Random aperiodic steps of 0.5 to 1.5 ms."""
    return np.random.default_rng(seed).uniform(0.5, 1.5, size=steps) * H


def u_at(t: float) -> np.ndarray:
    return np.array([20 * math.sin(math.pi * t) + 10 * math.sin(2.6 * math.pi * t) + 5 * math.sin(6.2 * math.pi * t)])


def reference(rt) -> np.ndarray:
    return np.concatenate([rt.xhat(), rt.theta(), rt.residual(), [rt.margin()], [float(rt.valid)]])


def outputs(fmu) -> np.ndarray:
    return np.concatenate([fmu.get(name) for name in OUTPUTS])


def drive(fmu, rt, plant, hs, t0: float = 0.0):
    """The plant's signals at each point on the FMU (and the runtime ``rt``), then the step: the outputs at
    every point and after the last step, and the end time."""
    got, want, t = [], [], t0
    for h in hs:
        plant.u[:] = u_at(t)
        values = {"y": plant.y(), "ydot": plant.ydot(), "u": plant.u.copy()}
        for name, value in values.items():
            fmu.set(name, value)
            if rt is not None:
                getattr(rt, f"set_{name}")(value)
        got.append(outputs(fmu))
        fmu.step(t, float(h))
        if rt is not None:
            want.append(reference(rt))
            rt.step(float(h))
        plant.step(float(h))
        t += float(h)
    got.append(outputs(fmu))
    if rt is not None:
        want.append(reference(rt))
    return np.array(got), np.array(want), t


def assert_close(got, want, what: str) -> None:
    err = np.abs(np.asarray(got) - np.asarray(want)) / (1.0 + np.abs(want))
    err = np.where(np.isnan(err), np.inf, err)
    assert err.max() <= RTOL, f"{what}: largest relative difference {err.max():.3g} at point {err.max(axis=1).argmax()}"


def check_equal_to_the_runtime(path, card) -> None:
    """(a)."""
    xhat0 = np.array([0.3, -0.2, 0.1])
    rt = DelayedRuntime(card, xhat0=xhat0)
    with Fmu(path, "observer") as fmu:
        fmu.initialize(0.0, {"xhat0": xhat0})
        got, want, _ = drive(fmu, rt, plant_of(card), plan(STEPS, 1))
        warnings = [m.split(": ", 1)[1] for m in fmu.messages if "noted once" in m or "vanished" in m]
    assert_close(got, want, "C delayed observer against DelayedRuntime")
    valid = got[:, -1]
    assert valid[0] == 0 and valid.max() == 1 and np.flatnonzero(valid)[0] >= 100, valid     # from 0.1 s
    assert np.ptp(got[:, 3:6]) > 0.1, "thetahat never moves"
    assert warnings == rt.notices and len(warnings) == 1, (warnings, rt.notices)


def buffer_of(blob, card) -> tuple:
    """(scalars, buffer rows used) of an image."""
    _, data = _layout(blob)
    values = np.frombuffer(blob[data:], dtype="<f8")
    n, m, p, nt = card.dims["n"], card.dims["m"], card.dims["p"], card.matrices["D0"].shape[1]
    c = len(card.schedule["delays"]) + 1
    head = SCALARS + 2 * n * c + nt + n + 2 * p + m
    width = 1 + 2 * p + m
    used = int(values[5])
    return values[:SCALARS], values[head:head + used * width].reshape(used, width), head, width


def check_states(path, card) -> None:
    """(b)."""
    hs = plan(200, 2)
    with Fmu(path, "a") as a, Fmu(path, "b") as b:
        a.initialize(0.0)
        rt = DelayedRuntime(card)
        plant = plant_of(card)
        _, _, t = drive(a, rt, plant, hs[:150])
        plant.u[:] = u_at(t)
        a.set("u", plant.u)                          # an input set but not yet stepped travels too
        saved, u_set = plant.get_state(), plant.u.copy()

        def run(fmu):
            plant.set_state(saved)
            return drive(fmu, None, plant, hs[150:], t)[0]

        def restored(fmu):
            assert np.array_equal(fmu.get("u"), u_set)

        blob, after = check_restores(a, b, run, restored)
        scalars, rows, head, width = buffer_of(blob, card)
        ref = rt.get_state()
        assert scalars[0] == ref["t"] and scalars[1] == ref["k"] == 150 and scalars[3] == float(ref["running"])
        assert rows.shape[0] == ref["rows"] >= 90, "the buffer spans the delay"
        assert np.array_equal(rows.ravel(), ref["buffer"]), "the image's buffer is the runtime's"
        used, R = rows.shape[0], buffer_rows(card.schedule["delays"], card.schedule["step"])
        forged = [(0, -1.0, "t = -1.0"), (0, math.inf, "t = inf"), (1, 0.5, "k = 0.5"), (1, -1.0, "k = -1"),
                  (2, 7.0, "phase = 7"), (2, 1.0, "before initialisation ended"), (3, 2.0, "running = 2"),
                  (4, 0.5, "noted = 0.5"), (5, R + 1.0, "used points"), (5, 1.5, "used points"),
                  (5, used + 1.0, "must increase"), (SCALARS, math.nan, "z[1] = nan"),
                  (SCALARS + 6, math.inf, "xa[1] = inf"), (head, scalars[0] + 1.0, "must increase"),
                  (head + width, rows[0, 0], "must increase"), (head + (used - 1) * width, scalars[0] + H, "not pass"),
                  (head + 2, math.nan, "buffer[1][3] = nan"), (head + used * width + 1, 1.0, "past the")]
        for index, value, word in forged:
            refused(lambda: b.deserialize(_with_double(blob, index, value)), word)
        refused(lambda: b.deserialize(blob[:-8]))
        b.set_state(b.deserialize(blob))              # the genuine image still restores the same run
        assert np.array_equal(after, run(b)), "after the refused states"


def runtime_refusal(rt, h) -> str:
    with pytest.raises(StepRejected) as info:
        rt.step(h)
    return str(info.value)


def check_refusals(path, card) -> None:
    """(c)."""
    hs = plan(170, 3)
    with Fmu(path, "observer") as fmu:
        fmu.initialize(0.0)
        rt = DelayedRuntime(card)
        plant = plant_of(card)
        _, _, t = drive(fmu, rt, plant, hs[:150])              # past the delay and the premise's start
        for name in ("y", "ydot", "u"):
            good = fmu.get(name)
            for value in (math.nan, math.inf, -math.inf):
                fmu.set(name, [value] * len(good))
                word = "nan" if math.isnan(value) else ("-inf" if value < 0 else "inf")
                refused(lambda: fmu.step(t, H), f"input {name}[1] = {word} at step k = 150 is not finite")
            fmu.set(name, good)
        for h in (1e4, 1e3):          # too many substeps for the observer and for the model's prediction
            start = len(fmu.messages)
            discarded(lambda: fmu.step(t, h), "take steps of at most")
            assert fmu.messages[start].split(": ", 1)[1] == runtime_refusal(rt, h)
        got, want, _ = drive(fmu, rt, plant, hs[150:], t)
        assert_close(got, want, "after the refused steps")
        # steps so short that the buffer overflows, then t + h past the largest double
        fmu.reset()
        fmu.initialize(0.0)
        rt = DelayedRuntime(card)
        short = card.schedule["delays"][-1] / (rt.rows_max + 10)
        t = 0.0
        for k in range(rt.rows_max + 10):
            try:
                rt.step(short)
            except StepRejected as exc:
                start = len(fmu.messages)
                discarded(lambda: fmu.step(t, short), "the delay buffer would hold")
                assert fmu.messages[start].split(": ", 1)[1] == str(exc)
                break
            fmu.step(t, short)
            t += short
        else:
            raise AssertionError("steps of a tenth of the shortest average were taken")
        assert k == rt.rows_max
        state = fmu.get_state()
        blob = _with_double(fmu.serialize(state), 0, 1.7e308)
        fmu.set_state(fmu.deserialize(blob))
        discarded(lambda: fmu.step(t, 1e308), "t + h = inf is not a time")
        fmu.set_state(state)
        fmu.step(t, card.schedule["delays"][-1])             # a step that empties the buffer is taken


def check_observer(path, card) -> None:
    """(a), (b), (c), (e) for the C delayed observer FMU at ``path`` of ``card``."""
    check_equal_to_the_runtime(path, card)
    check_states(path, card)
    check_refusals(path, card)
    random_calls(path, H, 1)
    random_calls(path, H, 2, calls=150)


def check_plant(path, data) -> None:
    """(f) for the C plant FMU at ``path`` of the plant ``data``."""
    theta, x0 = [1.5, -0.5, 2.0], [0.1, -0.2, 0.3]
    rng = np.random.default_rng(3)
    inputs, hs = rng.normal(size=(200, 1)) * 10, plan(200, 4)
    ref = ParametricPlantRuntime(data)
    ref.params[:] = theta
    ref.apply_parameters()
    ref.x0 = np.array(x0)
    ref.reset()

    def run(fmu, rt, ks, t0=0.0):
        got, want, t = [], [], t0
        for k in ks:
            fmu.set("u", inputs[k])
            got.append(np.concatenate([fmu.get("x"), fmu.get("y"), fmu.get("ydot")]))
            if rt is not None:
                rt.u[:] = inputs[k]
                want.append(np.concatenate([rt.x, rt.y(), rt.ydot()]))
                rt.step(float(hs[k]))
            fmu.step(t, float(hs[k]))
            t += float(hs[k])
        return np.array(got), np.array(want), t

    with Fmu(path, "plant") as fmu, Fmu(path, "other") as other:
        fmu.initialize(0.0, {"x0": x0, "theta": theta})
        got, want, t = run(fmu, ref, range(100))
        assert_close(got, want, "C plant against ParametricPlantRuntime")
        assert np.ptp(got[:, :3]) > 0.01
        blob, after = check_restores(fmu, other, lambda f: run(f, None, range(100, 130), t)[0])
        for index, value, word in [(0, 7.0, "phase = 7"), (1, math.nan, "x0[1] = nan"), (4, math.inf, "x[1] = inf"),
                                   (8, math.nan, "theta[1] = nan"), (11, math.inf, "params[1] = inf"),
                                   (0, 1.0, "before initialisation ended")]:
            refused(lambda: other.deserialize(_with_double(blob, index, value)), word)
        fmu.set_state(fmu.deserialize(blob))
        got, want, t = run(fmu, ref, range(100, 150), t)
        assert_close(got, want, "C plant after a restored state")
        fmu.set("u", [math.nan])
        refused(lambda: fmu.step(t, H), "input u[1] = nan is not finite")
        fmu.set("u", inputs[150])
        ref.u[:] = inputs[150]
        start = len(fmu.messages)
        discarded(lambda: fmu.step(t, 1e300), "RK4 substeps of the plant")
        assert fmu.messages[start].split(": ", 1)[1] == runtime_refusal(ref, 1e300)
        got, want, _ = run(fmu, ref, range(150, 200), t)
        assert_close(got, want, "C plant after the refused calls")
    random_calls(path, H, 3)


@pytest.fixture(scope="module")
def built(observer_fmus):
    return observer_fmus("delayed_card", "c")


def test_the_c_observer_equals_the_runtime(built):
    check_equal_to_the_runtime(built[1], built[0])


def test_states_with_a_full_buffer_restore_and_forgeries_are_refused(built):
    check_states(built[1], built[0])


def test_refused_inputs_and_steps_change_nothing(built):
    check_refusals(built[1], built[0])


def test_random_call_sequences(built):
    random_calls(built[1], H, 1)


DELAYED_EDITS = [(".ndelays = 1", ".ndelays = 2", "K: expected 54 numbers"),
                 (".ndelays = 1", ".ndelays = 0", "0 delays"),
                 (".n = 3", ".n = 4", "A: expected 16 numbers"),
                 (".has_gamma_bound = 1", ".has_gamma_bound = 2", "gamma_bound"),
                 (".nt = 3", ".nt = 0", "dims.n_theta = 0 is out of range")]


def test_instantiate_refuses_inconsistent_design_data(built, tmp_path):
    card, path = built
    rows = buffer_rows(card.schedule["delays"], card.schedule["step"])
    edits = [*DELAYED_EDITS, (f".rows = {rows}", ".rows = 1", "a buffer of 1 points")]
    refused_edits(path, c_backend.c_kernel(card), edits, tmp_path, "delayed")


@pytest.mark.parametrize("kernel", [c_backend.C_KERNELS["delayed"], c_backend.PLANT_KERNELS["parametric"]],
                         ids=["delayed", "parametric"])
def test_the_kernel_compiles_warning_free_with_the_strict_flags(tmp_path, kernel):
    (tmp_path / kernel.ports_header).write_text(c_backend.port_header(kernel))
    (tmp_path / c_backend.REFUSALS_HEADER).write_text(c_backend.refusals_header())
    proc = subprocess.run(["gcc", "-std=c99", "-Wall", "-Wextra", "-Wpedantic", "-Wshadow", "-Wconversion",
                           "-Wno-sign-conversion", f"-I{c_backend.HERE}", f"-I{tmp_path}",
                           f"-I{c_backend.fmi_headers()}", "-c", "-o", str(tmp_path / "k.o"),
                           str(c_backend.HERE / kernel.source)], capture_output=True, text=True)
    assert proc.returncode == 0 and proc.stderr.strip() == "", proc.stderr


def test_a_card_too_large_for_the_c_kernel_is_built_with_python_by_default(built, tmp_path, monkeypatch):
    """A card whose delay buffer (or augmented system) exceeds what kernel_delayed.c takes: ``--backend c`` refuses
    it naming the numbers, the default picks python and says why."""
    from uiofmu.fmu.export import build_observer, choose_backend
    from uiofmu.runtime.errors import FmuError

    card = built[0]
    monkeypatch.setattr(c_backend, "DELAYED_MAX_BUFFER", 100)
    rows = buffer_rows(card.schedule["delays"], card.schedule["step"])
    with pytest.raises(FmuError) as info:
        build_observer(card, tmp_path / "o.fmu", backend="c")
    text = str(info.value)
    assert f"100 numbers in its delay buffer; this card has (n, m, p) (len(delays) + 1) = (6, 2, 4) and {rows + 1} " \
        "x 6" in text and "use --backend python" in text, text
    backend, note = choose_backend(card)
    assert backend == "python" and "delay buffer" in note and not (tmp_path / "o.fmu").exists()


@pytest.fixture(scope="module")
def plant(delayed_card):
    """The card's plant (a plant with unknown parameters)."""
    return problem_from_data(delayed_card[0].data["problem"]).plant


def test_the_c_plant_equals_the_runtime_and_refuses_what_it_refuses(plant, tmp_path):
    from uiofmu.fmu.export import build_plant

    check_plant(build_plant(plant, "short", tmp_path / "plant.fmu", backend="c"), plant.to_data())


@pytest.mark.skipif(not shutil.which("gcc"), reason="the sanitizers need gcc")
def test_the_observer_and_plant_under_asan_and_ubsan(delayed_card, plant, tmp_path):
    check_sanitized(__file__, {"short": delayed_card[0]}, {"short": plant}, tmp_path)


if __name__ == "__main__":
    sys.exit(script_main(sys.argv[1:], check_observer, check_plant))
