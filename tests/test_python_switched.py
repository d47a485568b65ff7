"""Switched observers and plants (seed 002) as pythonfmu FMUs (backend "python"), really built and run.

Two designs: the paper's setup 2 (dead-beat, two modes) and a three-mode plant of our own
(n = 3, p = 2, q = 1, a known input, one fixed eigenvalue per mode: 0.5, -0.6, 0.3, so the
design is an LMI one with decay 0.6001, not dead-beat). Their observer FMUs, driven through fmpy
(:class:`uiofmu.cosim.fmi.Fmu`), equal :class:`uiofmu.runtime.observer.Runtime` bit for bit over
a random mode sequence; a mode outside 1..N is refused with fmi2Error and a log line; the FMU
state, saved, restored and serialised, carries the previous mode. The switched plant FMUs
(rules threshold, input, random) equal :class:`uiofmu.runtime.switching.SwitchedPlantRuntime`. A
plant and observer loop runs in a second importer, ecospy, equal to our master.
"""

from __future__ import annotations

import json
import tomllib
import zipfile
from xml.etree import ElementTree

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.validation import validate_fmu

from importers import TableInputs, call_error, check_state_round_trip, ecospy_equals_master
from uiofmu.cosim.fmi import Fmu, read_model_json
from uiofmu.fmu.export import build_observer, build_plant
from uiofmu.problem import problem_from_data
from uiofmu.runtime.fmu_model import make_model
from uiofmu.runtime.observer import Runtime
from uiofmu.runtime.switching import SwitchedPlantRuntime
from uiofmu.synthesis import design

#: Seed 002, setup 2 (Millerioux and Daafouz): the paper's rule, mode 1 while x[1] < 6 (x0 ours, so that the
#: observer, started at 0, has an initial error).
SETUP2 = """
name = "millerioux-daafouz-setup2"
[plant]
time = "discrete"
dt = 1.0
x0 = [1.0, -2.0, 0.5]
C = [[1.0, 1.0, -1.0], [2.0, -1.0, 1.0]]
E = [[1.0], [-2.0], [1.0]]
[[plant.modes]]
A = [[0.0, 0.89, -2.0], [-1.28, 0.89, 0.0], [-0.1, 0.0, 0.1]]
[[plant.modes]]
A = [[0.0, 0.89, -2.0], [1.95, 0.89, 0.0], [-0.1, 0.0, 0.1]]
w = [0.0, -18.0, 0.0]
[plant.switching]
rule = "threshold"
state = 1
threshold = 6.0
[observer]
family = "switched"
decay = "max"
"""
#: The fixed eigenvalue of each mode of the three-mode plant (their largest modulus is the decay's floor).
FIXED = (0.5, -0.6, 0.3)
#: Steps of every run against a reference.
STEPS = 100


def three_mode_data(switching: dict) -> dict:
    """A random three-mode switched plant, n = 3, p = 2, q = 1, m = 1, that is not dead-beat.

    In coordinates x' = T^-1 x, ``C' = [I 0]`` and ``E' = e_2``; a zero ``A'[0, 2]`` keeps
    ``C (I - E (CE)^+ C) A`` in the row space of ``C``, so rank [C; C At_i] = 2 < 3 and x'_3 is
    unobservable with its eigenvalue ``A'[2, 2]``: a fixed eigenvalue of (At_i, Ct_i).

    Parameters
    ----------
    switching : dict
        The ``[plant.switching]`` table.

    Returns
    -------
    dict
        The problem as :func:`uiofmu.problem.problem_from_data` takes it.
    """
    rng = np.random.default_rng(7)
    T = rng.normal(size=(3, 3)) + 2 * np.eye(3)
    Ti = np.linalg.inv(T)
    modes = []
    for fixed in FIXED:
        A = rng.uniform(-1, 1, size=(3, 3))
        A[0, 2], A[2, 2] = 0.0, fixed
        modes.append({"A": (Ti @ A @ T).tolist(), "w": rng.normal(size=3).tolist()})
    C = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]) @ T
    return {"name": "three-mode", "plant": {"time": "discrete", "dt": 0.5, "C": C.tolist(),
                                            "E": (Ti @ np.array([[0.0], [1.0], [0.0]])).tolist(),
                                            "B": rng.normal(size=(3, 1)).tolist(), "modes": modes,
                                            "switching": switching},
            "observer": {"family": "switched", "decay": "max"}}


