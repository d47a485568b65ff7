"""Bad calls into pythonfmu FMUs (backend "python"): refused with a log line, never fatal, never a crash.

What pythonfmu 0.7.0's native binary allows (see ``uiofmu/fmu/templates/pythonfmu_slave.py.tmpl``):
a Python exception becomes fmi2Fatal and leaves the instance with dangling pointers, a method
that returns gives fmi2OK (``do_step`` returning False gives fmi2Discard). So the slave refuses
a bad fmi2SetReal / fmi2GetReal / fmi2SetFMUstate with an fmi2Error log line and changes
nothing, and the native guard in front of the binary (:mod:`uiofmu.fmu.pythonfmu_guard`) turns
that line into the status fmi2Error; these tests check both, against a reference instance
driven alike.

Every FMU call runs in a child process (a segfault then fails the test instead of killing
pytest); the child prints one ``RESULT`` line of JSON.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

import uiofmu
from uiofmu.runtime.card import card_from_data
from uiofmu.fmu.export import build_observer, build_plant
from uiofmu.runtime.fmu_model import ObserverModel, StateRejected
from uiofmu.mujoco_plant import build_mujoco_plant, load_spec
from uiofmu.runtime.mujoco_runtime import MujocoRuntime
from uiofmu.runtime.plant_runtime import PlantRuntime
from uiofmu.runtime.observer import Runtime
from uiofmu.runtime.schedules import StepRejected
from tests.conftest import ROOT

QUARTER_CAR = ROOT / "plants" / "quarter_car"
#: Communication steps: the building observer's design intervals (h_prev changes), a quarter-car step.
BUILDING_STEPS = [600.0, 1200.0, 600.0, 1800.0]
CAR_STEPS = [0.01, 0.02]
#: Statuses a call that is not itself refused may answer: fmi2OK, fmi2Discard, fmi2Error; never fmi2Fatal (4).
NOT_FATAL = (0, 2, 3)

CHILD = r'''
"""One scenario against pythonfmu FMUs: python CHILD SCENARIO ARGS_JSON; prints RESULT <json>."""
import json
import pathlib
import sys
import tempfile
import zipfile

import numpy as np

from uiofmu.runtime.errors import FmuError
from uiofmu.cosim.fmi import Fmu, FmuCallError


def call(fmu, function, *args):
    """(status, log lines, value) of one FMI call; status 0 when fmpy raised nothing."""
    start = len(fmu.messages)
    try:
        value, status = fmu._call(function, *args), 0
    except FmuCallError as exc:
        value, status = None, exc.status
    return status, fmu.messages[start:], value


def plain(value):
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, (int, float, str, bool)) or value is None:
        return value
    return repr(value)


def ports(fmu, causality):
    names = []
    for v in fmu.description.modelVariables:
        base = v.name.split("[")[0]
        if v.causality == causality and base not in names:
            names.append(base)
    return names


def outputs(fmu):
    return np.concatenate([fmu.get(n) for n in ports(fmu, "output")]).tolist()


def drive(fmus, k0, steps, t0, hs):
    """The same inputs and steps into every instance; the outputs each showed before each step."""
    traces = [[] for _ in fmus]
    t = t0
    for k in range(k0, k0 + steps):
        h = hs[k % len(hs)]
        for f, trace in zip(fmus, traces):
            for j, name in enumerate(ports(f, "input")):
                f.set(name, [np.sin(0.7 * k + j + 0.3 * i) for i in range(len(f.refs(name)))])
            trace.append(outputs(f))
            f.step(t, h)
        t += h
    return traces, t


def value_refs(fmu):
    vr = {c: fmu.refs(ports(fmu, c)[0])[0] for c in ("input", "output", "parameter")}
    return vr["input"], vr["output"], vr["parameter"]


def scenario_refs(a):
    res = {}
    with Fmu(a["path"], "a") as f, Fmu(a["path"], "ref") as ref:
        f.initialize(0.0)
        ref.initialize(0.0)
        _, t = drive([f, ref], 0, 3, 0.0, a["hs"])
        inp, out, par = value_refs(f)
        name_in = ports(f, "input")[0]
        before, inputs = outputs(f), f.get(name_in).tolist()
        cases = {
            "get_unknown": ("getReal", [out, 99999]),
            "get_vr_above_int_max": ("getReal", [2 ** 32 - 1]),
            "set_unknown": ("setReal", [inp, 99999], [5.0, 5.0]),
            "set_output": ("setReal", [out], [123.0]),
            "set_input_and_output": ("setReal", [inp, out], [7.0, 7.0]),
            "set_fixed_parameter": ("setReal", [par], [3.0]),
            "get_integer": ("getInteger", [out, 99999]),
            "set_integer": ("setInteger", [inp], [1]),
            "get_boolean": ("getBoolean", [inp]),
            "set_boolean": ("setBoolean", [inp], [True]),
            "get_string": ("getString", [inp]),
            "set_string": ("setString", [inp], ["x"]),
        }
        for label, (function, *args) in cases.items():
            status, log, value = call(f, function, *args)
            res[label] = {"status": status, "log": log, "value": plain(value),
                          "unchanged": outputs(f) == before and f.get(name_in).tolist() == inputs}
        res["out_value"] = before[0]
        traces, _ = drive([f, ref], 3, 4, t, a["hs"])
        res["same_afterwards"] = traces[0] == traces[1]
    return res


def tampered(blob, good, spec):
    if "bytes" in spec:
        kind = spec["bytes"]
        return {"truncated": blob[: len(blob) // 2], "garbage": b"\x00\xff\xfegarbage", "empty": b"",
                "deep": b"[" * 100000}.get(kind, kind.encode())
    state = json.loads(json.dumps(good))
    *path, last = spec["path"]
    node = state
    for key in path:
        node = node[key]
    if spec.get("delete"):
        del node[last]
    else:
        node[last] = spec["value"]
    return json.dumps(state).encode()


def scenario_states(a):
    res = {"cases": {}}
    hs = a["hs"]
    with Fmu(a["path"], "a") as f, Fmu(a["path"], "ref") as ref:
        f.initialize(0.0)
        ref.initialize(0.0)
        _, t = drive([f, ref], 0, 3, 0.0, hs)
        state = f.get_state()
        blob = f.serialize(state)
        good = json.loads(blob)
        res["good"] = good
        before = outputs(f)
        for label, spec in a["tampers"]:
            data = tampered(blob, good, spec)
            st_d, log_d, q = call(f, "deSerializeFMUstate", data)
            st_s, log_s = (call(f, "setFMUstate", q)[:2]) if q is not None else (None, [])
            res["cases"][label] = {"deserialize": st_d, "set": st_s, "log": log_d + log_s,
                                   "unchanged": outputs(f) == before}
            if q is not None:
                f.slave.freeFMUstate(q)
        traces, t2 = drive([f, ref], 3, 3, t, hs)
        res["same_afterwards"] = traces[0] == traces[1]
        f.set_state(f.deserialize(blob))                    # its own state still restores exactly
        again, _ = drive([f], 3, 3, t, hs)
        res["own_state_restores"] = again[0] == traces[0]
    return res


def scenario_foreign(a):
    res = {}
    with Fmu(a["path"], "a") as f, Fmu(a["path"], "ref") as ref, Fmu(a["other"], "b") as g:
        for x in (f, ref, g):
            x.initialize(0.0)
        _, t = drive([f, ref], 0, 3, 0.0, a["hs"])
        drive([g], 0, 3, 0.0, a["hs_other"])
        mine = f.get_state()
        before = outputs(f)
        theirs = g.get_state()
        res["pointer"] = call(f, "setFMUstate", theirs)[:2]
        res["pointer_unchanged"] = outputs(f) == before
        q = f.deserialize(g.serialize(theirs))
        res["bytes"] = call(f, "setFMUstate", q)[:2]
        res["bytes_unchanged"] = outputs(f) == before
        traces, _ = drive([f, ref], 3, 3, t, a["hs"])
        res["same_afterwards"] = traces[0] == traces[1]
        f.set_state(mine)
        again, _ = drive([f], 3, 3, t, a["hs"])
        res["own_state_restores"] = again[0] == traces[0]
    return res


def rezip(path, out, change):
    tmp = pathlib.Path(tempfile.mkdtemp())
    with zipfile.ZipFile(path) as z:
        z.extractall(tmp)
    change(tmp)
    with zipfile.ZipFile(out, "w") as z:
        for p in tmp.rglob("*"):
            if p.is_file():
                z.write(p, p.relative_to(tmp).as_posix())
    return out


def scenario_instantiate(a):
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave
    from uiofmu.cosim.fmi import _release_python_state

    res = {}
    work = pathlib.Path(a["work"])

    def refused(path):
        try:
            with Fmu(path, "x") as f:
                f.initialize(0.0)
            return "instantiated"
        except FmuError as exc:
            return str(exc)

    def swap_model(d):
        p = d / "resources" / "model.json"
        p.write_bytes(p.read_bytes() + b" ")

    def edit_guid(d):
        p = d / "modelDescription.xml"
        text = p.read_text()
        guid = read_model_description(str(p)).guid
        p.write_text(text.replace(guid, "12345678-1234-5678-1234-567812345678"))

    def swap_model_and_guid(d):
        """The card edited and modelDescription.xml's GUID recomputed to match (as the slave computes it)."""
        import hashlib
        import re
        import uuid

        swap_model(d)
        ident = read_model_description(str(d / "modelDescription.xml")).coSimulation.modelIdentifier
        slave = next((d / "resources").glob("*_slave.py")).read_text()
        runtime = re.search(r'^RUNTIME = "([A-Za-z0-9_]+)"', slave, re.M).group(1)
        digest = hashlib.sha256((d / "resources" / "model.json").read_bytes()).hexdigest()
        new = str(uuid.uuid5(uuid.NAMESPACE_URL, f"uiofmu:pythonfmu:{runtime}:{ident}:{digest}"))
        p = d / "modelDescription.xml"
        p.write_text(p.read_text().replace(read_model_description(str(p)).guid.strip("{}"), new))

    res["other_model_json"] = refused(rezip(a["path"], work / "swapped.fmu", swap_model))
    res["edited_guid"] = refused(rezip(a["path"], work / "edited.fmu", edit_guid))
    res["model_and_guid"] = refused(rezip(a["path"], work / "both.fmu", swap_model_and_guid))
    res["intact"] = refused(a["path"])
    # the importer's fmuGUID never reaches the slave; the guard compares it with its own
    md = read_model_description(a["path"])
    d = extract(a["path"])
    s = FMU2Slave(guid="{bogus-guid}", unzipDirectory=d, modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName="bogus")
    try:
        s.instantiate()
        res["bogus_guid_instantiated"] = True
        s.fmi2FreeInstance(s.component)
    except Exception:  # noqa: BLE001 - fmpy raises a bare Exception for a failed instantiation
        res["bogus_guid_instantiated"] = False
    _release_python_state(s.dll)
    s.freeLibrary()
    return res


