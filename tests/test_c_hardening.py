"""The C observer FMU refuses foreign and forged states and never reads out of bounds.

(a) The call-sequence fuzzer (tests/c/fmu_fuzz.c, built with the FMU's own sources under
ASan and UBSan by tests/cfuzz.py) with the other step policies ('nearest', 'count'), and a
check that it catches a runtime whose state checks are switched off (its short run on each
schedule kind, and valid round trips: tests/test_conformance.py). (b) Through fmpy: a state
of another FMU with equal dims, bytes with h_prev = 123 or NaN, truncated and extended bytes
are refused with fmi2Error and a log line saying why, and the instance steps on exactly as an
untouched twin. (c) A state taken in initialisation mode round-trips.
"""

from __future__ import annotations

import copy
import math
import struct
import zipfile
from ctypes import byref
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description

from uiofmu.runtime.card import card_from_data
from uiofmu.fmu.export import build_observer
from uiofmu.runtime.errors import FmuError
from uiofmu.cosim.fmi import Fmu, FmuCallError

import cfuzz

SANITIZER = ("AddressSanitizer", "LeakSanitizer", "runtime error:")


@pytest.fixture(scope="module")
def cards(example1_card, building_card, ltv_card):
    return {"lti-uio": example1_card[0], "ltv-auid": ltv_card[0], "sampled-data": building_card[0]}


@pytest.fixture(scope="module")
def fmus(observer_fmus):
    """The C FMU of each family, built once per session."""
    names = {"lti-uio": "example1_card", "ltv-auid": "ltv_card", "sampled-data": "building_card"}
    return {family: observer_fmus(name, "c")[1] for family, name in names.items()}


def _no_sanitizer_report(res):
    text = res.stdout + res.stderr
    assert not any(mark in text for mark in SANITIZER), text[-3000:]


# -- (a) the fuzzer --------------------------------------------------------------------------

@pytest.mark.parametrize("family", sorted(cfuzz.VARIANTS))
def test_fuzzer_scenarios_with_the_other_step_policies(cards, tmp_path, family):
    """'nearest' (interval schedule: any h_prev resolves, a notice may be recorded) and 'count'
    (geometric: any positive step)."""
    base, policy = cfuzz.VARIANTS[family]
    target = cfuzz.prepare(family, cfuzz.with_step_policy(cards[base], policy), tmp_path)
    res = cfuzz.run_scenarios(target)
    _no_sanitizer_report(res)
    assert res.returncode == 0 and res.failures == [], res.stderr[-3000:]
    assert set(res.scenarios.values()) == {"ok"}
    res = cfuzz.run_random(target, seconds=1.0, seed=5)
    _no_sanitizer_report(res)
    assert res.returncode == 0 and res.failures == [] and res.sequences > 30, res.stderr[-3000:]


def test_fuzzer_catches_a_runtime_without_state_checks(fmus, tmp_path):
    """The same scenarios against the interval runtime with check_values switched off: the
    forged states are accepted (failed checks, exit 1), and the runtime's own index checks
    still keep every access in bounds (no sanitizer report)."""
    with zipfile.ZipFile(fmus["sampled-data"]) as z:
        z.extractall(tmp_path, [n for n in z.namelist() if n.startswith("sources/")])
    src = tmp_path / "sources"
    text = (src / "kernel_affine.c").read_text()
    head = "static int check_values(Instance *s, const char *ctx, const Byte *v) {\n"
    assert text.count(head) == 1
    (src / "kernel_affine.c").write_text(text.replace(head, head + "    (void)s; (void)ctx; (void)v;\n    return 1;\n"))
    target = cfuzz.Target("unchecked", tmp_path / "fuzz", src, cfuzz.compile_fuzzer(src, tmp_path / "fuzz"))
    res = cfuzz.run(target, "scenarios", "--scenario", "h_prev")
    assert res.returncode == 1 and res.scenarios == {"h_prev": "FAIL"}
    assert any("fmi2DeSerializeFMUstate of h_prev = 123: fmi2ok, expected fmi2error" in f for f in res.failures)
    assert any("no matrix" in f or "not a design interval" in f for f in res.failures), res.failures
    _no_sanitizer_report(res)


# -- (b) foreign and forged states through fmpy ----------------------------------------------

def _drive(fmu, rng_seed, steps, h_choices):
    """Steps with inputs from a seeded generator; the outputs before each step."""
    rng = np.random.default_rng(rng_seed)
    out = []
    for _ in range(steps):
        fmu.set("y", rng.normal(size=len(fmu.refs("y"))))
        fmu.set("u", rng.normal(size=len(fmu.refs("u"))))
        out.append(np.concatenate([fmu.get("xhat"), fmu.get("r"), fmu.get("dhat")]))
        fmu.step(0.0, float(h_choices[int(rng.integers(len(h_choices)))]))
    return np.array(out)