PROBLEMS = {
    "setup2": lambda: problem_from_data(tomllib.loads(SETUP2)),
    "three": lambda: problem_from_data(three_mode_data({"rule": "input"})),
}
#: The plant of each rule: setup 2 for the paper's threshold, the three-mode plant for the others.
PLANTS = {
    "threshold": lambda: problem_from_data(tomllib.loads(SETUP2)),
    "input": lambda: problem_from_data(three_mode_data({"rule": "input", "mode0": 2})),
    "random": lambda: problem_from_data(three_mode_data({"rule": "random", "probabilities": [0.2, 0.5, 0.3],
                                                         "seed": 11})),
}


@pytest.fixture(scope="module")
def built(tmp_path_factory, observer_fmus):
    """``built(kind, key)``: ``(problem, card or None, FMU path)``, made once per module.

    ``kind`` is ``"obs"`` (key in :data:`PROBLEMS`) or ``"plant"`` (key in :data:`PLANTS`). Setup 2's observer
    is conftest's (examples/seed002_setup2.toml: the same plant and observer), built once per session.
    """
    root = tmp_path_factory.mktemp("switched_python")
    made: dict = {}

    def get(kind: str, key: str):
        if (kind, key) not in made:
            if (kind, key) == ("obs", "setup2"):
                made[kind, key] = (PROBLEMS[key](), *observer_fmus("setup2_card", "python"))
            elif kind == "obs":
                problem = PROBLEMS[key]()
                card = design(problem)
                made[kind, key] = problem, card, build_observer(card, root / f"obs_{key}.fmu", backend="python")
            else:
                problem = PLANTS[key]()
                made[kind, key] = problem, None, build_plant(problem.plant, f"{problem.name}-{key}",
                                                             root / f"plant_{key}.fmu", backend="python")
        return made[kind, key]

    return get


def _observer_outputs(source) -> np.ndarray:
    """``xhat, r, dhat`` of an observer FMU or a :class:`Runtime`."""
    if isinstance(source, Runtime):
        return np.concatenate([source.xhat(), source.residual(), source.dhat()])
    return np.concatenate([source.get("xhat"), source.get("r"), source.get("dhat")])


def _observer_inputs(card, steps: int, seed: int):
    """Random ``(y, u, mode)`` per step; modes uniform in 1..N."""
    rng = np.random.default_rng(seed)
    d = card.dims
    return (rng.normal(size=(steps, d["p"])), rng.normal(size=(steps, d["m"])),
            rng.integers(1, card.schedule["modes"] + 1, size=steps))


def _drive(fmu, inputs, t0: float, h: float) -> np.ndarray:
    """Set each step's inputs, read the outputs, step; the outputs before every step."""
    out, t = [], t0
    for y, u, mode in zip(*inputs):
        fmu.set("y", y)
        fmu.set("u", u)
        fmu.set("mode", [mode])
        out.append(_observer_outputs(fmu))
        fmu.step(t, h)
        t += h
    return np.array(out)


def _run(rt: Runtime, inputs, h: float) -> np.ndarray:
    """The runtime driven as :func:`_drive` drives the FMU.

    Parameters
    ----------
    rt : Runtime
    inputs : tuple of ndarray
        ``(y, u, mode)``, one row per step (:func:`_observer_inputs`).
    h : float
        The step.

    Returns
    -------
    ndarray
        ``xhat, r, dhat`` before every step, one row per step.
    """
    out = []
    for y, u, mode in zip(*inputs):
        rt.set_y(y)
        rt.set_u(u)
        rt.set_mode(int(mode))
        out.append(_observer_outputs(rt).copy())
        rt.step(h)
    return np.array(out)


