"""What the tests of the C FMUs of one family share (test_c_switched.py, test_c_functional.py).

- :func:`sanitized_observer`, :func:`sanitized_plant`: a C FMU whose own sources are compiled
  under ASan and UBSan (:data:`cfuzz.SANITIZER_FLAGS`, the flags of the fuzzer and of plant_test.c);
- :func:`run_sanitized`: a test file's checks on such an FMU, in a Python with the sanitizer
  runtimes preloaded (the test file runs as a script: :func:`script_main`), with no report;
  :func:`check_sanitized` for the observers of some cards and some plants;
- :func:`refused`, :func:`discarded`: a call that returns fmi2Error (fmi2Discard) with a log line;
- :func:`run_plant`: a plant FMU's run against its reference runtime;
- :func:`check_restores`: a saved FMU state restores the same run, in the instance and in another;
- :func:`refused_edits`: hand edits of an FMU's design_data.c, each refused by fmi2Instantiate;
- :func:`random_calls`: random FMI call sequences through fmpy, never answered with fmi2Fatal.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

import cfuzz
from uiofmu.cosim.fmi import Fmu, FmuCallError
from uiofmu.fmu import c_backend

HERE = Path(__file__).resolve().parent
#: The fmpy statuses of fmi2Discard and fmi2Error.
DISCARD, ERROR = 2, 3
#: A test module's ``pytestmark``: the C backend needs a C compiler.
NEEDS_CC = pytest.mark.skipif(c_backend.c_compiler() is None, reason="the C backend needs a C compiler")


def sanitized_observer(card, output: Path) -> Path:
    """The C observer FMU of ``card`` with its sources compiled under ASan and UBSan."""
    ident = "sanitized_observer"
    guid = c_backend.guid_of({"sanitized": True, **card.data})
    return c_backend.pack_c_fmu(output, ident, c_backend.c_kernel(card), c_backend.design_source(card, guid, ident),
                                lambda sources: c_backend.model_description(card, guid, ident, sources),
                                {"kind": "observer", "card": card.data}, list(cfuzz.SANITIZER_FLAGS))


def sanitized_plant(plant, output: Path) -> Path:
    """The C plant FMU of ``plant`` with its sources compiled under ASan and UBSan."""
    ident = "sanitized_plant"
    data = plant.to_data()
    guid = c_backend.guid_of({"sanitized": True, **data})
    spec = {"kind": "plant", "plant": data}
    return c_backend.pack_c_fmu(output, ident, c_backend.plant_kernel(data), c_backend.plant_source(data, guid, ident),
                                lambda sources: c_backend.plant_model_description(spec, "sanitized", guid, ident,
                                                                                  sources),
                                spec, list(cfuzz.SANITIZER_FLAGS))


def _failed(status: int, call, words) -> None:
    with pytest.raises(FmuCallError) as info:
        call()
    assert info.value.status == status, info.value
    text = " ".join(info.value.messages)
    assert all(w in text for w in words), text


def refused(call, *words) -> None:
    """``call()`` raises fmi2Error with a log line holding every word."""
    _failed(ERROR, call, words)


def discarded(call, *words) -> None:
    """``call()`` returns fmi2Discard with a log line holding every word."""
    _failed(DISCARD, call, words)


def equal_to_the_runtime(path, card, h: float, read, expected) -> np.ndarray:
    """Run the observer FMU at ``path`` and the reference runtime on the same 20 random ``y``, ``u`` from a random
    ``xhat0``, steps of ``h``: ``read(fmu)`` equals ``expected(runtime)`` to 1e-11 at every point, and a state saved at
    point 5 and restored gives the same outputs bit for bit from there. Returns the runtime's last ``z``."""
    from uiofmu.runtime.observer import Runtime

    rng = np.random.default_rng(3)
    dims = card.data["dims"]
    xhat0 = rng.standard_normal(dims["n"])
    ref = Runtime(card, xhat0=xhat0)
    inputs = [(rng.standard_normal(dims["p"]), rng.standard_normal(dims["m"])) for _ in range(20)]
    with Fmu(path, "observer") as fmu:
        fmu.initialize(0.0, {"xhat0": xhat0})
        outs = []
        for k, (y, u) in enumerate(inputs):
            fmu.set("y", y)
            fmu.set("u", u)
            ref.set_y(y)
            ref.set_u(u)
            got = read(fmu)
            np.testing.assert_allclose(got, expected(ref), rtol=1e-11, atol=1e-11)
            outs.append(got)
            if k == 5:
                saved = fmu.serialize(fmu.get_state())
            fmu.step(k * h, h)
            ref.step(h)
        fmu.set_state(fmu.deserialize(saved))        # at t_5, the inputs of t_5 set
        fmu.step(5 * h, h)
        for k, (y, u) in enumerate(inputs[6:], start=6):
            fmu.set("y", y)
            fmu.set("u", u)
            np.testing.assert_array_equal(read(fmu), outs[k])
            fmu.step(k * h, h)
    return ref.z


