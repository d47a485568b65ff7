"""Every runtime kernel on every backend: one observer FMU per kernel and schedule kind, held to one contract.

The table below names, for each kernel, its reference runtime, its output ports (how the runtime gives
each) and one example card per schedule kind it steps; the backends build each card's observer FMU
(once per session: conftest's ``observer_fmus``, which the family tests share). Each pair is checked the
same way:

- the model description: fmpy's ``validate_fmu`` finds nothing, the FMU can get, set and serialise its
  state, its outputs are the kernel's; a C FMU needs no tool and carries its sources;
- the FMU against the reference runtime, on random inputs (modes in 1..N) and random admissible steps,
  from a random ``xhat0``: bit for bit on the python backend, to 1e-12 relative on the C backend;
- state round trips: a state taken mid-run (an input set but not yet stepped with it) restores the same
  continuation by fmi2SetFMUstate in the instance and by deserialisation in another, both then serialise
  to the same bytes; on the C backend also deserialised into a state it reuses, and set in another
  instance from memory;
- refusals: an inadmissible step is answered with fmi2Discard, a NaN input (a mode outside 1..N) with
  fmi2Error, an unknown value reference or a write to an output with fmi2Error, each with a log line and
  nothing changed (the state serialises to the same bytes, and the run goes on equal to the runtime);
- C only: the call fuzzer's short run: tests/c/fmu_fuzz.c under ASan and UBSan (cfuzz.py) for the
  schedule kinds it models (constant, interval, geometric), fmpy-driven random call sequences
  (:func:`cfmu.random_calls`) for the others (tests/test_c_functional.py and tests/test_c_delayed.py run
  those with the FMU's sources under ASan and UBSan).

Every kernel has a C kernel (its descriptor names it); a kernel without one would have no C pair.
"""

from __future__ import annotations

import math
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.validation import validate_fmu

import cfuzz
from cfmu import DISCARD, ERROR, NEEDS_CC, check_restores, random_calls
from test_c_hardening import _layout
from uiofmu.cosim.fmi import Fmu, FmuCallError
from uiofmu.fmu import c_backend
from uiofmu.runtime.delayed import MAX_SUBSTEPS
from uiofmu.runtime.kernels import KERNELS as KERNEL_DESCRIPTORS
from uiofmu.runtime.kernels import SCHEDULES
from uiofmu.runtime.observer import Runtime


#: What the suite reads of each runtime kernel besides its descriptor (:data:`uiofmu.runtime.kernels.KERNELS`:
#: its reference runtime, its C kernel or why it has none): its outputs, each as the runtime gives it (an FMU
#: has those its card has), and how long it runs before it judges a step's length (a function of the card;
#: None: from its first step).
OUTPUTS = {
    "affine": {"xhat": lambda rt: rt.xhat(), "r": lambda rt: rt.residual(), "dhat": lambda rt: rt.dhat()},
    "window": {"gx": lambda rt: rt.gx(), "gx_valid": lambda rt: [float(rt.valid)]},
    "delayed": {"xhat": lambda rt: rt.xhat(), "thetahat": lambda rt: rt.theta(), "r": lambda rt: rt.residual(),
                "sigma_min": lambda rt: [rt.margin()], "valid": lambda rt: [float(rt.valid)]},
}
LEAD_IN = {"delayed": lambda card: 1.1 * max(card.schedule["valid_from"], *card.schedule["delays"])}


@dataclass(frozen=True)
class Kernel:
    """What the suite knows of a runtime kernel: its reference runtime (from its descriptor), its outputs and
    its lead-in (:data:`OUTPUTS`, :data:`LEAD_IN`)."""

    runtime: type
    outputs: dict
    lead_in: object = None