# -- model descriptions ---------------------------------------------------------------------------------------
def _expected_attributes(spec) -> tuple:
    """(type, causality, variability, initial) of the FMI variables of a declared port."""
    if spec.causality == "parameter":
        return spec.type, "parameter", "fixed", "exact"
    variability = "continuous" if spec.type == "Real" else "discrete"
    return spec.type, spec.causality, variability, "calculated" if spec.causality == "output" else None


@pytest.mark.parametrize("kind, key", [("obs", "setup2"), ("obs", "three"), ("plant", "threshold"),
                                       ("plant", "input"), ("plant", "random")])
def test_model_description_lists_the_integer_ports_in_declaration_order(built, kind, key):
    """Every variable at its index in the declaration (value reference = index, the C backend's
    numbering), Integer ones discrete (FMI 2.0 has no continuous Integer), the model structure
    the declaration's, and fmpy's validation finds nothing."""
    _, _, path = built(kind, key)
    assert validate_fmu(str(path)) == []
    specs = [port.spec for port in make_model(read_model_json(path)).ports]
    expected = [(f"{s.name}[{i + 1}]", *_expected_attributes(s)) for s in specs for i in range(s.size)]
    with zipfile.ZipFile(path) as z:                        # the attributes as written (fmpy adds defaults)
        root = ElementTree.fromstring(z.read("modelDescription.xml"))
    written = root.find("ModelVariables").findall("ScalarVariable")
    found = [(v.get("name"), v[0].tag, v.get("causality"), v.get("variability"), v.get("initial")) for v in written]
    assert found == expected
    assert [int(v.get("valueReference")) for v in written] == list(range(len(expected)))
    md = read_model_description(str(path))
    integers = {s.name for s in specs if s.type == "Integer"}
    assert integers == ({"mode_prev0", "mode"} if kind == "obs" else {"seed", "mode", "mismatch_seed"}
                        if key == "random" else {"mode", "mismatch_seed"})
    index = {v.name: i for i, v in enumerate(md.modelVariables)}
    depends = {f"{s.name}[{i + 1}]": [f"{d}[{j + 1}]" for d in s.depends for j in range(
        next(t.size for t in specs if t.name == d))] for s in specs if s.causality == "output" for i in range(s.size)}
    assert [u.variable.name for u in md.outputs] == list(depends)
    for unknown in md.outputs:
        assert [index[v.name] for v in unknown.dependencies] == [index[n] for n in depends[unknown.variable.name]]
    if kind == "obs":
        starts = {v.name: v.start for v in md.modelVariables if v.type == "Integer"}
        assert starts == {"mode_prev0[1]": "1", "mode[1]": "1"}


# -- observers ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("key", ["three"])          # setup 2 from the card's xhat0 and mode_prev0: test_conformance.py
def test_observer_equals_the_runtime_over_a_random_mode_sequence(built, key):
    problem, card, path = built("obs", key)
    N, h = card.schedule["modes"], card.schedule["dt"]
    rng = np.random.default_rng(21)
    xhat0, mode_prev0 = rng.normal(size=card.dims["n"]), N       # not the card's defaults (0, mode 1)
    inputs = _observer_inputs(card, STEPS, seed=5)
    assert set(inputs[2]) == set(range(1, N + 1))
    if key == "three":                                            # an LMI design, not a dead-beat one
        assert card.data["design_method"] == "lmi" and max(map(abs, FIXED)) < card.data["decay_bound"] < 1
    rt = Runtime(card, xhat0=xhat0, mode_prev0=mode_prev0)
    with Fmu(path, "observer") as fmu:
        fmu.initialize(0.0, {"xhat0": xhat0, "mode_prev0": [mode_prev0]})
        assert fmu.get("mode_prev0").tolist() == [mode_prev0]
        got = _drive(fmu, inputs, 0.0, h)
    np.testing.assert_array_equal(got, _run(rt, inputs, h))
    assert np.all(np.isfinite(got)) and np.ptp(got) > 0


