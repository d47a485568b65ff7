"""Issue 18, the FMUs of seed 001: the delayed UIO with parameter identification and its plant.

Everything here is real: the paper's example (``conftest.DELAYED_EXAMPLE``) is designed, its FMUs are built by
the command line with the default backend (C, observer and plant) and with pythonfmu, run by our master and by
ecospy, and compared with the reference runtimes (:class:`uiofmu.runtime.delayed.DelayedRuntime`,
:class:`uiofmu.runtime.parametric_plant.ParametricPlantRuntime`): the pythonfmu FMUs bit for bit, the C ones to
1e-12 (the C observer's own tests: tests/test_c_delayed.py).

Runs are short: the observer integrates ~20 RK4 substeps per 1 ms communication step (about 4 ms of
wall time per step). The example's delay is 0.5 s, so its estimates become valid only after 0.5 s of
simulated time; the tests that compare over 300 steps of 1 ms use the same problem with a delay of
0.1 s (``conftest.DELAYED_SHORT``) so that the delay buffer is full and the estimates valid inside the run;
what every observer FMU owes (its runtime on random steps, state round trips, refusals of NaN inputs and of
steps too long) is checked on that one by tests/test_conformance.py.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from conftest import DELAYED_EXAMPLE as EXAMPLE
from conftest import DELAYED_SHORT as SHORT
from conftest import run_cli
from importers import ecospy_equals_master

H = 1e-3
STEPS = 300


def _cli(*argv):
    result = run_cli(*argv)
    assert result.code == 0, f"uiofmu {' '.join(map(str, argv))} exited {result.code}:\n{result.err}"
    return result


@pytest.fixture(scope="module")
def built(tmp_path_factory, observer_fmus):
    """Both problems designed, and their observer and plant FMUs built by the command line with the default
    backend: ``{"example": {...}, "short": {...}}`` with ``toml``, ``card``, ``obs``, ``plant`` and the
    command lines' output ``build_out``, ``plant_out``; ``SHORT``'s card and observer are conftest's
    ``delayed_card`` and its FMU (once per session, the ones tests/test_conformance.py runs)."""
    root = tmp_path_factory.mktemp("delayed_fmus")
    out = {}
    for key, text in (("example", EXAMPLE), ("short", SHORT)):
        folder = root / key
        folder.mkdir()
        paths = {"toml": folder / "problem.toml", "card": folder / "card.json", "obs": folder / "observer.fmu",
                 "plant": folder / "plant.fmu"}
        paths["toml"].write_text(text, encoding="utf-8")
        if key == "short":
            card, paths["obs"] = observer_fmus("delayed_card", "python")
            card.write(paths["card"])
        else:
            _cli("design", paths["toml"], "-o", paths["card"])
            paths["build_out"] = _cli("build", paths["card"], "-o", paths["obs"]).out
        paths["plant_out"] = _cli("plant", paths["toml"], "-o", paths["plant"]).out
        if key == "example":
            paths["plant_python"] = folder / "plant_python.fmu"
            _cli("plant", paths["toml"], "-o", paths["plant_python"], "--backend", "python")
        out[key] = paths
    return out


def _card(path):
    from uiofmu.runtime.card import read_card

    return read_card(path)


def _plant_runtime(toml_path, theta=None):
    from uiofmu.problem import load_problem
    from uiofmu.runtime.parametric_plant import ParametricPlantRuntime

    rt = ParametricPlantRuntime(load_problem(toml_path).plant.to_data())
    if theta is not None:
        rt.params[:] = theta
        rt.apply_parameters()
    return rt


def _u(t: float) -> np.ndarray:
    """The problem's input: 20 sin(pi t) + 10 sin(2.6 pi t) + 5 sin(6.2 pi t)."""
    return np.array([20 * math.sin(2 * math.pi * 0.5 * t) + 10 * math.sin(2 * math.pi * 1.3 * t)
                     + 5 * math.sin(2 * math.pi * 3.1 * t)])


OUTPUTS = ("xhat", "thetahat", "r", "sigma_min", "valid")


def _reference_outputs(rt) -> np.ndarray:
    return np.concatenate([rt.xhat(), rt.theta(), rt.residual(), [rt.margin()], [1.0 if rt.valid else 0.0]])