def _steps(card):
    sched = card.schedule
    return sched["intervals"] if sched["kind"] == "interval" else [sched["dt"]]


def _layout(blob):
    """(GUID, offset of the doubles) of a layout-2 state."""
    magic, layout, size, glen = struct.unpack_from("<IIQI", blob, 0)
    assert (magic, layout, size) == (0x75696F66, 2, len(blob))
    return blob[40:40 + glen].decode(), 40 + (glen + 7) // 8 * 8


def _with_double(blob, index, value):
    _, data = _layout(blob)
    b = bytearray(blob)
    struct.pack_into("<d", b, data + 8 * index, value)
    return bytes(b)


@pytest.fixture(scope="module")
def twin_fmus(cards, observer_fmus, tmp_path_factory):
    """The building's FMU and one of a card that differs only in initial.xhat0 (equal dims,
    another GUID)."""
    d = tmp_path_factory.mktemp("twins")
    card = cards["sampled-data"]
    data = copy.deepcopy(card.data)
    data["initial"]["xhat0"] = [v + 1.0 for v in data["initial"]["xhat0"]]
    other = card_from_data(data)
    assert other.dims == card.dims
    _, a = observer_fmus("building_card", "c")
    b = build_observer(other, d / "b.fmu", backend="c")
    guids = (read_model_description(str(a)).guid, read_model_description(str(b)).guid)
    assert guids[0] != guids[1]
    return card, a, b, guids


def test_a_state_of_another_fmu_with_equal_dims_is_refused(twin_fmus):
    card, path_a, path_b, (guid_a, guid_b) = twin_fmus
    H = _steps(card)
    with Fmu(path_a, "a") as a, Fmu(path_b, "b") as b, Fmu(path_b, "b2") as b2:
        for f in (a, b, b2):
            f.initialize(0.0)
        _drive(a, 1, 6, H)
        _drive(b, 2, 6, H)
        _drive(b2, 2, 6, H)
        state_a = a.get_state()
        blob_a = a.serialize(state_a)
        assert _layout(blob_a)[0] == guid_a

        with pytest.raises(FmuCallError) as info:               # in memory
            b.set_state(state_a)
        assert info.value.status == 3
        assert any("GUID" in m and guid_a in m and guid_b in m for m in info.value.messages), info.value.messages

        with pytest.raises(FmuCallError) as info:               # as bytes
            b.deserialize(blob_a)
        assert info.value.status == 3
        assert any("belongs to the FMU with GUID " + guid_a in m for m in info.value.messages), info.value.messages

        with pytest.raises(FmuCallError) as info:               # reused by fmi2GetFMUstate
            b._call("fmi2GetFMUstate", b.slave.component, byref(state_a))
        assert info.value.status == 3 and any("cannot reuse" in m for m in info.value.messages)

        with pytest.raises(FmuCallError) as info:               # reused by fmi2DeSerializeFMUstate
            b._call("deSerializeFMUstate", b.serialize(b.get_state()), state_a)
        assert info.value.status == 3 and any("cannot reuse" in m for m in info.value.messages)
        with pytest.raises(FmuCallError) as info:               # nor freed by another FMU
            b._call("freeFMUstate", state_a)
        assert any("not freed" in m for m in info.value.messages)
        a.slave.freeFMUstate(state_a)

        after_refusals = _drive(b, 3, 12, H)
        untouched = _drive(b2, 3, 12, H)
        assert after_refusals.tobytes() == untouched.tobytes()


@pytest.mark.parametrize("value,fragment", [
    (123.0, "h_prev = 123.0 s is not a design interval"),
    (math.nan, "h_prev = nan is not a step"),
    (-600.0, "h_prev = -600.0 is not a step"),
])
def test_bytes_with_a_bad_h_prev_are_refused(twin_fmus, value, fragment):
    card, path, _, _ = twin_fmus
    H = _steps(card)
    with Fmu(path, "o") as fmu, Fmu(path, "twin") as twin:
        fmu.initialize(0.0)
        twin.initialize(0.0)
        _drive(fmu, 5, 7, H)
        _drive(twin, 5, 7, H)
        blob = fmu.serialize(fmu.get_state())
        with pytest.raises(FmuCallError) as info:
            fmu.deserialize(_with_double(blob, 1, value))        # doubles: k, h_prev, h_prev0, ...
        assert info.value.status == 3
        assert any(fragment in m for m in info.value.messages), info.value.messages
        assert _drive(fmu, 6, 10, H).tobytes() == _drive(twin, 6, 10, H).tobytes()


