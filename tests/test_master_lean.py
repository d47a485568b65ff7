"""The lean co-simulation master gives, bit for bit, what a straightforward master gives.

:func:`reference_loop` is the loop as one writes it first: at each point the input source's values,
then one :meth:`Fmu.set` / :meth:`Fmu.get` per vector (by name), then both doSteps. The master
(:func:`uiofmu.cosim.master.cosimulate`) makes one call per FMU, direction and type on buffers
allocated once, with the inputs evaluated for all points beforehand; its histories must equal the
reference's exactly, for the two-room building (sampled-data observer, drop-outs), a switched
observer with an Integer mode the plant feeds it, and a functional observer whose plant and
observer take a scheduling input theta. The vectorised signals, input tables and communication
points are checked against their pointwise forms bit for bit.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

from uiofmu.cosim.fmi import Fmu
from uiofmu.cosim.inputs import CsvInputs, SignalInputs, values_at
from uiofmu.cosim.master import communication_points, cosimulate, default_inputs, observer_card, routes
from uiofmu.cosim.steps import step_sequence
from uiofmu.fmu.c_backend import c_compiler
from uiofmu.fmu.export import build_observer, build_plant
from uiofmu.problem import load_problem, problem_from_data
from uiofmu.signals import parse_signals

needs_cc = pytest.mark.skipif(c_compiler() is None, reason="no C compiler")


def reference_loop(plant_path, observer_path, steps, inputs=None, plant_parameters=None) -> dict:
    """The co-simulation loop written plainly with :meth:`Fmu.get` / :meth:`Fmu.set`; its histories."""
    card = observer_card(observer_path)
    inputs = inputs or default_inputs(card)
    K = len(steps)
    with Fmu(plant_path, "plant") as plant, Fmu(observer_path, "observer") as obs:
        fed, sourced = routes(plant, obs, inputs.sizes)
        plant.initialize(0.0, plant_parameters)
        obs.initialize(0.0)
        out = {"times": [], "x": [], "y": [], "u": [], "d": [], "mode": [],
               **{name: [] for name in obs.ports("output")}}
        t = 0.0
        for k in range(K + 1):
            values = inputs.values(t)
            for name in plant.ports("input"):
                plant.set(name, values[name])
            for name in fed:
                obs.set(name, plant.get(name))
            for name in sourced:
                obs.set(name, values[name])
            out["times"].append(t)
            out["x"].append(plant.get("x"))
            out["y"].append(plant.get("y"))
            out["u"].append(values.get("u", np.zeros(len(plant.refs("u")))))
            out["d"].append(values.get("d", np.zeros(len(plant.refs("d")))))
            if obs.has("mode"):
                out["mode"].append((plant.get("mode") if "mode" in fed else np.round(values["mode"]))[0])
            for name in obs.ports("output"):
                out[name].append(obs.get(name))
            if k == K:
                break
            obs.step(t, steps[k])
            plant.step(t, steps[k])
            t = float(np.sum(steps[:k + 1])) if k % 1024 == 1023 else t + steps[k]
    return {name: np.array(v, dtype=float) for name, v in out.items()}


def assert_same_histories(result, ref: dict) -> None:
    """Every history of ``result`` equals the reference's bit for bit."""
    pairs = {"times": result.times, "x": result.x, "y": result.y, "u": result.u, "d": result.d}
    if result.functional is not None:
        pairs.update(gx=result.functional["gx"], gx_valid=result.functional["valid"][:, None])
    else:
        pairs.update(xhat=result.xhat, r=result.r)
        if result.dhat.shape[1]:
            pairs["dhat"] = result.dhat
    if result.mode is not None:
        pairs["mode"] = result.mode
    for name, mine in pairs.items():
        theirs = ref[name].reshape(mine.shape)
        assert mine.dtype == theirs.dtype and mine.tobytes() == theirs.tobytes(), name


@needs_cc
def test_building_with_drop_outs_bit_for_bit(building_card, building_path, tmp_path):
    card, _ = building_card
    problem = load_problem(building_path)
    obs = build_observer(card, tmp_path / "obs.fmu", backend="c")
    plant = build_plant(problem.plant, "building", tmp_path / "plant.fmu", backend="c")
    steps = step_sequence("dropout:600:0.3:11", 172800.0, seed=11)
    result = cosimulate(plant, obs, steps, show_progress=False)
    assert result.timing["fmi_calls_per_step"] == 6            # one set, one get per FMU, two doSteps
    assert_same_histories(result, reference_loop(plant, obs, steps))
    assert result.metrics["bound_respected"] is True