def _drive(fmu, rt, plant, t0, k0, steps):
    """Feed the FMU (and the reference ``rt`` when given) from the plant runtime for ``steps`` steps of H:
    the outputs at every point (rows)."""
    rows = []
    for k in range(k0, k0 + steps):
        t = t0 + (k - k0) * H
        plant.u[:] = _u(t)
        y, ydot = plant.y(), plant.ydot()
        for name, value in (("y", y), ("ydot", ydot), ("u", plant.u)):
            fmu.set(name, value)
        got = np.concatenate([fmu.get(name) for name in OUTPUTS])
        if rt is not None:
            rt.set_y(y)
            rt.set_ydot(ydot)
            rt.set_u(plant.u)
            np.testing.assert_array_equal(got, _reference_outputs(rt), err_msg=f"step {k}")
            rt.step(H)
        rows.append(got)
        fmu.step(t, H)
        plant.step(H)
    return np.array(rows)


def test_the_default_backend_is_c_for_both(built):
    """The default builds observer and plant in C, without a note: standalone FMUs, no Python needed."""
    from fmpy import read_model_description

    ex = built["example"]
    for out, fmu in ((ex["build_out"], ex["obs"]), (ex["plant_out"], ex["plant"])):
        assert "note:" not in out and "(c backend)" in out, out
        assert read_model_description(str(fmu)).coSimulation.needsExecutionTool is False


def test_observer_fmu_equals_the_runtime(built):
    """300 steps of 1 ms fed by the plant runtime: every output of the FMU bit-equal to DelayedRuntime's,
    through start-up, the first valid point and the stretches where the margin falls below the bound."""
    from uiofmu.cosim.fmi import Fmu
    from uiofmu.runtime.delayed import DelayedRuntime

    short = built["short"]
    xhat0 = np.array([0.3, -0.2, 0.1])
    rt = DelayedRuntime(_card(short["card"]), xhat0=xhat0)
    plant = _plant_runtime(short["toml"])
    with Fmu(short["obs"], "observer") as fmu:
        fmu.initialize(0.0, {"xhat0": xhat0})
        rows = _drive(fmu, rt, plant, 0.0, 0, STEPS)
    valid = rows[:, -1]
    assert valid[0] == 0 and valid.max() == 1, "the run must reach valid estimates"
    first = int(np.flatnonzero(valid)[0])
    assert first * H >= 0.1 - 1e-12 and np.any(valid[first:] == 0), "and lose them again (margin below the bound)"


def _tampered_buffer(blob: bytes) -> bytes:
    """The serialised state with the delay buffer's first two times swapped (out of order)."""
    state = json.loads(blob)
    rt = state["model"]["runtime"]
    width = len(rt["buffer"]) // rt["rows"]
    assert rt["rows"] >= 2
    rt["buffer"][0], rt["buffer"][width] = rt["buffer"][width], rt["buffer"][0]
    return json.dumps(state).encode()


def test_fmu_state_with_a_full_delay_buffer(built):
    """get/set and serialise/deserialise mid-run, once the delay buffer is full: the continuation is
    bit-identical; a state whose buffer times are out of order is refused (error status, a log line) and
    changes nothing."""
    from uiofmu.cosim.fmi import Fmu, FmuCallError

    short = built["short"]
    plant = _plant_runtime(short["toml"])
    with Fmu(short["obs"], "observer") as fmu:
        fmu.initialize(0.0, {"xhat0": [0.3, -0.2, 0.1]})
        _drive(fmu, None, plant, 0.0, 0, 150)               # 0.15 s: past the delay of 0.1 s
        state, plant_state = fmu.get_state(), plant.get_state()
        blob = fmu.serialize(state)
        assert json.loads(blob)["model"]["runtime"]["rows"] >= 100       # the buffer spans the delay
        first = _drive(fmu, None, plant, 0.15, 150, 40)
        fmu.set_state(state)
        plant.set_state(plant_state)
        second = _drive(fmu, None, plant, 0.15, 150, 40)
        assert first.tobytes() == second.tobytes()
        fmu.set_state(fmu.deserialize(blob))
        plant.set_state(plant_state)
        third = _drive(fmu, None, plant, 0.15, 150, 40)
        assert first.tobytes() == third.tobytes()

        before = np.concatenate([fmu.get(name) for name in OUTPUTS])
        after_state = fmu.get_state()
        bad = fmu.deserialize(_tampered_buffer(blob))
        start = len(fmu.messages)
        with pytest.raises(FmuCallError) as info:
            fmu.set_state(bad)
        assert info.value.status == 3
        log = " ".join(fmu.messages[start:])
        assert "buffer" in log and "refused" in log, log
        np.testing.assert_array_equal(np.concatenate([fmu.get(name) for name in OUTPUTS]), before)
        fmu.set_state(after_state)                          # the FMU still works