#: The runtime kernels, every one of the descriptors'.
KERNELS = {name: Kernel(k.runtime, OUTPUTS[name], LEAD_IN.get(name)) for name, k in KERNEL_DESCRIPTORS.items()}
#: One example card per kernel and schedule kind: (case, kernel, schedule kind, the session fixture of its
#: card in conftest.py, designed once per session from its problem file).
CASES = [
    ("constant", "affine", "constant", "example1_card"),       # examples/seed000_example1.toml
    ("interval", "affine", "interval", "building_card"),       # plants/two_room_building/problem.toml
    ("geometric", "affine", "geometric", "ltv_card"),          # examples/seed000_example1_ltv.toml
    ("modes", "affine", "mode", "setup2_card"),                # examples/seed002_setup2.toml
    ("window", "window", "window", "needs_theta_card"),        # examples/seed003_needs_theta.toml
    ("delayed", "delayed", "continuous", "delayed_card"),      # conftest.DELAYED_SHORT: valid from 0.1 s
]
BACKENDS = ("c", "python")
#: The kernels the C backend has a kernel for, from their descriptors.
C_KERNEL = {name for name, k in KERNEL_DESCRIPTORS.items() if k.c_kernel is not None}
#: The schedule kinds the C call fuzzer (tests/c/fmu_fuzz.c) models; the others get fmpy-driven random calls.
FUZZER_KINDS = ("constant", "interval", "geometric")
#: Steps of the runs against the runtime (the delayed kernel integrates some 20 RK4 substeps a step). The
#: delayed kernel's 60 stay inside its start-up: on independent random y and ydot its observer is so
#: ill-conditioned (||Gamma|| ~ 1e4) that one ulp of y moves the runtime's own next estimate by 1e-8, so the C
#: backend is held to its runtime on a plant's signals instead (tests/test_c_delayed.py).
STEPS = {"delayed": 60}
DEFAULT_STEPS = 200
#: Largest difference from the runtime relative to 1 + |reference| (python: the same arithmetic, bit for bit).
RTOL = {"c": 1e-12, "python": 0.0}

KIND = {case: (kernel, kind) for case, kernel, kind, _ in CASES}
SOURCE = {case: fixture for case, _, _, fixture in CASES}
PAIRS = [pytest.param(case, backend, id=f"{case}-{backend}", marks=[NEEDS_CC] if backend == "c" else [])
         for case, kernel, _, _ in CASES for backend in BACKENDS if backend == "python" or kernel in C_KERNEL]


# -- designs and FMUs, once per module ----------------------------------------------------------------------

@pytest.fixture(scope="module")
def cards(request):
    """``cards(case)``: the designed card of a case (a session fixture of conftest.py)."""
    def get(case: str):
        card = request.getfixturevalue(SOURCE[case])[0]
        assert card.kernel == KIND[case][0] and card.schedule["kind"] == KIND[case][1], case
        return card

    return get


@pytest.fixture(scope="module")
def fmus(cards, observer_fmus):
    """``fmus(case, backend)``: ``(card, observer FMU path)``, built once per session (conftest's
    ``observer_fmus``: the family tests run the same FMUs)."""
    def get(case: str, backend: str):
        cards(case)
        return observer_fmus(SOURCE[case], backend)

    return get


# -- driving an FMU and its runtime alike -------------------------------------------------------------------

SETTERS = {"y": "set_y", "u": "set_u", "mode": "set_mode", "theta": "set_theta", "ydot": "set_ydot"}


def design_steps(card) -> list:
    """The steps the card's schedule is designed for (continuous time: its default step)."""
    if card.schedule["kind"] == "continuous":
        return [card.schedule["step"]]
    return Runtime(card).schedule.admissible_steps() if card.kernel == "affine" else [card.schedule["dt"]]


def steps_of(card, rng) -> float:
    """A random admissible step: one of the schedule's design steps, or (continuous time, where every
    step is admissible) 0.5 to 1.5 of the default step."""
    if card.schedule["kind"] == "continuous":
        return float(rng.uniform(0.5, 1.5) * card.schedule["step"])
    choices = design_steps(card)
    return float(choices[int(rng.integers(len(choices)))])


def inadmissible_step(card) -> float:
    """A step the card's schedule refuses: 3/4 of its shortest design step, or a continuous-time step that
    needs more substeps than a step may take."""
    if card.schedule["kind"] == "continuous":        # more RK4 substeps than a step may take, however judged
        return 1e3 * MAX_SUBSTEPS * max(card.schedule["max_substep"], card.schedule["step"])
    return 0.75 * min(design_steps(card))


def random_plan(card, inputs: dict, steps: int, seed: int) -> list:
    """``steps`` points: the random inputs of each (``{name: values}``, a mode in 1..N) and the random
    admissible step after it."""
    rng = np.random.default_rng(seed)
    plan = []
    for _ in range(steps):
        values = {name: ([int(rng.integers(1, card.schedule["modes"] + 1))] if name == "mode"
                         else rng.normal(size=size) * 3) for name, size in inputs.items()}
        plan.append((values, steps_of(card, rng)))
    return plan


def fmu_outputs(fmu, names) -> np.ndarray:
    return np.concatenate([fmu.get(name) for name in names])


def runtime_outputs(rt, kernel: str, names) -> np.ndarray:
    return np.concatenate([np.asarray(KERNELS[kernel].outputs[name](rt), dtype=float) for name in names])


def set_inputs(fmu, rt, values: dict) -> None:
    for name, value in values.items():
        fmu.set(name, value)
        if rt is not None:
            getattr(rt, SETTERS[name])(int(value[0]) if name == "mode" else value)