def run_plant(fmu, rt, h: float, ks: range, t0: float, feed, outputs, reference):
    """Steps ``ks`` of period ``h`` from ``t0`` on the plant FMU and, when given, its runtime ``rt``:
    at each point ``feed(k)`` sets the inputs of both, the outputs are sampled (the FMU's ports
    ``outputs``, the runtime's arrays ``reference(rt)``) and both step; sampled once more after the
    last. The samples of the FMU and of the runtime, as arrays."""
    got, want = [], []

    def sample():
        got.append(np.concatenate([fmu.get(name) for name in outputs]))
        if rt is not None:
            want.append(np.concatenate(reference(rt)))

    for k in ks:
        feed(k)
        sample()
        fmu.step(t0 + (k - ks.start) * h, h)
        if rt is not None:
            rt.step(h)
    sample()
    return np.array(got), np.array(want)


def check_restores(a, b, run, restored=None):
    """The FMU state of the instance ``a`` where it is: the run on from there (``run(fmu)``, its
    outputs) the same after fmi2SetFMUstate in ``a`` and after deserialising it into ``b``
    (initialised here; ``restored(b)`` looks at ``b`` before its run), and both instances in equal
    states after it. Returns the serialised state and the run's outputs."""
    state = a.get_state()
    blob = a.serialize(state)
    after = run(a)
    a.set_state(state)
    assert np.array_equal(after, run(a)), "get/set state"
    b.initialize(0.0)
    b.set_state(b.deserialize(blob))
    if restored is not None:
        restored(b)
    assert np.array_equal(after, run(b)), "serialised state in another instance"
    assert a.serialize(a.get_state()) == b.serialize(b.get_state())
    return blob, after


def refused_edits(path: Path, kernel, edits, tmp_path: Path, tag: str) -> None:
    """Each ``(old, new, words)`` of ``edits`` applied to the design_data.c of the FMU at ``path``
    (``old`` once in it), compiled with the sources of ``kernel`` and instantiated: refused with
    ``words`` in the error."""
    unzip = tmp_path / f"unzip-{tag}"
    with zipfile.ZipFile(path) as z:
        z.extractall(unzip)
    src = unzip / "sources"
    ident = next((unzip / "binaries" / "linux64").iterdir()).stem
    original = (src / "design_data.c").read_text()
    for i, (old, edit, words) in enumerate(edits):
        assert original.count(old) == 1, old
        (src / "design_data.c").write_text(original.replace(old, edit))
        c_backend.compile_binary(src, ident, unzip / "binaries" / "linux64", sources=c_backend.kernel_sources(kernel))
        broken = tmp_path / f"{tag}{i}.fmu"
        shutil.make_archive(str(broken.with_suffix("")), "zip", unzip)
        broken.with_suffix(".zip").rename(broken)
        with pytest.raises(c_backend.FmuError) as info:
            Fmu(broken, "o")
        assert "inconsistent" in str(info.value) and words in str(info.value), str(info.value)


#: The values a random sequence sets: ordinary, extreme and non-finite.
ODD_VALUES = (0.0, 1.0, -1.0, 0.3, math.nan, math.inf, -math.inf, 1e308, -1e308, 5e-324)
#: The values a random sequence sets on an Integer input (a mode, say): in range, out of it, the ends of fmi2Integer.
ODD_INTEGERS = (0, 1, 2, 3, -1, 17, 2 ** 31 - 1, -2 ** 31)