@pytest.mark.parametrize("index,value,fragment", [
    (0, -1.0, "k = -1.0 is not a step count"),
    (0, 0.5, "k = 0.5 is not a step count"),
    (0, 1e300, "is not a step count"),
    (2, 123.0, "h_prev0 = 123.0 s is not a design interval"),
    (3, 2.0, "noticed = 2.0 is neither 0 nor 1"),
    (4, 7.0, "phase = 7.0 is none of"),
    (5, math.inf, "z[1] = inf is not finite"),
    (7, math.nan, "pred[1] = nan is not finite"),
    (8, math.nan, "xhat0[1] = nan is not finite"),
])
def test_bytes_with_other_bad_fields_are_refused(twin_fmus, index, value, fragment):
    card, path, _, _ = twin_fmus
    with Fmu(path, "o") as fmu:
        fmu.initialize(0.0)
        _drive(fmu, 5, 4, _steps(card))
        blob = fmu.serialize(fmu.get_state())
        with pytest.raises(FmuCallError) as info:
            fmu.deserialize(_with_double(blob, index, value))
        assert info.value.status == 3 and any(fragment in m for m in info.value.messages), info.value.messages


@pytest.mark.parametrize("edit", ["cut 1", "cut 8", "header only", "plus 1", "plus 8"])
def test_truncated_or_extended_bytes_are_refused(twin_fmus, edit):
    card, path, _, _ = twin_fmus
    H = _steps(card)
    with Fmu(path, "o") as fmu, Fmu(path, "twin") as twin:
        fmu.initialize(0.0)
        twin.initialize(0.0)
        _drive(fmu, 8, 5, H)
        _drive(twin, 8, 5, H)
        blob = fmu.serialize(fmu.get_state())
        bad = {"cut 1": blob[:-1], "cut 8": blob[:-8], "header only": blob[:40], "plus 1": blob + b"\0",
               "plus 8": blob + bytes(8)}[edit]
        with pytest.raises(FmuCallError) as info:
            fmu.deserialize(bad)
        assert info.value.status == 3
        assert any(f"the buffer holds {len(bad)} bytes, the state in it says {len(blob)} bytes" in m
                   for m in info.value.messages), info.value.messages
        assert _drive(fmu, 9, 10, H).tobytes() == _drive(twin, 9, 10, H).tobytes()


def test_a_state_that_bypasses_initialisation_checks_is_refused(twin_fmus):
    """A running state at k = 0 holding a NaN xhat0 (which fmi2ExitInitializationMode refuses),
    and one whose h_prev0 is not the h_prev the first step will use."""
    card, path, _, _ = twin_fmus
    with Fmu(path, "o") as fmu:
        fmu.initialize(0.0)
        blob = fmu.serialize(fmu.get_state())
        with pytest.raises(FmuCallError) as info:
            fmu.deserialize(_with_double(blob, 8, math.nan))
        assert any("xhat0[1] = nan is not finite" in m for m in info.value.messages)
        with pytest.raises(FmuCallError) as info:
            fmu.deserialize(_with_double(blob, 2, 1200.0))
        assert any("h_prev = 600.0 s at k = 0 differs from h_prev0 = 1200.0 s" in m for m in info.value.messages)
        fmu.step(0.0, 600.0)


# -- (c) a state taken in initialisation mode (valid round trips of running states: test_conformance.py) ---

def test_a_state_taken_in_initialisation_mode_round_trips(cards, fmus):
    """A pending h_prev0 (not yet checked) travels with the state and is checked where it is taken."""
    path = fmus["sampled-data"]
    with Fmu(path, "o") as fmu, Fmu(path, "o2") as other:
        for f in (fmu, other):
            f._call("setupExperiment", None, 0.0)
            f._call("enterInitializationMode")
        fmu.set("h_prev0", [1800.0])
        fmu.set("xhat0", [21.0, 18.0])
        blob = fmu.serialize(fmu.get_state())
        other.set_state(other.deserialize(blob))
        assert other.get("h_prev0").tolist() == [1800.0] and other.get("xhat0").tolist() == [21.0, 18.0]
        for f in (fmu, other):
            f._call("exitInitializationMode")
        H = _steps(cards["sampled-data"])
        assert _drive(fmu, 4, 10, H).tobytes() == _drive(other, 4, 10, H).tobytes()
        pending = _with_double(blob, 2, 123.0)                   # a pending h_prev0 of 123 s ...
        with Fmu(path, "o3") as third:
            third._call("setupExperiment", None, 0.0)
            third.set_state(third.deserialize(pending))          # ... is taken as a parameter value
            with pytest.raises(FmuCallError) as info:            # ... and refused where it is used
                third._call("exitInitializationMode")
            assert any("parameter h_prev0: step h = 123.0 s is not one of the design intervals" in m
                       for m in info.value.messages)