@pytest.mark.parametrize("key", ["three"])          # setup 2's modes 0 and N + 1: test_conformance.py
def test_a_bad_mode_is_refused_with_an_error_and_a_log_line(built, key):
    """Modes 0 and N + 1 (and the ends of the Integer range): fmi2Error, the mode and the range in
    the log line, the observer's state unchanged; then it steps on, equal to the runtime."""
    _, card, path = built("obs", key)
    N, h = card.schedule["modes"], card.schedule["dt"]
    inputs = _observer_inputs(card, 10, seed=9)
    rt = Runtime(card)
    with Fmu(path, "observer") as fmu:
        fmu.initialize(0.0)
        _drive(fmu, tuple(v[:5] for v in inputs), 0.0, h)
        t = 5 * h
        for bad in (0, N + 1, -2 ** 31, 2 ** 31 - 1):
            before_state = json.loads(fmu.serialize(fmu.get_state()))["model"]["runtime"]
            before = _observer_outputs(fmu)
            fmu.set("mode", [bad])
            exc = call_error(fmu.step, t, h)
            assert exc.status == 3, exc                                  # fmi2Error, not fmi2Fatal
            assert any(f"mode = {bad} " in m and f"from 1 to {N}" in m for m in exc.messages), exc.messages
            np.testing.assert_array_equal(_observer_outputs(fmu), before)
            after_state = json.loads(fmu.serialize(fmu.get_state()))["model"]["runtime"]
            assert after_state.pop("mode") == bad                       # the input as set, nothing else
            assert after_state == {k: v for k, v in before_state.items() if k != "mode"}
        got = _drive(fmu, tuple(v[5:] for v in inputs), t, h)
    _run(rt, tuple(v[:5] for v in inputs), h)
    np.testing.assert_array_equal(got, _run(rt, tuple(v[5:] for v in inputs), h))


def test_a_bad_mode_prev0_stops_the_observer_with_a_log_line(built):
    _, card, path = built("obs", "three")
    N, h = card.schedule["modes"], card.schedule["dt"]
    for bad in (0, N + 1):
        with Fmu(path, "observer") as fmu:
            exc = call_error(fmu.initialize, 0.0, {"mode_prev0": [bad]})
            assert exc.status == 3 and exc.function == "fmi2ExitInitializationMode", exc
            assert any(f"mode_prev0 = {bad} " in m and f"from 1 to {N}" in m for m in exc.messages), exc.messages
            exc = call_error(fmu.step, 0.0, h)
            assert exc.status == 3 and any("phase 'invalid'" in m for m in exc.messages), exc.messages
            assert np.all(np.isfinite(fmu.get("xhat")))              # still alive


def test_real_and_integer_accesses_of_the_wrong_type_are_refused(built):
    """fmi2GetReal / fmi2SetReal on an Integer variable and fmi2GetInteger / fmi2SetInteger on a
    Real one: fmi2Error, a log line naming the variable and both types, nothing set; a fixed
    Integer parameter cannot be set after initialisation."""
    _, card, path = built("obs", "three")
    h = card.schedule["dt"]
    with Fmu(path, "observer") as fmu, Fmu(path, "reference") as ref:
        for f in (fmu, ref):
            f.initialize(0.0)
        mode, y, mode_prev0 = fmu.refs("mode")[0], fmu.refs("y")[0], fmu.refs("mode_prev0")[0]
        fmu.set("mode", [2])
        cases = [
            (("getReal", [mode]), "mode[1]) is an Integer variable, not Real"),
            (("setReal", [mode], [3.0]), "mode[1]) is an Integer variable, not Real"),
            (("getInteger", [y]), "y[1]) is a Real variable, not Integer"),
            (("setInteger", [y], [7]), "y[1]) is a Real variable, not Integer"),
            (("setInteger", [mode, y], [3, 7]), "y[1]) is a Real variable, not Integer"),
            (("setInteger", [mode_prev0], [2]), "parameter mode_prev0[1] (value reference"),
        ]
        for (function, *args), text in cases:
            exc = call_error(fmu._call, function, *args)
            assert exc.status == 3 and any(text in m for m in exc.messages), (function, exc.messages)
        assert fmu.get("mode").tolist() == [2.0] and fmu.get("mode_prev0").tolist() == [1.0]
        inputs = _observer_inputs(card, 5, seed=2)
        np.testing.assert_array_equal(_drive(fmu, inputs, 0.0, h), _drive(ref, inputs, 0.0, h))