def scenario_empty_resources(a):
    """fmi2Instantiate with a resource location that does not hold the slave (pythonfmu 0.7.0 alone crashes)."""
    from ctypes import byref
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave, fmi2CoSimulation, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE

    md = read_model_description(a["path"])
    s = FMU2Slave(guid=md.guid, unzipDirectory=extract(a["path"]), modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName="x")
    lines = []
    callbacks = fmi2CallbackFunctions()
    callbacks.logger = fmi2CallbackLoggerTYPE(lambda *args: lines.append(args[-1]))
    empty = pathlib.Path(tempfile.mkdtemp()).as_uri()
    c = s.fmi2Instantiate(b"x", fmi2CoSimulation, md.guid.encode(), empty.encode(), byref(callbacks), 0, 1)
    return {"component": bool(c), "lines": len(lines)}


if __name__ == "__main__":
    result = globals()["scenario_" + sys.argv[1]](json.loads(sys.argv[2]))
    print("RESULT " + json.dumps(result), flush=True)
'''


def run_child(tmp_path, scenario: str, args: dict, allow_crash: bool = False):
    """Run a scenario in a child process; its RESULT (or the completed process when ``allow_crash``)."""
    script = tmp_path / "child.py"
    script.write_text(CHILD)
    proc = subprocess.run([sys.executable, str(script), scenario, json.dumps(args)], capture_output=True,
                          text=True, timeout=240, cwd=tmp_path, env={**os.environ, "PYTHONPATH": os.pathsep.join(
                              [str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])})
    if allow_crash:
        return proc
    assert proc.returncode == 0, f"child died with {proc.returncode}:\n{proc.stderr[-3000:]}"
    line = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    assert line, proc.stdout[-2000:] + proc.stderr[-2000:]
    return json.loads(line[-1][len("RESULT "):])


@pytest.fixture(scope="module")
def fmus(building_card, building_path, observer_fmus, tmp_path_factory):
    """The building observer (interval schedule) and, with the same ports, its 'nearest' variant;
    the building's linear plant; the MuJoCo quarter-car plant. All pythonfmu."""
    card, _ = building_card
    d = tmp_path_factory.mktemp("hardening")
    data = json.loads(card.to_json())
    data["schedule"]["step_policy"] = "nearest"
    problem = uiofmu.load_problem(building_path)
    return {"obs": str(observer_fmus("building_card", "python")[1]),
            "obs_nearest": str(build_observer(card_from_data(data), d / "obs_nearest.fmu", backend="python")),
            "plant": str(build_plant(problem.plant, problem.name, d / "plant.fmu", backend="python")),
            "mj": str(build_mujoco_plant(load_spec(QUARTER_CAR), d / "mj.fmu", backend="python"))}


def _refused(case, *fragments):
    """A refusal: fmi2Error (the slave's error line, turned into the status by the guard), logged, no change."""
    assert case["status"] == 3, case
    assert any(all(f in line for f in fragments) for line in case["log"]), case["log"]
    assert case["unchanged"], case


@pytest.mark.parametrize("which,hs", [("obs", BUILDING_STEPS), ("plant", BUILDING_STEPS)])
def test_bad_value_references_and_causalities_are_refused(fmus, tmp_path, which, hs):
    res = run_child(tmp_path, "refs", {"path": fmus[which], "hs": hs})
    _refused(res["get_unknown"], "fmi2GetReal", "value reference 99999 is not a variable of this FMU")
    _refused(res["get_vr_above_int_max"], "fmi2GetReal", "value reference 4294967295 is not a variable")
    _refused(res["set_unknown"], "fmi2SetReal", "value reference 99999", "nothing was set")   # all or nothing
    _refused(res["set_output"], "is an output", "nothing was set")
    _refused(res["set_input_and_output"], "is an output", "nothing was set")
    _refused(res["set_fixed_parameter"], "is fixed: it can only be set before initialisation ends")
    _refused(res["get_integer"], "fmi2GetInteger", "is a Real variable, not Integer")
    _refused(res["set_integer"], "fmi2SetInteger", "not Integer")
    _refused(res["get_boolean"], "fmi2GetBoolean", "not Boolean")
    _refused(res["set_boolean"], "fmi2SetBoolean", "not Boolean")
    _refused(res["get_string"], "fmi2GetString", "not String")
    _refused(res["set_string"], "fmi2SetString", "not String")
    assert res["same_afterwards"]                 # the instance goes on exactly as an untouched one


def _field(path, value=None, delete=False):
    return {"path": path, "value": value, "delete": delete}


RAW = [("truncated", {"bytes": "truncated"}, "are not a serialised uiofmu state"),
       ("garbage", {"bytes": "garbage"}, "UnicodeDecodeError"),
       ("empty", {"bytes": "empty"}, "from 0 bytes"),
       ("deeply-nested", {"bytes": "deep"}, "are not a serialised uiofmu state"),
       ("not-a-dict", {"bytes": "[1, 2]"}, "not a state made by a uiofmu pythonfmu FMU"),
       ("other-format", {"bytes": '{"format": "x"}'}, "not a state made by a uiofmu pythonfmu FMU"),
       ("guid", _field(["guid"], "0ddf672f-0000-5aca-8953-78866c76bb05"), "belongs to the FMU with GUID"),
       ("phase", _field(["phase"], "flying"), "state field 'phase' = 'flying'"),
       ("extra-envelope-field", _field(["spare"], 1), "state fields"),
       ("no-model", _field(["model"], delete=True), "state fields"),
       ("parameters-length", _field(["model", "parameters", 0], [1.0]),
        "'parameters.xhat0': expected a list of 2 numbers"),
       ("parameters-type", _field(["model", "parameters", 0, 0], "a"), "'parameters.xhat0'[0]: expected a number")]

OBSERVER_FIELDS = [
    ("k-negative", _field(["model", "runtime", "k"], -1), "'k' = -1: expected an integer"),
    ("k-float", _field(["model", "runtime", "k"], 2.5), "'k' = 2.5: expected an integer"),
    ("k-bool", _field(["model", "runtime", "k"], True), "'k' = True: expected an integer"),
    ("k-huge", _field(["model", "runtime", "k"], 10 ** 400), "expected an integer 0 <= k <= 2**53"),
    ("z-nan", _field(["model", "runtime", "z", 1], float("nan")), "'z'[1] = nan is not finite"),
    ("z-length", _field(["model", "runtime", "z"], [0.0]), "'z': expected a list of 2 numbers, found 1 values"),
    ("pred-string", _field(["model", "runtime", "pred"], "0"), "'pred': expected a list of 1 numbers, found str"),
    ("xhat0-inf", _field(["model", "runtime", "xhat0", 0], float("inf")), "'xhat0'[0] = inf is not finite"),
    ("h_prev-not-an-interval", _field(["model", "runtime", "h_prev"], 900.0),
     "'h_prev': step h = 900.0 s is not one of the design intervals"),
    ("h_prev-zero", _field(["model", "runtime", "h_prev"], 0.0), "'h_prev' = 0.0: expected a finite number > 0"),
    ("h_prev0-not-an-interval", _field(["model", "runtime", "h_prev0"], 650.0), "'h_prev0': step h = 650.0 s"),
    ("y-list-of-lists", _field(["model", "runtime", "y"], [[1.0]]), "'y'[0]: expected a number, found list"),
    ("u-missing", _field(["model", "runtime", "u"], delete=True), "missing fields ['u']"),
    ("runtime-extra", _field(["model", "runtime", "w"], 1), "unknown fields ['w']"),
]

PLANT_FIELDS = [
    ("x-nan", _field(["model", "runtime", "x", 0], float("nan")), "plant state field 'x'[0] = nan is not finite"),
    ("x0-length", _field(["model", "runtime", "x0"], [1.0, 2.0, 3.0]), "'x0': expected a list of 2 numbers"),
    ("params", _field(["model", "runtime", "params"], [1.0]), "'params': expected a list of 0 numbers"),
    ("d-string", _field(["model", "runtime", "d", 0], "1"), "'d'[0]: expected a number, found str"),
]

MUJOCO_FIELDS = [
    ("time-negative", _field(["model", "runtime", "time"], -1.0), "'time' = -1.0: expected a finite number >= 0"),
    ("time-nan", _field(["model", "runtime", "time"], float("nan")), "'time' = nan"),
    ("qpos-nan", _field(["model", "runtime", "qpos", 0], float("nan")), "'qpos'[0] = nan is not finite"),
    ("qvel-length", _field(["model", "runtime", "qvel"], [0.0]), "'qvel': expected a list of 2 numbers"),
    ("ctrl-bool", _field(["model", "runtime", "ctrl", 0], False), "'ctrl'[0]: expected a number, found bool"),
    ("params-length", _field(["model", "runtime", "params"], [1.0]), "'params': expected a list of 6 numbers"),
    ("params-inf", _field(["model", "runtime", "params", 2], float("inf")), "'params'[2] = inf is not finite"),
    ("act-length", _field(["model", "runtime", "act"], [0.0]), "'act': expected a list of 0 numbers"),
]


@pytest.mark.parametrize("which,hs,fields", [("obs", BUILDING_STEPS, OBSERVER_FIELDS),
                                             ("plant", BUILDING_STEPS, PLANT_FIELDS),
                                             pytest.param("mj", CAR_STEPS, MUJOCO_FIELDS, marks=pytest.mark.mujoco)])
def test_bad_states_are_refused_field_by_field(fmus, tmp_path, which, hs, fields):
    cases = [c for c in RAW if which == "obs" or not c[0].startswith("parameters")] + fields
    res = run_child(tmp_path, "states", {"path": fmus[which], "hs": hs, "tampers": [[c[0], c[1]] for c in cases]})
    assert set(res["good"]) == {"format", "guid", "phase", "model"}
    for label, _, fragment in cases:
        case = res["cases"][label]
        assert case["deserialize"] in NOT_FATAL and case["set"] == 3, (label, case)   # refused by fmi2SetFMUstate
        assert any("fmi2SetFMUstate" in m and fragment in m and "nothing changed" in m for m in case["log"]), \
            (label, case["log"])
        assert case["unchanged"], label
    assert res["same_afterwards"] and res["own_state_restores"]


@pytest.mark.parametrize("other,hs_other", [("obs_nearest", BUILDING_STEPS), ("plant", BUILDING_STEPS)])
def test_states_of_another_fmu_are_refused(fmus, tmp_path, other, hs_other):
    """A state (pointer or bytes) of another uiofmu FMU: the observer with another step policy
    (same ports) or the building's plant (before: SIGSEGV at the next call)."""
    res = run_child(tmp_path, "foreign", {"path": fmus["obs"], "other": fmus[other], "hs": BUILDING_STEPS,
                                          "hs_other": hs_other})
    expected = {"pointer": "is not a live state of this FMU",      # the guard knows the states it handed out
                "bytes": "belongs to the FMU with GUID"}             # the slave reads the GUID inside them
    for key in ("pointer", "bytes"):
        status, log = res[key]
        assert status == 3
        assert any(expected[key] in m and "nothing changed" in m for m in log), log
        assert res[f"{key}_unchanged"]
    assert res["same_afterwards"] and res["own_state_restores"]


def test_resources_that_are_not_the_fmus_own_are_refused_at_instantiation(fmus, tmp_path):
    res = run_child(tmp_path, "instantiate", {"path": fmus["obs"], "work": str(tmp_path)})
    assert res["intact"] == "instantiated"
    for key in ("other_model_json", "edited_guid"):
        assert "fmi2Instantiate failed" in res[key] and "instantiation refused" in res[key], res[key]
    assert "12345678-1234-5678-1234-567812345678" in res["edited_guid"]
    # a card edited with modelDescription.xml's GUID made to match: the native guard was compiled with the
    # GUID of the card build re-checked, and refuses the one the importer now passes
    assert "is not this FMU's" in res["model_and_guid"] and "instantiation refused" in res["model_and_guid"]
    assert res["bogus_guid_instantiated"] is False      # refused by the guard, which knows the FMU's GUID


def test_the_guid_is_a_digest_of_the_model(fmus, building_card, tmp_path):
    from fmpy import read_model_description

    again = build_observer(building_card[0], tmp_path / "again.fmu", backend="python")
    guids = {k: read_model_description(fmus[k]).guid for k in ("obs", "obs_nearest", "plant")}
    assert read_model_description(str(again)).guid == guids["obs"]
    assert len(set(guids.values())) == 3


def test_a_resource_location_without_the_slave_is_refused(fmus, tmp_path):
    """pythonfmu 0.7.0's binary alone crashes here (its PySlaveInstance calls a null class when the
    location holds no ``slavemodule.txt``); the guard refuses the location with a log line."""
    proc = run_child(tmp_path, "empty_resources", {"path": fmus["plant"]}, allow_crash=True)
    assert proc.returncode == 0, (proc.returncode, proc.stdout[-500:], proc.stderr[-500:])
    result = json.loads(proc.stdout.split("RESULT ", 1)[1])
    assert result == {"component": False, "lines": 1}


# -- the runtimes' set_state, in process ---------------------------------------------------

def _refuses(obj, state, fragment):
    before = json.dumps(obj.get_state())
    with pytest.raises(ValueError, match=fragment):
        obj.set_state(state)
    assert json.dumps(obj.get_state()) == before            # nothing changed


def _with(state, key, value):
    return {**state, key: value}


def test_observer_runtime_set_state_checks_every_field(building_card):
    card, _ = building_card
    rt = Runtime(card)
    for k, h in enumerate(BUILDING_STEPS):
        rt.set_y([20.0 + k])
        rt.set_u([1.0])
        rt.step(h)
    good = rt.get_state()
    for key, value, fragment in [("k", -1, "'k' = -1"), ("k", 1.0, "'k' = 1.0"), ("z", [1.0, "x"], r"'z'\[1\]"),
                                 ("pred", [math.inf], "'pred'.0. = inf is not finite"),
                                 ("h_prev", 601.0, "'h_prev': step h = 601.0 s is not one of"),
                                 ("h_prev0", -600.0, "'h_prev0' = -600.0"), ("xhat0", None, "'xhat0'"),
                                 ("u", [1.0, 2.0], "'u': expected a list of 1 numbers, found 2 values")]:
        _refuses(rt, _with(good, key, value), fragment)
    _refuses(rt, {k: v for k, v in good.items() if k != "z"}, r"missing fields \['z'\]")
    _refuses(rt, [good], "expected a dict, found list")
    rt.set_state(_with(good, "y", [math.nan]))                  # an input may hold NaN (the step refuses it)
    rt.set_state(json.loads(json.dumps(good)))                  # the JSON round trip is exact
    assert rt.get_state() == good


def test_a_nearest_policy_accepts_any_positive_previous_step(building_card):
    data = json.loads(building_card[0].to_json())
    data["schedule"]["step_policy"] = "nearest"
    rt = Runtime(card_from_data(data))
    rt.set_y([21.0])
    rt.step(900.0)                                              # not a design interval: used as the nearest
    state = rt.get_state()
    assert state["h_prev"] == 900.0
    rt.set_state(state)
    _refuses(rt, _with(state, "h_prev", math.inf), "'h_prev' = inf")


def test_observer_model_initialisation_and_state_are_all_or_nothing(building_card):
    model = ObserverModel(building_card[0])
    model.parameters[1].values[0] = 650.0                       # h_prev0 that is not an interval
    h_prev0 = model.rt.h_prev0
    with pytest.raises(StepRejected):
        model.initialize()
    assert model.rt.h_prev0 == h_prev0
    good = model.get_state()
    with pytest.raises(StateRejected, match="'parameters.h_prev0': expected a list of 1 numbers, found 2 values"):
        model.set_state({**good, "parameters": [[0.0, 0.0], [1.0, 2.0]]})
    with pytest.raises(StateRejected, match=r"unknown fields \['extra'\]"):
        model.set_state({**good, "extra": 1})
    model.set_state(good)
    assert model.get_state() == good


def test_plant_runtime_set_state_checks_every_field():
    rt = PlantRuntime({"time": "continuous", "A": [[0.0, 1.0], [-1.0, -0.1]], "E": [[0.0], [1.0]],
                       "C": [[1.0, 0.0]], "x0": [1.0, 0.0]})
    rt.d[:] = [0.5]
    rt.step(0.3)
    good = rt.get_state()
    for key, value, fragment in [("x", [1.0, math.nan], r"'x'\[1\] = nan"), ("x0", [1.0], "'x0': expected"),
                                 ("params", [0.0], "'params'"), ("u", [1.0], "'u': expected a list of 0"),
                                 ("d", [True], r"'d'\[0\]: expected a number, found bool")]:
        _refuses(rt, _with(good, key, value), fragment)
    rt.set_state(json.loads(json.dumps(good)))
    assert rt.get_state() == good


@pytest.mark.mujoco
def test_mujoco_runtime_set_state_checks_every_field():
    spec = load_spec(QUARTER_CAR)
    rt = MujocoRuntime(spec.mujoco, QUARTER_CAR)
    rt.u[:], rt.d[:] = [100.0], [-50.0]
    for _ in range(3):
        rt.step(0.01)
    good = rt.get_state()
    y = rt.y().copy()
    for key, value, fragment in [("time", -0.5, "'time' = -0.5"), ("time", "0", "'time' = '0'"),
                                 ("qpos", [0.0], "'qpos': expected a list of 2"),
                                 ("qvel", [0.0, math.nan], r"'qvel'\[1\] = nan"),
                                 ("params", good["params"][:-1], "'params': expected a list of 6"),
                                 ("x0", None, "'x0': expected a list of 4 numbers, found NoneType")]:
        _refuses(rt, _with(good, key, value), fragment)
    ref = MujocoRuntime(spec.mujoco, QUARTER_CAR)
    ref.set_state(json.loads(json.dumps(good)))                 # exact: the next steps agree bit for bit
    assert np.array_equal(ref.y(), y)
    for r in (rt, ref):
        r.step(0.02)
    assert np.array_equal(rt.x, ref.x)