def test_the_sources_carry_the_length_of_every_array(fmus):
    with zipfile.ZipFile(fmus["sampled-data"]) as z:
        text = z.read("sources/design_data.c").decode()
    assert text.count("UIOFMU_LENGTH(m_") == 11 and "UIOFMU_LENGTH(intervals)" in text
    assert "UIOFMU_LENGTH(xhat0)" in text
    assert Path(cfuzz.FUZZER).is_file()


# -- the design data, checked at fmi2Instantiate ---------------------------------------------

DESIGN_EDITS = [
    (None, None),
    ("[M_N] = {144, 2, 2,", "[M_N] = {143, 2, 2,", "matrix N has 143 blocks, expected 144"),
    ("[M_Xz] = {12, 2, 2,", "[M_Xz] = {12, 3, 2,", "matrix Xz is 3 x 2, expected n x nz = 2 x 2"),
    ("static const double m_L[] = {0.0, ", "static const double m_L[] = {",
     "matrix L: 144 blocks of 2 x 1 need 288 numbers, its array holds 287"),
    ("[M_Dy] = {12, 1, 1, m_Dy, UIOFMU_LENGTH(m_Dy)}", "[M_Dy] = {0, 0, 0, 0, 0}",
     "matrix Dy has 0 blocks, expected 12"),
    (".nz = 2,", ".nz = 3,", "dims.nz = 3 differs from dims.n = 2"),
    (".n = 2,", ".n = 0,", "dims.n = 0 is out of range"),
    ("{600.0, 1200.0,", "{-600.0, 1200.0,", "interval 1 = -600 is not a positive finite step"),
    (".h_prev0 = 600.0,", ".h_prev0 = 650.0,", "h_prev0 = 650 is not one of the design intervals"),
    (".nintervals = 12,", ".nintervals = 13,", "13 intervals in an array of 12"),
    (".kind = UIOFMU_INTERVAL,", ".kind = 7,", "schedule kind 7 is unknown"),
    (".step_rtol = 1e-06,", ".step_rtol = -1.0,", "step_rtol >= 0"),
    ("static const double xhat0[] = {22.0, 17.5};", "static const double xhat0[] = {22.0, __builtin_inf()};",
     "xhat0[2] = inf is not finite"),
]


def test_instantiate_refuses_inconsistent_design_data(fmus, tmp_path):
    """design_data.c edited by hand (it is generated, but the runtime does not trust it): each
    inconsistency is refused by fmi2Instantiate with a log line, the untouched one runs."""
    import shutil
    import subprocess

    path = fmus["sampled-data"]
    ident = read_model_description(str(path)).coSimulation.modelIdentifier
    unzip = tmp_path / "unzip"
    with zipfile.ZipFile(path) as z:
        z.extractall(unzip)
    src = unzip / "sources"
    flags = ["-std=c99", "-O2", "-fPIC", "-fvisibility=hidden", "-Wall", "-Wextra", f"-I{src}"]  # compile_binary's
    objects = []
    for name in ("fmi2_plumbing.c", "kernel_util.c", "kernel_affine.c"):  # the FMU's sources but design_data.c
        objects.append(str(tmp_path / name.replace(".c", ".o")))
        proc = subprocess.run(["gcc", *flags, "-c", "-o", objects[-1], str(src / name)], capture_output=True, text=True)
        assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    original = (src / "design_data.c").read_text()
    for i, (old, *edit) in enumerate(DESIGN_EDITS):
        text = original if old is None else original.replace(old, edit[0])
        assert old is None or text != original, old
        (src / "design_data.c").write_text(text)
        lib = unzip / "binaries" / "linux64" / f"{ident}.so"
        proc = subprocess.run(["gcc", *flags, "-shared", "-o", str(lib), *objects,
                               str(src / "design_data.c"), "-lm"], capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr
        broken = tmp_path / f"edit{i}.fmu"
        shutil.make_archive(str(broken.with_suffix("")), "zip", unzip)
        broken.with_suffix(".zip").rename(broken)
        if old is None:
            with Fmu(broken, "o") as fmu:
                fmu.initialize(0.0)
                fmu.step(0.0, 600.0)
            continue
        with pytest.raises(FmuError) as info:
            Fmu(broken, "o")
        assert "the design data compiled into this FMU is inconsistent" in str(info.value)
        assert edit[1] in str(info.value), str(info.value)