def random_calls(path, h: float, seed: int, calls: int = 400) -> None:
    """``calls`` random FMI calls on the FMU at ``path`` of period ``h`` (inputs set to odd values, steps of odd
    lengths, outputs read, states saved, restored, serialised, byte-flipped and deserialised,
    resets, calls in the wrong instance state): each returns a status from fmi2OK to fmi2Error,
    never fmi2Fatal, and (under the sanitizers) nothing reads or writes out of bounds."""
    rng = np.random.default_rng(seed)
    with Fmu(path, "fuzz") as fmu:
        inputs, outputs = list(fmu.ports("input")), list(fmu.ports("output"))
        blobs, t = [], 0.0
        for _ in range(calls):
            op = int(rng.integers(0, 9))
            try:
                if op == 0 and inputs:
                    name = inputs[int(rng.integers(len(inputs)))]
                    odd = ODD_INTEGERS if fmu.integer(name) else ODD_VALUES
                    fmu.set(name, [odd[int(rng.integers(len(odd)))] for _ in fmu.refs(name)])
                elif op in (1, 2):
                    step = h if op == 1 else float(rng.choice([h / 2, 2 * h, 0.0, -h, math.nan, math.inf]))
                    fmu.step(t, step)
                    t += h
                elif op == 3:
                    for name in outputs:
                        fmu.get(name)
                elif op == 4:
                    blobs.append(fmu.serialize(fmu.get_state()))
                elif op == 5 and blobs:
                    blob = bytearray(blobs[int(rng.integers(len(blobs)))])
                    for _ in range(int(rng.integers(1, 4))):
                        blob[int(rng.integers(len(blob)))] = int(rng.integers(256))
                    fmu.set_state(fmu.deserialize(bytes(blob[:int(rng.integers(len(blob) // 2, len(blob) + 1))])))
                elif op == 6 and blobs:
                    fmu.set_state(fmu.deserialize(blobs[int(rng.integers(len(blobs)))]))
                elif op == 7:
                    fmu.reset()
                else:
                    fmu.initialize(t)
            except FmuCallError as exc:
                assert exc.status in (1, 2, DISCARD, ERROR), exc


def run_sanitized(script: str, kind: str, fmu: Path, data: dict, work: Path) -> None:
    """``python script kind FMU DATA.json`` (:func:`script_main`) in a Python with the sanitizer
    runtimes preloaded: it prints "checked", and the sanitizers report nothing."""
    spec = work / f"{kind}-{Path(fmu).stem}.json"
    spec.write_text(json.dumps(data))
    libs = [subprocess.run(["gcc", f"-print-file-name={lib}"], capture_output=True, text=True).stdout.strip()
            for lib in ("libasan.so", "libubsan.so")]
    env = {**os.environ, "LD_PRELOAD": ":".join(libs), "ASAN_OPTIONS": "detect_leaks=0:abort_on_error=0",
           "UBSAN_OPTIONS": "print_stacktrace=1"}
    proc = subprocess.run([sys.executable, script, kind, str(fmu), str(spec)], capture_output=True, text=True,
                          env=env, timeout=600, cwd=str(HERE.parent))
    assert proc.returncode == 0, proc.stderr[-4000:]
    for mark in cfuzz.SANITIZER_MARKS:
        assert mark not in proc.stderr, proc.stderr[-4000:]
    assert "checked" in proc.stdout, proc.stdout


def check_sanitized(script: str, cards: dict, plants: dict, work: Path) -> None:
    """:func:`run_sanitized` of ``script`` on the sanitized observer FMU of each card (really
    instrumented) and on the sanitized FMU of each plant (dicts by name)."""
    for name, card in cards.items():
        fmu = sanitized_observer(card, work / f"{name}.fmu")
        with zipfile.ZipFile(fmu) as z:     # really instrumented
            assert b"__asan_" in z.read("binaries/linux64/sanitized_observer.so")
        run_sanitized(script, "observer", fmu, card.data, work)
    for name, plant in plants.items():
        run_sanitized(script, "plant", sanitized_plant(plant, work / f"{name}-plant.fmu"), plant.to_data(), work)


def script_main(argv, check_observer, check_plant) -> int:
    """A test file as a script, ``observer FMU CARD.json`` or ``plant FMU PLANT.json``: its
    ``check_observer(fmu, card)`` or ``check_plant(fmu, data)``, "checked" when they pass."""
    from uiofmu.runtime.card import card_from_data

    kind, fmu, spec = argv
    data = json.loads(Path(spec).read_text())
    if kind == "observer":
        check_observer(fmu, card_from_data(data))
    else:
        check_plant(fmu, data)
    print("checked")
    return 0
