"""The native guard in front of pythonfmu's binary (``uiofmu/fmu/pythonfmu_guard.py``,
``uiofmu/fmu/c/pythonfmu_guard.c``).

Unguarded, pythonfmu 0.7.0's binary instantiates whatever GUID and type it is given, crashes on
resource locations it cannot read, and answers fmi2OK to every call uiofmu's slave refuses
(the refusal is only a log line of status fmi2Error). Guarded, those instantiations fail with a
log line, odd folder names work, refusals return fmi2Error, and valid runs are bit for bit
those of the unguarded FMU, in fmpy, libcosimpy and uiofmu's C host.

Calls that could crash run in a child process (a crash fails the test instead of pytest); the
child prints one ``RESULT`` line of JSON.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.validation import validate_fmu

import uiofmu
import uiofmu.fmu.pythonfmu_guard as pg
from uiofmu.runtime.errors import FmuError
from uiofmu.fmu.export import build_observer, build_plant
from uiofmu.fmu.c_backend import build_host, c_compiler, fmi_headers
from uiofmu.cosim.fmi import Fmu
from uiofmu.cosim.validate import validate


OBS = "two_room_building_observer"
PLANT = "two_room_building_plant"
#: fmi2Statuses.
OK, DISCARD, ERROR, FATAL = 0, 2, 3, 4

CHILD = r'''
"""python child.py JSON: instantiate an extracted FMU's binary through fmpy's bindings, run ops."""
import ctypes, json, os, sys
from ctypes import byref, c_char, c_size_t
from fmpy import calloc, free
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE, fmi2CallbackFunctions,
                       fmi2CallbackLoggerTYPE, fmi2FMUstate, fmi2Real, fmi2ValueReference)
from fmpy.logging import addLoggerProxy

a = json.loads(sys.argv[1])
lines = []
cb = fmi2CallbackFunctions()
cb.logger = fmi2CallbackLoggerTYPE(
    lambda env, name, status, cat, msg: lines.append([status, msg.decode("utf-8", "replace")]))
cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
addLoggerProxy(byref(cb))
s = FMU2Slave(guid="-", unzipDirectory=a["dir"], modelIdentifier=a["model"], instanceName="x")
refs = lambda vrs: (fmi2ValueReference * len(vrs))(*vrs)


def op(c, states, name, *args):
    if name == "setup": return s.fmi2SetupExperiment(c, 0, 0.0, 0.0, 0, 0.0), None
    if name == "enter": return s.fmi2EnterInitializationMode(c), None
    if name == "exit": return s.fmi2ExitInitializationMode(c), None
    if name == "reset": return s.fmi2Reset(c), None
    if name == "step": return s.fmi2DoStep(c, args[0], args[1], 1), None
    if name == "setReal":
        return s.fmi2SetReal(c, refs(args[0]), len(args[0]), (fmi2Real * len(args[1]))(*args[1])), None
    if name == "getReal":
        v = (fmi2Real * len(args[0]))()
        return s.fmi2GetReal(c, refs(args[0]), len(args[0]), v), [repr(x) for x in v]
    if name == "getState":
        states.setdefault(args[0], fmi2FMUstate())
        return s.fmi2GetFMUstate(c, byref(states[args[0]])), None
    if name == "setState": return s.fmi2SetFMUstate(c, states[args[0]]), None
    if name == "freeState": return s.fmi2FreeFMUstate(c, byref(states[args[0]])), None
    if name == "serialize":
        n = c_size_t()
        st = s.fmi2SerializedFMUstateSize(c, states[args[0]], byref(n))
        buf = (c_char * n.value)()
        return max(st, s.fmi2SerializeFMUstate(c, states[args[0]], buf, n.value)), bytes(buf).hex()
    if name == "deserialize":
        data = bytes.fromhex(args[1])
        states[args[0]] = fmi2FMUstate()
        return s.fmi2DeSerializeFMUstate(c, (c_char * len(data)).from_buffer_copy(data), len(data),
                                         byref(states[args[0]])), None
    if name == "alias":                      # the same state pointer under another name
        states[args[1]] = fmi2FMUstate(states[args[0]].value)
        return 0, None
    if name == "pointer":                    # a state pointer that is no state (None: NULL)
        states[args[0]] = fmi2FMUstate(args[1])
        return 0, None
    if name == "rename":
        os.rename(args[0], args[1])
        return 0, None
    raise SystemExit("unknown op " + name)


out = []
for run in a["runs"]:
    del lines[:]
    c = s.fmi2Instantiate(run.get("name", "x").encode(), run.get("type", 1), run["guid"].encode(),
                          run["resources"].encode(), byref(cb), 0, run.get("logging", True))
    result = {"instantiated": c is not None, "log": lines[:], "ops": []}
    states = {}
    for o in run.get("ops", []) if c else []:
        del lines[:]
        try:
            status, value = op(c, states, *o)
        except FMICallException as exc:
            status, value = exc.status, None
        result["ops"].append({"op": o[0], "status": status, "log": lines[:], "value": value})
    if c:
        s.fmi2FreeInstance(c)
    out.append(result)
finalize = getattr(s.dll, "finalizePythonInterpreter")
finalize.restype = None
finalize()
print("RESULT " + json.dumps(out))
'''

#: A stand-in for pythonfmu's binary, without Python: the guard's own memory use under valgrind.
STUB = r'''
#define _POSIX_C_SOURCE 200809L
#include <stdlib.h>
#include <string.h>
#include "fmi2Functions.h"
#define U(x) (void)(x)
typedef struct { const fmi2CallbackFunctions *f; char *name; double x[8]; } Stub;
typedef fmi2ValueReference VR;
typedef fmi2StatusKind Kind;
static void say(Stub *s, fmi2Status st, const char *text) {
    s->f->logger(s->f->componentEnvironment, s->name, st, "logAll", text);
}
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }
void finalizePythonInterpreter(void) {}
fmi2Component fmi2Instantiate(fmi2String n, fmi2Type t, fmi2String g, fmi2String r, const fmi2CallbackFunctions *f,
                              fmi2Boolean v, fmi2Boolean l) {
    Stub *s = calloc(1, sizeof *s);
    U(t); U(g); U(r); U(v); U(l);
    s->f = f;
    s->name = strdup(n);
    return s;
}
void fmi2FreeInstance(fmi2Component c) { Stub *s = c; free(s->name); free(s); }
fmi2Status fmi2SetReal(fmi2Component c, const VR vr[], size_t n, const fmi2Real v[]) {
    Stub *s = c;
    for (size_t i = 0; i < n; i++) {
        if (vr[i] > 7) { say(s, fmi2Error, "stub: 100% refused"); return fmi2OK; }
        s->x[vr[i]] = v[i];
    }
    return fmi2OK;
}
fmi2Status fmi2GetReal(fmi2Component c, const VR vr[], size_t n, fmi2Real v[]) {
    Stub *s = c;
    for (size_t i = 0; i < n; i++) v[i] = vr[i] < 8 ? s->x[vr[i]] : 0.0;
    return fmi2OK;
}
fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean b) {
    Stub *s = c;
    U(t); U(b);
    if (h == 900.0) say(s, fmi2Discard, "stub: step h = 900 refused");
    else s->x[5] += h * s->x[3];
    return fmi2OK;
}
fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean l, size_t n, const fmi2String k[]) {
    U(c); U(l); U(n); U(k); return fmi2OK;
}
fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean a, fmi2Real b, fmi2Real d, fmi2Boolean e, fmi2Real f) {
    U(c); U(a); U(b); U(d); U(e); U(f); return fmi2OK;
}
#define LIFE(name, status) fmi2Status name(fmi2Component c) { U(c); return status; }
LIFE(fmi2EnterInitializationMode, fmi2OK) LIFE(fmi2ExitInitializationMode, fmi2OK) LIFE(fmi2Terminate, fmi2OK)
LIFE(fmi2Reset, fmi2OK) LIFE(fmi2CancelStep, fmi2Error)
#define ARRAY(name, T) \
    fmi2Status name(fmi2Component c, const VR vr[], size_t n, T v[]) { U(c); U(vr); U(n); U(v); return fmi2Error; }
ARRAY(fmi2GetInteger, fmi2Integer) ARRAY(fmi2GetBoolean, fmi2Boolean) ARRAY(fmi2GetString, fmi2String)
ARRAY(fmi2SetInteger, const fmi2Integer) ARRAY(fmi2SetBoolean, const fmi2Boolean) ARRAY(fmi2SetString, const fmi2String)
#define KIND(name, T) fmi2Status name(fmi2Component c, const Kind k, T *v) { U(c); U(k); U(v); return fmi2Error; }
KIND(fmi2GetStatus, fmi2Status) KIND(fmi2GetRealStatus, fmi2Real) KIND(fmi2GetIntegerStatus, fmi2Integer)
KIND(fmi2GetBooleanStatus, fmi2Boolean) KIND(fmi2GetStringStatus, fmi2String)
fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s) { U(c); *s = malloc(8); return fmi2OK; }
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s) { U(c); U(s); return fmi2OK; }
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s) { U(c); free(*s); return fmi2OK; }
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *n) {
    U(c); U(s); *n = 1; return fmi2OK;
}
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n) {
    U(c); U(s); U(n); b[0] = 1; return fmi2OK;
}
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate *s) {
    U(c); U(b); U(n); *s = malloc(8); return fmi2OK;
}
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const VR a[], size_t b, const VR d[], size_t e,
                                        const fmi2Real f[], fmi2Real g[]) {
    U(c); U(a); U(b); U(d); U(e); U(f); U(g); return fmi2Error;
}
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const VR a[], size_t b, const fmi2Integer d[],
                                       const fmi2Real e[]) {
    U(c); U(a); U(b); U(d); U(e); return fmi2Error;
}
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const VR a[], size_t b, const fmi2Integer d[], fmi2Real e[]) {
    U(c); U(a); U(b); U(d); U(e); return fmi2Error;
}
'''


def _guid(path) -> str:
    return read_model_description(str(path)).guid


def _extract(fmu, where: Path) -> Path:
    with zipfile.ZipFile(fmu) as z:
        z.extractall(where)
    return where


@pytest.fixture(scope="module")
def fmus(building_card, building_path, tmp_path_factory):
    """The building observer and plant as pythonfmu built them ("raw") and guarded, extracted too."""
    d = tmp_path_factory.mktemp("guard")
    problem = uiofmu.load_problem(building_path)
    with pytest.MonkeyPatch.context() as mp:           # pythonfmu's FMU even where export.py guards it
        mp.setattr(pg, "available", lambda: False)
        raw = {"obs": build_observer(building_card[0], d / "obs_raw.fmu", backend="python"),
               "plant": build_plant(problem.plant, problem.name, d / "plant_raw.fmu", backend="python")}
    out = {"dir": d, "card": building_card[0]}
    for key, path in raw.items():
        guarded = shutil.copyfile(path, d / f"{key}_guarded.fmu")
        assert pg.guard_fmu(guarded) == guarded
        out[key] = {"raw": path, "guarded": guarded, "guid": _guid(path),
                    "raw_dir": _extract(path, d / f"{key}_raw"), "guarded_dir": _extract(guarded, d / f"{key}_guarded")}
    return out


def run_child(tmp_path, args, timeout=120):
    """Run CHILD with ``args``; returns (returncode, its results or None, stderr)."""
    script = tmp_path / "guard_child.py"
    script.write_text(CHILD)
    proc = subprocess.run([sys.executable, str(script), json.dumps(args)], capture_output=True, text=True,
                          timeout=timeout, cwd=tmp_path)
    lines = [line for line in proc.stdout.splitlines() if line.startswith("RESULT ")]
    return proc.returncode, (json.loads(lines[-1][len("RESULT "):]) if lines else None), proc.stderr[-3000:]


def _runs(fmus, key, kind, runs):
    """Child runs against the extracted ``kind`` ("raw" or "guarded") FMU ``key``; GUID and
    resources default to the right ones."""
    folder = fmus[key][f"{kind}_dir"]
    base = {"guid": fmus[key]["guid"], "resources": (folder / "resources").as_uri()}
    return {"dir": str(folder), "model": OBS if key == "obs" else PLANT, "runs": [{**base, **r} for r in runs]}


INIT = [["setup"], ["enter"], ["exit"]]


# -- the library and the rewriting --------------------------------------------------------

def test_the_guard_compiles_warning_free_and_exports_every_co_simulation_function(fmus, tmp_path):
    cc = c_compiler()
    proc = subprocess.run([cc, *pg.CFLAGS, "-Werror", "-pedantic", f"-I{fmi_headers()}",
                           f'-DGUARD_GUID="{fmus["obs"]["guid"]}"', f'-DGUARD_MODEL="{OBS}"', "-o",
                           str(tmp_path / "g.so"), str(pg.SOURCE), *pg.LIBS, "-Wl,--no-undefined"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    header = (fmi_headers() / "fmi2Functions.h").read_text()
    me_only = {"fmi2EnterEventMode", "fmi2NewDiscreteStates", "fmi2EnterContinuousTimeMode",
               "fmi2CompletedIntegratorStep", "fmi2SetTime", "fmi2SetContinuousStates", "fmi2GetDerivatives",
               "fmi2GetEventIndicators", "fmi2GetContinuousStates", "fmi2GetNominalsOfContinuousStates"}
    cs = set(re.findall(r"FMI2_Export\s+\w+TYPE\s+(fmi2\w+);", header)) - me_only
    assert len(cs) == 34

    def exported(so):
        nm = subprocess.run(["nm", "-D", "--defined-only", str(so)], capture_output=True, text=True, check=True)
        return {line.split()[-1] for line in nm.stdout.splitlines() if not line.split()[-1].startswith("_")}

    binaries = fmus["obs"]["guarded_dir"] / "binaries" / "linux64"
    mine, theirs = exported(binaries / f"{OBS}.so"), exported(binaries / f"{OBS}_pythonfmu.so")
    assert mine == cs | {"finalizePythonInterpreter"}
    assert {s for s in theirs if s.startswith("fmi2")} == cs and "finalizePythonInterpreter" in theirs
    raw = fmus["obs"]["raw_dir"] / "binaries" / "linux64" / f"{OBS}.so"
    assert (binaries / f"{OBS}_pythonfmu.so").read_bytes() == raw.read_bytes()


@pytest.mark.parametrize("guid", ['1393490c-36e6-5288-8e61-41d9f6cca525"); system("x', "not-a-guid", "",
                                  "{1393490c-36e6-5288-8e61-41d9f6cca525", "1393490c-36e6-5288-8e61-41d9f6cca525\n"])
def test_only_a_uuid_becomes_the_guards_guid(guid):
    with pytest.raises(FmuError, match="not a UUID"):
        pg.check_guid(guid)


def test_guard_fmu_refuses_what_it_cannot_guard_and_leaves_the_file_alone(fmus, tmp_path):
    raw = fmus["obs"]["raw"]
    with pytest.raises(FmuError, match="already guarded"):
        pg.guard_fmu(shutil.copyfile(fmus["obs"]["guarded"], tmp_path / "twice.fmu"))
    with pytest.raises(FmuError, match="has GUID"):
        pg.guard_fmu(shutil.copyfile(raw, tmp_path / "other.fmu"), "00000000-0000-0000-0000-000000000000")
    tampered = tmp_path / "tampered.fmu"
    with zipfile.ZipFile(raw) as z, zipfile.ZipFile(tampered, "w") as out:
        for info in z.infolist():
            data = z.read(info)
            if info.filename == "modelDescription.xml":
                data = re.sub(rb'guid="[^"]*"', b'guid="x\\&quot;); abort(); //"', data, count=1)
            out.writestr(info, data)
    before = tampered.read_bytes()
    with pytest.raises(FmuError, match="not a UUID"):
        pg.guard_fmu(tampered)
    assert tampered.read_bytes() == before
    assert pg.is_guarded(fmus["obs"]["guarded"]) and not pg.is_guarded(raw)
    assert validate_fmu(str(fmus["obs"]["guarded"])) == [] and validate_fmu(str(fmus["plant"]["guarded"])) == []


def test_export_guards_pythonfmu_fmus(fmus, tmp_path):
    assert pg.available()
    assert pg.is_guarded(build_observer(fmus["card"], tmp_path / "o.fmu", backend="python"))


# -- fmi2Instantiate ----------------------------------------------------------------------

def test_instantiate_refuses_a_wrong_guid_type_name_or_resource_location_with_a_log_line(fmus, tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    unslaved = tmp_path / "unslaved"
    shutil.copytree(fmus["obs"]["guarded_dir"] / "resources", unslaved)
    (unslaved / "slavemodule.txt").unlink()
    bad_utf8 = Path(os.fsdecode(bytes(tmp_path) + b"/bad\xffname"))
    shutil.copytree(fmus["obs"]["guarded_dir"] / "resources", bad_utf8)
    res = (fmus["obs"]["guarded_dir"] / "resources").as_uri()
    cases = {
        "wrong GUID": ({"guid": "00000000-0000-0000-0000-000000000000"}, "is not this FMU's"),
        "model exchange": ({"type": 0}, "Co-Simulation only"),
        "empty name": ({"name": ""}, "instance name is empty"),
        "empty folder": ({"resources": empty.as_uri()}, "holds no slavemodule.txt"),
        "no slavemodule.txt": ({"resources": unslaved.as_uri()}, "holds no slavemodule.txt"),
        "missing folder": ({"resources": (tmp_path / "nowhere").as_uri()}, "cannot be resolved"),
        "http": ({"resources": "http://example.com/resources"}, "is not a file URI"),
        "other host": ({"resources": "file://elsewhere" + res[len("file://"):]}, 'names the host "elsewhere"'),
        "relative": ({"resources": "file:resources"}, "has no absolute path"),
        "malformed escape": ({"resources": res + "%G0"}, "malformed percent-escape"),
        "NUL": ({"resources": res + "%00"}, "encodes a NUL byte"),
        "not UTF-8": ({"resources": "file://" + str(bad_utf8).replace("\udcff", "%FF")}, "is not UTF-8"),
    }
    rc, results, err = run_child(tmp_path, _runs(fmus, "obs", "guarded", [c for c, _ in cases.values()]))
    assert rc == 0 and results, err
    for (name, (_, fragment)), result in zip(cases.items(), results):
        assert not result["instantiated"], name
        assert len(result["log"]) == 1 and result["log"][0][0] == ERROR, (name, result["log"])
        assert fragment in result["log"][0][1] and "instantiation refused" in result["log"][0][1], (name, result["log"])
    # pythonfmu itself ignores the GUID and the type (the resource cases above crash it)
    raw_runs = [cases["wrong GUID"][0], cases["model exchange"][0]]
    rc, results, err = run_child(tmp_path, _runs(fmus, "obs", "raw", raw_runs))
    assert rc == 0 and [r["instantiated"] for r in results] == [True, True], err


def test_odd_folder_names_and_uri_forms_work(fmus, tmp_path):
    odd = tmp_path / "dir ä #1" / "fmu"
    shutil.copytree(fmus["obs"]["guarded_dir"], odd)
    ops = [*INIT, ["setReal", [3, 4], [21.5, 0.5]], ["step", 0.0, 600.0], ["getReal", [5, 6]]]
    plain = (fmus["obs"]["guarded_dir"] / "resources").as_uri()
    runs = [{"resources": plain, "ops": ops},
            {"resources": (odd / "resources").as_uri(), "ops": ops},                 # percent-escaped
            {"resources": "file://" + str(odd / "resources"), "ops": ops},           # not escaped at all
            {"resources": "file:" + str(odd / "resources") + "/", "ops": ops},       # one slash, trailing slash
            {"resources": "FILE://localhost" + str(odd / "resources"), "ops": ops}]
    args = _runs(fmus, "obs", "guarded", runs)
    args["dir"] = str(odd)
    rc, results, err = run_child(tmp_path, args)
    assert rc == 0 and results, err
    for result in results:
        assert result["instantiated"], result["log"]
        assert [o["status"] for o in result["ops"]] == [OK] * len(ops), result
    assert len({json.dumps(r["ops"][-1]["value"]) for r in results}) == 1


def test_a_log_line_with_a_percent_sign_arrives_unformatted(fmus, tmp_path):
    """The slave refuses resources beside another FMU's modelDescription.xml; its line names the
    folder, whose '%s %n' pythonfmu passes as a format: the guard forwards it as text."""
    odd = tmp_path / "p %s %n %d" / "fmu"
    shutil.copytree(fmus["obs"]["guarded_dir"], odd)
    md = odd / "modelDescription.xml"
    md.write_text(md.read_text().replace(fmus["obs"]["guid"], "00000000-0000-0000-0000-000000000000"))
    args = _runs(fmus, "obs", "guarded", [{"resources": (odd / "resources").as_uri()}])
    rc, results, err = run_child(tmp_path, args)
    assert rc == 0 and results, err
    assert not results[0]["instantiated"]
    assert any(f"{odd}/resources" in line and "IdentityError" in line for _, line in results[0]["log"]), results


# -- statuses of refused calls ------------------------------------------------------------

def test_refused_calls_return_error_with_the_slaves_line_and_the_instance_goes_on(fmus, tmp_path):
    foreign = json.dumps({"format": "uiofmu-pythonfmu-state/1", "guid": "00000000-0000-0000-0000-000000000000",
                          "phase": "running", "model": {}}).encode().hex()
    bad = {"unknown get": (["getReal", [999]], "value reference 999 is not a variable of this FMU"),
           "unknown set": (["setReal", [999], [1.0]], "value reference 999 is not a variable of this FMU"),
           "output set": (["setReal", [5], [1.0]], "is an output: fmi2SetReal on it is not allowed"),
           "garbled state": (["setState", "garbled"], "not a serialised uiofmu state"),
           "foreign state": (["setState", "foreign"], "belongs to the FMU with GUID"),
           "wrong step": (["step", 600.0, 900.0], "is not one of the design intervals")}
    good = [["setReal", [3, 4], [21.0, 1.0]], ["step", 0.0, 600.0], ["getReal", [5, 6]],
            ["setReal", [3, 4], [21.5, 0.0]], ["step", 600.0, 1200.0], ["getReal", [5, 6]]]
    prelude = [*INIT, ["deserialize", "garbled", "00ff17"], ["deserialize", "foreign", foreign]]
    mixed = prelude + [good[0], *[b for b, _ in bad.values()], *good[1:]]
    for kind, logging in (("guarded", True), ("guarded", False), ("raw", True)):
        rc, results, err = run_child(tmp_path, _runs(fmus, "obs", kind, [{"ops": prelude + good, "logging": logging},
                                                                          {"ops": mixed, "logging": logging}]))
        assert rc == 0 and results, err
        clean, refused = results
        assert [o["status"] for o in clean["ops"]] == [OK] * len(clean["ops"]), clean
        by_op = refused["ops"][len(prelude) + 1:len(prelude) + 1 + len(bad)]
        for (name, (_, fragment)), result in zip(bad.items(), by_op):
            expected = DISCARD if name == "wrong step" else (ERROR if kind == "guarded" else OK)
            assert result["status"] == expected, (kind, name, result)
            assert any(fragment in line for _, line in result["log"]), (kind, name, result)
        # nothing changed: the outputs after the refusals are those of the clean run, bit for bit
        assert [refused["ops"][i]["value"] for i in (-4, -1)] == [clean["ops"][i]["value"] for i in (-4, -1)]


def test_after_fmi2fatal_the_instance_refuses_every_call_instead_of_crashing(fmus, tmp_path):
    folder = tmp_path / "fatal"
    shutil.copytree(fmus["obs"]["guarded_dir"], folder)
    model = folder / "resources" / "model.json"
    args = _runs(fmus, "obs", "guarded", [{"resources": (folder / "resources").as_uri(), "ops": [
        *INIT, ["rename", str(model), str(model) + ".gone"], ["reset"], ["step", 0.0, 600.0], ["getReal", [5]]]}])
    args["dir"] = str(folder)
    rc, results, err = run_child(tmp_path, args)
    assert rc == 0 and results, err           # unguarded, the step after the fatal reset is a segfault
    ops = {o["op"]: o for o in results[0]["ops"]}
    assert ops["reset"]["status"] == FATAL and "FileNotFoundError" in ops["reset"]["log"][0][1]
    for name in ("step", "getReal"):
        assert ops[name]["status"] == ERROR and "returned fmi2Fatal before" in ops[name]["log"][0][1]


def test_only_live_states_of_this_fmu_reach_pythonfmu(fmus, tmp_path):
    ops = [*INIT, ["setReal", [3], [21.0]], ["getState", "a"], ["serialize", "a"], ["step", 0.0, 600.0],
           ["getReal", [5, 6]], ["setState", "a"], ["step", 0.0, 600.0], ["getReal", [5, 6]],
           ["alias", "a", "first"], ["getState", "a"],        # FMI 2.0: the state given is overwritten
           ["setState", "first"],
           ["alias", "a", "old"], ["freeState", "a"], ["setState", "old"], ["setState", "a"],
           ["pointer", "bogus", 4096], ["setState", "bogus"], ["freeState", "bogus"], ["step", 600.0, 600.0]]
    rc, results, err = run_child(tmp_path, _runs(fmus, "obs", "guarded", [{"ops": ops}]))
    assert rc == 0 and results, err          # unguarded, setState of a freed or NULL state is a segfault
    got = results[0]["ops"]
    refused = {13, 16, 17, 19, 20}
    assert [o["status"] for o in got] == [ERROR if i in refused else OK for i in range(len(ops))], got
    assert got[10]["value"] == got[7]["value"]                      # the restored state steps alike
    assert all("is not a live state of this FMU" in got[i]["log"][0][1] for i in refused)


# -- valid runs: bit for bit, in every importer --------------------------------------------

def _drive(path, rng_seed, steps=40):
    """Outputs, state bytes and the outputs after a state round trip of a random run via uiofmu.cosim.fmi."""
    rng = np.random.default_rng(rng_seed)
    out = []
    with Fmu(path, "bitwise") as fmu:
        fmu.initialize(0.0)
        plant = fmu.has("x")
        t = 0.0
        for k in range(steps):
            h = 600.0 * int(rng.integers(1, 4))
            fmu.set("u", rng.normal(size=len(fmu.refs("u"))))
            if plant:
                fmu.set("d", rng.normal(size=len(fmu.refs("d"))))
            else:
                fmu.set("y", 20 + rng.normal(size=len(fmu.refs("y"))))
            if k == steps // 2:
                state = fmu.get_state()
                data = fmu.serialize(state)
            fmu.step(t, h)
            t += h
            out.append(np.concatenate([fmu.get("x" if plant else "xhat"), fmu.get("y" if plant else "r")]))
        fmu.set_state(fmu.deserialize(data))
        fmu.step(0.0, 600.0)
        after = fmu.get("x" if plant else "xhat")
    return np.array(out), data, after


@pytest.mark.parametrize("key", ["obs", "plant"])
def test_valid_runs_equal_the_unguarded_fmu_bit_for_bit(fmus, key):
    raw, guarded = _drive(fmus[key]["raw"], 5), _drive(fmus[key]["guarded"], 5)
    assert np.array_equal(raw[0], guarded[0]) and raw[1] == guarded[1] and np.array_equal(raw[2], guarded[2])
    report = validate(fmus[key]["guarded"], steps=40, seed=3)
    assert report.ok, report.problems


COSIM = r'''
import json, sys
from libcosimpy.CosimExecution import CosimExecution
from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
from libcosimpy.CosimObserver import CosimObserver
from libcosimpy.CosimSlave import CosimLocalSlave
log_output_level(CosimLogLevel.ERROR)
a = json.loads(sys.argv[1])
ex = CosimExecution.from_step_size(step_size=600 * 10**9)
obs = ex.add_local_slave(local_slave=CosimLocalSlave(fmu_path=a["obs"], instance_name="observer"))
plant = ex.add_local_slave(local_slave=CosimLocalSlave(fmu_path=a["plant"], instance_name="plant"))
last = CosimObserver.create_last_value()
ex.add_observer(observer=last)
ex.connect_real_variables(plant, a["plant_y"], obs, a["obs_y"])
for index, ref in ((plant, a["plant_u"]), (obs, a["obs_u"])):
    ex.real_initial_value(slave_index=index, variable_reference=ref, value=1.0)
ok = ex.step(step_count=30)
print("RESULT " + json.dumps({"ok": ok,
      "xhat": last.last_real_values(slave_index=obs, variable_references=a["obs_xhat"]),
      "x": last.last_real_values(slave_index=plant, variable_references=a["plant_x"])}))
'''


def test_libcosimpy_runs_the_guarded_fmus_as_the_unguarded_ones(fmus, tmp_path):
    script = tmp_path / "cosim_child.py"
    script.write_text(COSIM)
    refs = {k: {v.name: v.valueReference for v in read_model_description(str(fmus[k]["raw"])).modelVariables}
            for k in ("obs", "plant")}
    results = []
    for kind in ("raw", "guarded"):
        args = {"obs": str(fmus["obs"][kind]), "plant": str(fmus["plant"][kind]), "plant_y": refs["plant"]["y[1]"],
                "obs_y": refs["obs"]["y[1]"], "plant_u": refs["plant"]["u[1]"], "obs_u": refs["obs"]["u[1]"],
                "obs_xhat": [refs["obs"]["xhat[1]"], refs["obs"]["xhat[2]"]],
                "plant_x": [refs["plant"]["x[1]"], refs["plant"]["x[2]"]]}
        proc = subprocess.run([sys.executable, str(script), json.dumps(args)], capture_output=True, text=True,
                              timeout=120)
        line = [x for x in proc.stdout.splitlines() if x.startswith("RESULT ")]
        assert proc.returncode == 0 and line, proc.stderr[-2000:]
        results.append(json.loads(line[0][len("RESULT "):]))
    assert results[0] == results[1] and results[1]["ok"]


def _libpython() -> Path | None:
    name = sysconfig.get_config_var("INSTSONAME") or ""
    for folder in (sysconfig.get_config_var("LIBDIR"), "/usr/lib/x86_64-linux-gnu"):
        if folder and name and (Path(folder) / name).is_file():
            return Path(folder) / name
    return None


def _host(fmus, kind, tmp_path, rows, wrapper=(), folder=None):
    """Run uiofmu's C host on the extracted observer ``kind`` (Python preloaded when pythonfmu's)."""
    folder = folder or fmus["obs"][f"{kind}_dir"]
    steps = tmp_path / "steps.txt"
    steps.write_text("".join(" ".join(map(repr, row)) + "\n" for row in rows))
    env = dict(os.environ)
    if kind != "stub":
        libpython = _libpython()
        assert libpython is not None, "the host needs a shared libpython to preload for pythonfmu FMUs"
        env["LD_PRELOAD"] = str(libpython)
        env["PYTHONPATH"] = os.pathsep.join(sysconfig.get_paths()[k] for k in ("purelib", "platlib"))
    model = OBS if kind != "stub" else "stub_model"
    guid = fmus["obs"]["guid"]
    host = tmp_path / "host" / "fmu_host"
    if not host.is_file():
        build_host(host.parent)
    cmd = [*wrapper, str(host), str(folder / "binaries" / "linux64" / f"{model}.so"), guid,
           (folder / "resources").as_uri(), "3,4", "5,6", str(steps)]
    return subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300)


def test_the_c_host_runs_the_guarded_fmu_as_the_unguarded_one(fmus, tmp_path):
    rng = np.random.default_rng(8)
    rows = [[600.0 * int(rng.integers(1, 4)), 20 + rng.normal(), rng.normal()] for _ in range(30)]
    raw, guarded = _host(fmus, "raw", tmp_path, rows), _host(fmus, "guarded", tmp_path, rows)
    assert raw.returncode == 0 and guarded.returncode == 0, guarded.stderr
    assert guarded.stdout == raw.stdout and len(guarded.stdout.splitlines()) == 30
    # the host instantiates with logging off: pythonfmu then drops every line; the guard passes
    # on those that are not fmi2OK (and the step's fmi2Discard)
    rows[10][0] = 900.0
    raw, guarded = _host(fmus, "raw", tmp_path, rows), _host(fmus, "guarded", tmp_path, rows)
    assert raw.returncode == guarded.returncode == 2
    assert "fmi2DoStep returned 2 at row 10" in guarded.stderr and "fmi2DoStep returned 2 at row 10" in raw.stderr
    assert "is not one of the design intervals" in guarded.stderr
    assert "is not one of the design intervals" not in raw.stderr


VALGRIND = ("valgrind", "--error-exitcode=3", "--leak-check=full", "--errors-for-leak-kinds=definite", "--quiet")


@pytest.mark.valgrind
def test_the_guard_under_valgrind_in_the_c_host(fmus, tmp_path):
    """The guard in front of a stand-in for pythonfmu's binary (no Python: valgrind would spend half
    a minute on the interpreter and numpy; set UIOFMU_VALGRIND_PYTHON=1 for that run too)."""
    folder = tmp_path / "stub"
    (folder / "binaries" / "linux64").mkdir(parents=True)
    (folder / "resources").mkdir()
    (folder / "resources" / "slavemodule.txt").write_text("stub\n")
    (tmp_path / "stub.c").write_text(STUB)
    pg.compile_guard(fmus["obs"]["guid"], "stub_model", folder / "binaries" / "linux64")
    subprocess.run([c_compiler(), "-std=c99", "-shared", "-fPIC", "-Wall", "-Wextra", "-Werror", f"-I{fmi_headers()}",
                    "-o", str(folder / "binaries" / "linux64" / "stub_model_pythonfmu.so"), str(tmp_path / "stub.c")],
                   check=True)
    rows = [[600.0, 1.0, 2.0]] * 5 + [[900.0, 1.0, 2.0]]
    proc = _host(fmus, "stub", tmp_path, rows, wrapper=VALGRIND, folder=folder)
    assert proc.returncode == 2, proc.stderr           # the host's status for the refused step (3: valgrind)
    assert "stub: step h = 900 refused" in proc.stderr and "fmi2DoStep returned 2 at row 5" in proc.stderr
    assert "definitely lost" not in proc.stderr and "Invalid" not in proc.stderr
    if os.environ.get("UIOFMU_VALGRIND_PYTHON") == "1":
        supp = tmp_path / "ld.supp"          # the dynamic loader's own strncmp over-reads (numpy's rpaths)
        supp.write_text("{\n   ld-rpath\n   Memcheck:Addr8\n   fun:strncmp\n   fun:is_dst\n}\n")
        proc = _host(fmus, "guarded", tmp_path, [[600.0, 21.0, 1.0]] * 3, wrapper=(*VALGRIND, f"--suppressions={supp}"))
        assert proc.returncode == 0, proc.stderr[-3000:]