def test_state_save_restore_and_serialisation_are_bit_exact_with_the_previous_mode(built):
    """Saved after 30 steps, restored in the same instance and deserialised in another: the next
    20 steps are identical, the state serialises to the same bytes; the previous mode is part of
    it (a state edited to another previous mode gives another estimate, one edited to a mode
    outside 1..N is refused with a log line and changes nothing)."""
    _, card, path = built("obs", "three")
    N, h = card.schedule["modes"], card.schedule["dt"]
    inputs = _observer_inputs(card, 50, seed=13)
    first, rest = tuple(v[:30] for v in inputs), tuple(v[30:] for v in inputs)
    with Fmu(path, "a") as a, Fmu(path, "b") as b:
        state, blob, _ = check_state_round_trip(a, b, _drive, first, rest, h)
        saved = json.loads(blob)["model"]["runtime"]
        assert saved["k"] == 30 and saved["mode_prev"] == int(first[2][-1]) and saved["mode"] == saved["mode_prev"]

        doc = json.loads(blob)
        other = saved["mode_prev"] % N + 1
        doc["model"]["runtime"]["mode_prev"] = other
        b.set_state(b.deserialize(json.dumps(doc).encode()))
        b.set("y", rest[0][0])
        rt = Runtime(card)
        rt.set_state({**saved, "mode_prev": other, "y": rest[0][0].tolist()})
        np.testing.assert_array_equal(b.get("xhat"), rt.xhat())
        a.set_state(state)
        a.set("y", rest[0][0])
        assert not np.array_equal(b.get("xhat"), a.get("xhat"))   # Q of another mode

        before = b.serialize(b.get_state())
        doc["model"]["runtime"]["mode_prev"] = N + 1
        exc = call_error(b.set_state, b.deserialize(json.dumps(doc).encode()))
        assert exc.status == 3 and any("mode_prev" in m for m in exc.messages), exc.messages
        assert b.serialize(b.get_state()) == before


def test_a_restored_state_restores_the_mode_input(built):
    """The mode set before a state was taken is the mode of the next step after its restore, as
    ``y`` and ``u`` are (no input set in between)."""
    _, card, path = built("obs", "three")
    h = card.schedule["dt"]
    rt = Runtime(card)
    rng = np.random.default_rng(21)
    y, u = rng.normal(size=card.dims["p"]), rng.normal(size=card.dims["m"])
    with Fmu(path, "a") as a:
        a.initialize(0.0)
        a.set("y", y)
        rt.set_y(y)
        a.set("u", u)
        rt.set_u(u)
        a.set("mode", [2])
        rt.set_mode(2)
        state = a.get_state()
        a.set("mode", [1])
        a.set_state(state)
        a.step(0.0, h)
        rt.step(h)
        a.set("y", y)
        rt.set_y(y)
        np.testing.assert_array_equal(a.get("xhat"), rt.xhat())
        assert a.get("mode")[0] == 2


# -- plants ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("rule", PLANTS)
def test_switched_plant_equals_the_runtime(built, rule):
    problem, _, path = built("plant", rule)
    plant = problem.plant
    N, h = plant.N, plant.dt
    rng = np.random.default_rng(17)
    rt = SwitchedPlantRuntime(plant.to_data())
    x0 = rng.normal(size=plant.n)
    parameters = {"x0": x0}
    rt.x0 = x0.copy()
    if rule == "random":
        parameters["seed"] = [123456789]
        rt.seed = 123456789
    rt.reset()
    modes = []
    with Fmu(path, "plant") as fmu:
        fmu.initialize(0.0, parameters)
        t = 0.0
        for k in range(STEPS):
            u, d = rng.normal(size=plant.m), rng.uniform(-1.0, 1.0, size=plant.q)
            fmu.set("u", u)
            fmu.set("d", d)
            rt.u[:], rt.d[:] = u, d
            if rule == "input":
                mode = int(rng.integers(1, N + 1))
                fmu.set("mode", [mode])
                rt.mode_in = mode
            np.testing.assert_array_equal(fmu.get("x"), rt.x, err_msg=f"step {k}")
            np.testing.assert_array_equal(fmu.get("y"), rt.y(), err_msg=f"step {k}")
            assert fmu.get("mode").tolist() == [rt.mode()], k
            modes.append(rt.mode())
            fmu.step(t, h)
            rt.step(h)
            t += h
        np.testing.assert_array_equal(fmu.get("x"), rt.x)
    assert set(modes) == set(range(1, N + 1)), modes                 # every mode was visited