def drive(fmu, rt, card, plan, t0: float = 0.0):
    """The plan on the FMU (and the runtime ``rt``): each point's inputs set, the outputs read, the step
    taken; the outputs of the FMU (and of the runtime) at every point and after the last step."""
    names = list(fmu.ports("output"))
    got, want, t = [], [], t0
    for values, h in plan:
        set_inputs(fmu, rt, values)
        got.append(fmu_outputs(fmu, names))
        fmu.step(t, h)
        if rt is not None:
            want.append(runtime_outputs(rt, card.kernel, names))
            rt.step(h)
        t += h
    got.append(fmu_outputs(fmu, names))
    if rt is not None:
        want.append(runtime_outputs(rt, card.kernel, names))
    return np.array(got), np.array(want), t


def started(fmu, card, seed: int):
    """The FMU initialised and its runtime, both from one random ``xhat0`` where the kernel has one."""
    rt = KERNELS[card.kernel].runtime(card)
    if fmu.has("xhat0"):
        xhat0 = np.random.default_rng(seed).normal(size=len(fmu.refs("xhat0")))
        fmu.initialize(0.0, {"xhat0": xhat0})
        rt.xhat0 = xhat0.copy()
        rt.reset()
    else:
        fmu.initialize(0.0)
    return rt


def assert_close(got, want, backend: str, what: str) -> None:
    got, want = np.asarray(got, dtype=float), np.asarray(want, dtype=float)
    assert got.shape == want.shape, what
    err = np.abs(got - want) / (1.0 + np.abs(want))
    err = np.where(np.isnan(err), np.inf, err)
    assert err.max() <= RTOL[backend], f"{what}: largest relative difference {err.max():.3g} > {RTOL[backend]:g}"


# -- the contract -------------------------------------------------------------------------------------------

def test_every_kernel_and_schedule_kind_of_the_descriptors_has_a_case():
    """A kernel or a schedule kind added to :mod:`uiofmu.runtime.kernels` without a case here fails."""
    assert {kernel for _, kernel, _, _ in CASES} == set(KERNEL_DESCRIPTORS)
    assert {kind for _, _, kind, _ in CASES} == set(SCHEDULES)
    assert all(kind in KERNEL_DESCRIPTORS[kernel].schedules for _, kernel, kind, _ in CASES)


@pytest.mark.parametrize("case, backend", PAIRS)
def test_the_model_description_declares_the_kernel(fmus, case, backend):
    card, path = fmus(case, backend)
    assert validate_fmu(str(path)) == []
    md = read_model_description(str(path))
    assert md.coSimulation.canGetAndSetFMUstate and md.coSimulation.canSerializeFMUstate
    outputs = {v.name.split("[")[0] for v in md.modelVariables if v.causality == "output"}
    assert outputs and outputs <= set(KERNELS[card.kernel].outputs), outputs
    assert float(md.defaultExperiment.stepSize) in design_steps(card)
    if backend == "c":
        assert md.coSimulation.needsExecutionTool is False
        with zipfile.ZipFile(path) as z:
            names = set(z.namelist())
        sources = {f"sources/{name}" for name in c_backend.c_sources(card)}
        assert sources | {f"binaries/linux64/{md.coSimulation.modelIdentifier}.so"} <= names, sorted(names)


@pytest.mark.parametrize("case, backend", PAIRS)
def test_the_fmu_equals_the_runtime_on_random_steps(fmus, case, backend):
    card, path = fmus(case, backend)
    with Fmu(path, "observer") as fmu:
        rt = started(fmu, card, seed=3)
        plan = random_plan(card, fmu.ports("input"), STEPS.get(card.kernel, DEFAULT_STEPS), seed=5)
        got, want, _ = drive(fmu, rt, card, plan)
    assert np.all(np.isfinite(got)) and np.ptp(got) > 0, "a run that shows nothing"
    if card.schedule["kind"] in ("interval", "continuous"):
        assert len({h for _, h in plan}) > 1, "the steps are not aperiodic"
    if "mode" in plan[0][0]:
        assert {v["mode"][0] for v, _ in plan} == set(range(1, card.schedule["modes"] + 1))
    assert_close(got, want, backend, f"{case} on the {backend} backend against {type(rt).__name__}")