@pytest.mark.parametrize("backend", ["c", "python"])
def test_plant_fmu_equals_the_runtime(built, backend):
    """The plant FMU against ParametricPlantRuntime: x, y, ydot over random inputs, aperiodic steps and a theta
    set as the FMU's parameter; bit-equal on the python backend, to 1e-12 (relative to 1 + |value|) in C."""
    from uiofmu.cosim.fmi import Fmu

    ex = built["example"]
    path = ex["plant"] if backend == "c" else ex["plant_python"]
    theta = [1.5, -0.5, 2.0]
    x0 = [0.1, -0.2, 0.3]
    ref = _plant_runtime(ex["toml"], theta)
    ref.x0 = np.array(x0)
    ref.reset()
    rng = np.random.default_rng(3)
    with Fmu(path, "plant") as fmu:
        fmu.initialize(0.0, {"x0": x0, "theta": theta})
        np.testing.assert_array_equal(fmu.get("theta"), theta)
        t = 0.0
        for _ in range(STEPS):
            ref.u[:] = rng.normal(size=1) * 10
            fmu.set("u", ref.u)
            got = np.concatenate([fmu.get("x"), fmu.get("y"), fmu.get("ydot")])
            want = np.concatenate([ref.x, ref.y(), ref.ydot()])
            err = np.abs(got - want) / (1 + np.abs(want))
            assert err.max() <= (0.0 if backend == "python" else 1e-12), err.max()
            h = float(rng.uniform(0.2, 3.0) * H)
            fmu.step(t, h)
            ref.step(h)
            t += h
        assert np.ptp(fmu.get("x")) > 0


def test_command_line_end_to_end(built, tmp_path):
    """cosim --t-end 1.5 writes results, metrics with the theta metrics and the validity, and the report;
    validate passes on the FMUs (the C ones within their tolerance, the pythonfmu plant bit for bit)."""
    ex = built["example"]
    out = tmp_path / "run"
    result = _cli("cosim", "--plant", ex["plant"], "--observer", ex["obs"], "--t-end", "1.5", "--out", out)
    m = json.loads((out / "metrics.json").read_text())
    v, th = m["validity"], m["theta"]
    assert m["steps"] == 1500 and 0 < v["fraction"] < 1 and v["first_valid_time"] >= 0.5
    assert v["first_valid_point"] == round(v["first_valid_time"] / H)
    assert th["true"] == [1.0, 2.0, 0.5] and len(th["final"]) == 3
    assert th["final_error_norm"] == pytest.approx(np.linalg.norm(np.array(th["final"]) - th["true"]), rel=1e-12)
    assert "time_to_1pct" in th and "certified_bound" in m and "premise set only" in m["certified_bound"]
    assert "bound_respected" not in m
    assert "valid " in result.out and "theta error" in result.out and "thetahat" in result.out
    header = (out / "results.csv").read_text().splitlines()[0].split(",")
    assert {"thetahat[1]", "thetahat[3]", "sigma_min", "valid", "theta_error_norm"} <= set(header)
    drawn = (out / "report.png").read_bytes()
    assert len(drawn) > 10_000
    (out / "report.png").unlink()
    _cli("report", out)                                   # the same figure, from results.csv and metrics.json
    assert (out / "report.png").read_bytes() == drawn
    for fmu in (ex["obs"], ex["plant"]):                 # C FMUs: their runtimes' outputs to 1e-12
        result = _cli("validate", fmu)
        assert "tolerance 1e-12" in result.out and "no problem" in result.out, result.out
    result = _cli("validate", ex["plant_python"])        # the pythonfmu plant: bit for bit
    assert "largest difference 0 " in result.out, result.out


def test_noise_is_measured_against_a_gain_the_run_does_not_check(built, tmp_path):
    """cosim --noise on the delayed observer: its card's gain_y holds with the premises noise-free (noise.covers),
    which its FMU does not keep, so the run measures the loop's gain and states that it does not check the card:
    noise_gain_respected is null whatever the ratio, and no line says FALSE CERTIFICATE."""
    sh = built["short"]
    out = tmp_path / "noisy"
    result = _cli("cosim", "--plant", sh["plant"], "--observer", sh["obs"], "--t-end", "0.3", "--noise", "y=0.5,3",
                  "--out", out)
    m = json.loads((out / "metrics.json").read_text())
    assert m["noise_gain_covers"] == json.loads(sh["card"].read_text())["noise"]["covers"]
    assert m["noise_gain_measured"] > 0 and m["noise_gain_certified"] > 0 and m["noise_gain_respected"] is None
    assert "not a check of it" in result.out and "FALSE CERTIFICATE" not in result.out