def test_input_rule_plant_refuses_a_bad_mode(built):
    problem, _, path = built("plant", "input")
    N, h = problem.plant.N, problem.plant.dt
    with Fmu(path, "plant") as fmu:
        fmu.initialize(0.0)
        assert fmu.get("mode").tolist() == [2.0]                    # mode0 of the switching table
        before = fmu.get("x")
        for bad in (0, N + 1):
            fmu.set("mode", [bad])
            exc = call_error(fmu.step, 0.0, h)
            assert exc.status == 3 and any(f"mode = {bad} " in m and f"from 1 to {N}" in m for m in exc.messages)
            np.testing.assert_array_equal(fmu.get("x"), before)
        fmu.set("mode", [3])
        fmu.step(0.0, h)


def test_random_plant_state_carries_the_generator_and_mode_is_an_output(built):
    problem, _, path = built("plant", "random")
    h = problem.plant.dt
    with Fmu(path, "plant") as fmu, Fmu(path, "other") as other:
        fmu.initialize(0.0)
        other.initialize(0.0)
        mode = fmu.refs("mode")[0]
        exc = call_error(fmu._call, "setInteger", [mode], [1])
        assert exc.status == 3 and any("is an output: fmi2SetInteger on it is not allowed" in m for m in exc.messages)

        def run(f, t0):
            out = []
            for k in range(20):
                out.append((f.get("mode")[0], *f.get("x")))
                f.step(t0 + k * h, h)
            return np.array(out)

        run(fmu, 0.0)
        blob = fmu.serialize(fmu.get_state())
        once = run(fmu, 20 * h)
        assert len(set(once[:, 0])) > 1
        other.set_state(other.deserialize(blob))
        np.testing.assert_array_equal(run(other, 20 * h), once)


# -- a second importer ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("rule, key", [("threshold", "setup2"), ("input", "three")])
def test_ecospy_runs_the_switched_loop_equal_to_our_master(built, rule, key):
    """ecospy connects the plant's Integer ``mode`` to the observer's (rule threshold) or sets both
    from the input source (rule input), with a bounded random unknown input; the histories equal
    our master's, and the dead-beat observer of setup 2 has no error after one step."""
    plant_problem, _, plant = built("plant", rule)
    _, card, observer = built("obs", key)
    h, K = card.schedule["dt"], 40
    rng = np.random.default_rng(3)
    p = plant_problem.plant
    table = {"u": rng.normal(size=(K + 1, p.m)), "d": rng.uniform(-1.0, 1.0, size=(K + 1, p.q))}
    if rule == "input":
        table["mode"] = rng.integers(1, p.N + 1, size=(K + 1, 1)).astype(float)
    fed = {"y": p.p, "mode": 1} if rule == "threshold" else {"y": p.p}
    ours, theirs = ecospy_equals_master(plant, observer, h, K, TableInputs(h, table), fed=fed, what=rule)
    modes = (1 + (ours.x[:-1, 0] >= 6.0)) if rule == "threshold" else table["mode"][:-1, 0]
    assert set(modes.astype(int)) == set(range(1, p.N + 1)), modes
    if key == "setup2":
        err = np.linalg.norm(theirs.x - theirs.xhat, axis=1)
        assert err[0] > 0
        assert np.all(err[1:] <= 1e-9 * np.maximum(1.0, np.linalg.norm(theirs.x[1:], axis=1))), err