@pytest.mark.parametrize("case, backend", PAIRS)
def test_a_saved_state_restores_the_same_continuation(fmus, case, backend):
    card, path = fmus(case, backend)
    with Fmu(path, "a") as a, Fmu(path, "b") as b:
        started(a, card, seed=7)
        plan = random_plan(card, a.ports("input"), 50, seed=9)
        _, _, t = drive(a, None, card, plan[:30])
        set_inputs(a, None, plan[30][0])            # an input set but not yet stepped travels with the state
        rest = [({}, plan[30][1]), *plan[31:]]

        def restored(fmu):
            for name, value in plan[30][0].items():
                assert np.array_equal(fmu.get(name), np.asarray(value, dtype=float)), name

        blob, after = check_restores(a, b, lambda fmu: drive(fmu, None, card, rest, t)[0], restored)
        assert np.ptp(after) > 0
        if backend == "c":
            assert _layout(blob)[0] == read_model_description(str(path)).guid   # the image names its FMU
            state = a.get_state()
            before = a.serialize(state)
            drive(a, None, card, rest, t)
            a.set_state(a.slave.deSerializeFMUstate(blob, state=state))      # into the state it reuses
            assert np.array_equal(drive(a, None, card, rest, t)[0], after), "deserialised into a reused state"
            b.set_state(state)                                                  # from memory, in another instance
            assert b.serialize(b.get_state()) == blob and before != blob
            a.slave.freeFMUstate(state)


@pytest.mark.parametrize("case, backend", PAIRS)
def test_an_inadmissible_step_is_discarded_and_changes_nothing(fmus, case, backend):
    card, path = fmus(case, backend)
    with Fmu(path, "observer") as fmu:
        rt = started(fmu, card, seed=11)
        plan = random_plan(card, fmu.ports("input"), 12, seed=13)
        lead_in = KERNELS[card.kernel].lead_in
        if lead_in is not None:                     # to where the kernel judges a step's length
            plan[0] = (plan[0][0], lead_in(card))
        _, _, t = drive(fmu, rt, card, plan[:5])
        set_inputs(fmu, rt, plan[5][0])
        before = fmu.serialize(fmu.get_state())
        bad = inadmissible_step(card)
        with pytest.raises(FmuCallError) as info:
            fmu.step(t, bad)
        assert info.value.status == DISCARD, info.value
        assert info.value.messages, "a discarded step without a log line"
        assert fmu.serialize(fmu.get_state()) == before, "a discarded step changed the state"
        got, want, _ = drive(fmu, rt, card, [({}, plan[5][1]), *plan[6:]], t)
    assert_close(got, want, backend, "after the discarded step")


def bad_values(card, inputs: dict):
    """``(name, values, words)``: an input out of its range and the words of its refusal."""
    out = []
    for name, size in inputs.items():
        if name == "mode":
            N = card.schedule["modes"]
            out += [(name, [bad], (f"mode = {bad}", f"from 1 to {N}")) for bad in (0, N + 1)]
        else:
            out.append((name, [math.nan] * size, (f"{name}[1] = nan", "not finite")))
    return out


@pytest.mark.parametrize("case, backend", PAIRS)
def test_an_input_out_of_range_is_an_error_and_changes_nothing(fmus, case, backend):
    card, path = fmus(case, backend)
    with Fmu(path, "observer") as fmu:
        rt = started(fmu, card, seed=15)
        inputs = fmu.ports("input")
        plan = random_plan(card, inputs, 12, seed=17)
        _, _, t = drive(fmu, rt, card, plan[:5])
        set_inputs(fmu, rt, plan[5][0])
        before = fmu.serialize(fmu.get_state())
        for name, values, words in bad_values(card, inputs):
            fmu.set(name, values)
            with pytest.raises(FmuCallError) as info:
                fmu.step(t, plan[5][1])
            assert info.value.status == ERROR, info.value
            assert any(all(w in m for w in words) for m in info.value.messages), (words, info.value.messages)
            fmu.set(name, plan[5][0][name])
            assert fmu.serialize(fmu.get_state()) == before, f"a refused {name} changed the state"
        got, want, _ = drive(fmu, rt, card, [({}, plan[5][1]), *plan[6:]], t)
    assert_close(got, want, backend, "after the refused inputs")