@needs_cc
def test_switched_with_an_integer_mode_bit_for_bit(tmp_path):
    from tests.conftest import EXAMPLES
    from uiofmu.synthesis import design

    data = copy.deepcopy(load_problem(EXAMPLES / "seed002_setup2.toml").data)
    data["plant"]["switching"] = {"rule": "random", "probabilities": [0.5, 0.5], "seed": 1}
    problem = problem_from_data(data)
    card = design(problem)
    obs = build_observer(card, tmp_path / "obs.fmu", backend="c")
    plant = build_plant(problem.plant, problem.name, tmp_path / "plant.fmu", backend="c")
    steps = step_sequence("fixed:1.0", 40.0)
    d = parse_signals([[{"kind": "random", "seed": 4, "std": 0.05, "hold": 1.0}]], "signals.d", 1)
    inputs = SignalInputs((), d)
    result = cosimulate(plant, obs, steps, inputs, plant_parameters={"seed": [3]}, show_progress=False)
    assert result.metrics["modes"]["switches"] > 0
    assert result.timing["fmi_calls_per_step"] == 8            # the mode: fmi2GetInteger, fmi2SetInteger
    assert_same_histories(result, reference_loop(plant, obs, steps, inputs, {"seed": [3]}))


def test_functional_with_a_scheduling_input_bit_for_bit(tmp_path):
    from test_deadbeat_functional import THETA_PLANT
    from uiofmu.synthesis import design

    problem = problem_from_data(copy.deepcopy(THETA_PLANT))
    card = design(problem)
    obs = build_observer(card, tmp_path / "obs.fmu", backend="python")
    plant = build_plant(problem.plant, problem.name, tmp_path / "plant.fmu", problem.options.step,
                        backend="python")
    steps = step_sequence(f"fixed:{problem.options.step!r}", 30 * problem.options.step)
    base = default_inputs(card)
    theta = parse_signals([[{"kind": "sine", "amplitude": 0.2, "frequency_hz": 0.05, "offset": 0.5}]],
                          "signals.theta", 1)
    inputs = SignalInputs(base.signals["u"], base.signals["d"], theta=theta)
    result = cosimulate(plant, obs, steps, inputs, show_progress=False)
    assert result.functional is not None and np.any(result.functional["valid"] > 0.5)
    assert result.timing["fmi_calls_per_step"] == 7            # and fmi2GetInteger for gx_valid
    assert_same_histories(result, reference_loop(plant, obs, steps, inputs))


# -- vectorised inputs ---------------------------------------------------------------------------------

TERMS = [
    [{"kind": "constant", "value": 8.0}, {"kind": "sine", "amplitude": 4.0, "frequency_hz": 1.1574074074074073e-05,
                                          "phase": -1.5707963267948966}],
    [{"kind": "constant", "value": 800.0}, {"kind": "sine", "amplitude": 100.0, "omega": 2.9e-4, "offset": -3.0}],
    [{"kind": "random", "seed": 7, "std": 2.0, "mean": 0.5, "hold": 600.0},
     {"kind": "step", "time": 1800.0, "value": -0.0, "initial": 2.5}],
    [{"kind": "constant", "value": -0.0}],
    [],
]


def _times() -> np.ndarray:
    rng = np.random.default_rng(5)
    steps = rng.choice([600.0, 1200.0, 0.1, 1e-7], size=2500)
    return np.concatenate([communication_points(steps), [-3.0, 1800.0, 599.9999999999, 1e12]])


def test_signals_at_all_times_bit_for_bit():
    times = _times()
    for signal in parse_signals(TERMS, "signals.u", len(TERMS)):
        at = signal.at(times)
        one_by_one = np.array([signal(t) for t in times.tolist()])
        assert at.dtype == one_by_one.dtype and at.tobytes() == one_by_one.tobytes(), signal
        for term in signal.terms:
            assert term.at(times).tobytes() == np.array([term(t) for t in times.tolist()], dtype=float).tobytes()


def test_signal_inputs_and_tables_at_all_times_bit_for_bit(tmp_path):
    times = _times()
    u = parse_signals(TERMS[:2], "signals.u", 2)
    d = parse_signals(TERMS[2:], "signals.d", 3)
    table = tmp_path / "in.csv"
    table.write_text("time,u[1],d[1]\n0,1.0,0.0\n1.0,-1.0,2.0\n2.5,0.0,-3.0\n1e4,7,8\n")
    for source in (SignalInputs(u, d, mode=u[:1]), CsvInputs(table, {"u": 1, "d": 1})):
        at = values_at(source, times)
        for k, t in enumerate(times.tolist()):
            for name, vec in source.values(t).items():
                assert at[name][k].tobytes() == vec.tobytes(), (name, t)


class _PointwiseOnly:
    """An input source without ``values_at``: the master evaluates it point by point."""

    sizes = {"u": 1, "d": 2}

    def values(self, t):
        return {"u": np.array([np.sin(t)]), "d": np.array([t, -t])}


def test_sources_without_values_at_are_evaluated_point_by_point():
    times = _times()[:50]
    at = values_at(_PointwiseOnly(), times)
    assert at["u"].shape == (50, 1) and at["d"].shape == (50, 2)
    assert at["d"][:, 1].tobytes() == (-times).tobytes()


def test_communication_points_sum_as_the_loop_did():
    rng = np.random.default_rng(2)
    for K in (0, 1, 1023, 1024, 1025, 3000):
        steps = rng.uniform(0.01, 7.3, K) * rng.choice([1.0, 1e-3, 1e3], K)
        t, expected = 0.0, [0.0]
        for k in range(K):
            t = float(np.sum(steps[:k + 1])) if k % 1024 == 1023 else t + steps[k]
            expected.append(t)
        assert communication_points(steps).tobytes() == np.array(expected).tobytes(), K