def test_plant_theta_changes_the_plant_not_the_observer(built, tmp_path):
    """The plant's parameter theta, changed through cosimulate, changes what the plant does (and the truth
    the metrics compare with); the observer never reads it: an observer FMU built from a card whose
    problem states another true theta (its premise family, simulated with the designed theta, unchanged:
    the card is still what its problem determines) gives bit-identical estimates."""
    from uiofmu.cosim.master import cosimulate
    from uiofmu.fmu.export import build_observer
    from uiofmu.runtime.card import card_from_data

    short = built["short"]
    steps = np.full(STEPS, H)
    new = [1.5, 1.0, 0.8]
    base = cosimulate(short["plant"], short["obs"], steps, show_progress=False)
    changed = cosimulate(short["plant"], short["obs"], steps, plant_parameters={"theta": new}, show_progress=False)
    assert base.metrics["theta"]["true"] == [1.0, 2.0, 0.5] and changed.metrics["theta"]["true"] == new
    assert np.abs(changed.y - base.y).max() > 1e-3
    assert not np.array_equal(changed.delayed["thetahat"], base.delayed["thetahat"])

    data = json.loads(short["card"].read_text())
    data["problem"]["plant"]["parameters"]["theta"] = new        # what the observer would read if it did
    old = base.metrics["theta"]["true"]                          # the premise family stays the designed one
    data["problem"]["observer"]["premise"]["theta"] = data["premise"]["theta"] = old
    other = build_observer(card_from_data(data), tmp_path / "other.fmu", backend="python")
    again = cosimulate(short["plant"], other, steps, plant_parameters={"theta": new}, show_progress=False)
    for name in ("xhat", "r"):
        np.testing.assert_array_equal(getattr(again, name), getattr(changed, name))
    for name in ("thetahat", "sigma_min", "valid"):
        np.testing.assert_array_equal(again.delayed[name], changed.delayed[name])


class _ConstantInput:
    """``u = 10`` at every point (the interface of :class:`uiofmu.cosim.inputs.SignalInputs`)."""

    sizes = {"u": 1, "d": 0}

    def values(self, t):
        return {"u": np.array([10.0]), "d": np.zeros(0)}


def test_ecospy_runs_the_loop_equal_to_our_master(built):
    """ecospy (a native Jacobi master) runs plant and observer for 0.3 s, ``y`` and ``ydot`` connected by name:
    equal to our master.

    The input is constant: ecospy copies the plant's ``ydot`` to the observer right after the plant's step,
    before its pre-step listener sets the next ``u`` on the plant, so with a varying ``u`` the observer gets
    ``C x'`` at ``u(t_{k-1})`` where our master gives it ``C x'`` at ``u(t_k)`` (the ``ydot`` of the held input of
    the step to come); with the problem's sines that differs by ~1e-3 in ``xhat``."""
    short = built["short"]
    ours, _ = ecospy_equals_master(short["plant"], short["obs"], H, STEPS, _ConstantInput(), fed={"y": 2, "ydot": 2})
    assert np.ptp(ours.xhat) > 0.1 and ours.metrics["validity"]["points_valid"] > 0


def test_a_step_that_needs_too_many_substeps_is_refused_not_run(built):
    """h / max_substep RK4 substeps a step, bounded by MAX_SUBSTEPS: h = 10 s (2e5 substeps, about 47 s
    of CPU) is answered at once with fmi2Discard and the longest step accepted; the next step goes through."""
    import time

    from uiofmu.cosim.fmi import Fmu, FmuCallError
    from uiofmu.runtime.delayed import MAX_SUBSTEPS

    ex = built["example"]
    plant = _plant_runtime(ex["toml"])
    longest = MAX_SUBSTEPS * _card(ex["card"]).schedule["max_substep"]
    with Fmu(ex["obs"], "observer") as fmu:
        fmu.initialize(0.0)
        _drive(fmu, None, plant, 0.0, 0, 1100)                # past the premise's start: the observer runs
        assert fmu.get("valid")[0] == 1.0
        start, began = len(fmu.messages), time.perf_counter()
        with pytest.raises(FmuCallError) as info:
            fmu.step(1.1, 10.0)
        assert info.value.status == 2 and time.perf_counter() - began < 2.0     # fmi2Discard: nothing changed
        log = " ".join(fmu.messages[start:])
        assert "h = 10 s needs" in log and f"take steps of at most {longest:.6g} s" in log, log
        fmu.step(1.1, H)