@pytest.mark.parametrize("case, backend", PAIRS)
def test_bad_value_references_are_errors_and_change_nothing(fmus, case, backend):
    """An unknown value reference read or written, an output written (alone and with an input): fmi2Error
    with a log line; nothing is set, and the run goes on equal to the runtime."""
    card, path = fmus(case, backend)
    with Fmu(path, "observer") as fmu:
        rt = started(fmu, card, seed=19)
        inputs = fmu.ports("input")
        real_in = next(name for name in inputs if not fmu.integer(name))
        real_out = next(name for name in fmu.ports("output") if not fmu.integer(name))
        plan = random_plan(card, inputs, 10, seed=21)
        _, _, t = drive(fmu, rt, card, plan[:4])
        set_inputs(fmu, rt, plan[4][0])
        before = fmu.serialize(fmu.get_state())
        vin, vout = fmu.refs(real_in)[0], fmu.refs(real_out)[0]
        for function, *args in (("getReal", [vout, 99999]), ("getReal", [2 ** 32 - 1]),
                                ("setReal", [vin, 99999], [5.0, 5.0]), ("setReal", [vout], [123.0]),
                                ("setReal", [vin, vout], [7.0, 7.0])):
            start = len(fmu.messages)
            with pytest.raises(FmuCallError) as info:
                fmu._call(function, *args)
            assert info.value.status == ERROR, (function, args, info.value)
            assert fmu.messages[start:], (function, args, "no log line")
            assert fmu.serialize(fmu.get_state()) == before, (function, args, "changed the state")
        got, want, _ = drive(fmu, rt, card, [({}, plan[4][1]), *plan[5:]], t)
    assert_close(got, want, backend, "after the refused calls")


# -- the C call fuzzer ---------------------------------------------------------------------------------------

C_PAIRS = [pytest.param(case, id=case, marks=NEEDS_CC) for case, kernel, _, _ in CASES if kernel in C_KERNEL]
PLUMBING_SCENARIOS = ("state-masks", "status-after-discard", "log-categories")


def no_sanitizer_report(res) -> None:
    text = res.stdout + res.stderr
    assert not any(mark in text for mark in cfuzz.SANITIZER_MARKS), text[-3000:]


def fuzz_with_the_c_fuzzer(name: str, path: Path, work: Path) -> None:
    """The fuzzer built warning-free with the sources of the C FMU at ``path``; its scenarios, each plumbing
    scenario on its own, and a random run of 3 s: no failed check, no sanitizer report."""
    with zipfile.ZipFile(path) as z:
        z.extractall(work, [n for n in z.namelist() if n.startswith("sources/")])
    target = cfuzz.Target(name, work / "fmu_fuzz", work / "sources", fmu=path)
    target.warnings = cfuzz.compile_fuzzer(target.sources, target.exe)
    assert target.warnings == ""
    res = cfuzz.run_scenarios(target)
    no_sanitizer_report(res)
    assert res.returncode == 0 and res.failures == [], res.stderr[-3000:]
    names = cfuzz.scenario_names(target)
    assert len(names) >= 12 and res.scenarios == {name: "ok" for name in names}
    for fn in ("fmi2SetFMUstate", "fmi2DeSerializeFMUstate", "fmi2GetFMUstate"):   # forged refused, valid taken
        assert res.functions[fn].get("error", 0) > 0 and res.functions[fn].get("ok", 0) > 0, fn
    for scenario in PLUMBING_SCENARIOS:
        res = cfuzz.run(target, "scenarios", "--scenario", scenario)
        no_sanitizer_report(res)
        assert res.returncode == 0 and res.failures == [] and res.scenarios == {scenario: "ok"}, res.stderr[-3000:]
        if scenario == "state-masks":
            for fn in ("fmi2DoStep", "fmi2SetupExperiment", "fmi2Terminate", "fmi2GetStatus", "fmi2SetReal"):
                assert res.functions[fn].get("error", 0) > 0 and res.functions[fn].get("ok", 0) + \
                    res.functions[fn].get("discard", 0) > 0, fn
        if scenario == "status-after-discard":
            assert res.functions["fmi2GetRealStatus"]["ok"] >= 3 and res.functions["fmi2GetStatus"]["discard"] >= 1
    res = cfuzz.run_random(target, seconds=3.0, seed=11)
    no_sanitizer_report(res)
    assert res.returncode == 0 and res.failures == [], res.stderr[-3000:]
    assert res.sequences > 100 and res.calls > 50_000
    assert all(res.statuses.get(k, 0) > 0 for k in ("ok", "discard", "error")), res.statuses
    assert res.statuses.get("other", 0) == 0 and res.statuses.get("fatal", 0) == 0
    assert res.functions["fmi2DeSerializeFMUstate"]["ok"] > 100
    assert res.functions["fmi2DeSerializeFMUstate"]["error"] > 100
    assert res.functions["fmi2DoStep"]["ok"] > 1000


@pytest.mark.parametrize("case", C_PAIRS)
def test_the_call_fuzzers_short_run(fmus, tmp_path, case):
    card, path = fmus(case, "c")
    if card.schedule["kind"] in FUZZER_KINDS:
        fuzz_with_the_c_fuzzer(case, path, tmp_path)
    else:
        random_calls(path, design_steps(card)[0], seed=1)
