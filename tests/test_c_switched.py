"""The C backend of switched UIOs and switched plants (seed 002): kernel_affine.c with a mode
schedule and kernel_plant.c with modes and a switching rule, against the Python references.

(a) The C observer FMU equals uiofmu.runtime.observer.Runtime to 1e-12 on 100 steps of a random
mode sequence with random y, u: setup 2 (dead-beat) and a 3-mode plant of our own whose modes
allow no dead-beat observer (an LMI design, decay 0.54).
(b) A bad input mode (0, N + 1) refuses the step with fmi2Error and a log line naming the mode and
the range; nothing changes and the run goes on; a bad mode_prev0 is refused when initialisation
ends.
(c) FMU states (get/set, serialise/deserialise) restore bit-identical runs, the previous mode
included; forged bytes with a bad previous mode are refused.
(d) The C switched plant equals SwitchedPlantRuntime for the rules threshold, input and random
(with a seed) over 100 steps with random u, d; its state (x, generator, drawn mode, input mode,
seed) round-trips; a bad input mode is refused with fmi2Error and a log line.
(e) (a)-(d) again with the FMUs' own C sources compiled under ASan and UBSan (cfmu.sanitized_observer
and sanitized_plant: cfuzz.SANITIZER_FLAGS, the flags of the fuzzer and of plant_test.c), run
through fmpy in a Python with the sanitizer runtimes preloaded (cfmu.run_sanitized): no report.

Each check is a plain function of an FMU's path, the sanitized run the same code: this file runs
as a script too (``python tests/test_c_switched.py observer|plant FMU DATA.json``).
"""

from __future__ import annotations

import dataclasses
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description

sys.path.insert(0, str(Path(__file__).resolve().parent))

from cfmu import (NEEDS_CC, check_restores, check_sanitized, refused, refused_edits, run_plant,  # noqa: E402
                  script_main)
from test_c_hardening import _layout, _with_double  # noqa: E402
from uiofmu.cosim.fmi import Fmu  # noqa: E402
from uiofmu.fmu import c_backend  # noqa: E402
from uiofmu.fmu.export import build_observer, build_plant  # noqa: E402
from uiofmu.problem import problem_from_data  # noqa: E402
from uiofmu.runtime.observer import Runtime  # noqa: E402
from uiofmu.runtime.switching import SwitchedPlantRuntime  # noqa: E402
from uiofmu.synthesis import design  # noqa: E402

pytestmark = NEEDS_CC
RTOL = 1e-12
STEPS = 100

SETUP2 = {
    "name": "millerioux-daafouz-setup2",
    "plant": {"time": "discrete", "dt": 1.0, "C": [[1.0, 1.0, -1.0], [2.0, -1.0, 1.0]], "E": [[1.0], [-2.0], [1.0]],
              "modes": [{"A": [[0.0, 0.89, -2.0], [-1.28, 0.89, 0.0], [-0.1, 0.0, 0.1]]},
                        {"A": [[0.0, 0.89, -2.0], [1.95, 0.89, 0.0], [-0.1, 0.0, 0.1]], "w": [0.0, -18.0, 0.0]}],
              "switching": {"rule": "threshold", "state": 1, "threshold": 6.0}},
    "observer": {"family": "switched", "decay": "max"},
}


def three_modes() -> dict:
    """A 3-mode plant (n = 3, p = 2, q = 1, m = 1) whose modes allow no dead-beat observer: each A_i
    maps the output direction orthogonal to C E into the row space of C (rank Ct_i = 2 < n), with a
    spectral radius of 0.9 and an affine term; rule random."""
    rng = np.random.default_rng(7)
    C, E = rng.normal(size=(2, 3)), rng.normal(size=(3, 1))
    CE = C @ E
    g = C.T @ np.array([CE[1, 0], -CE[0, 0]])
    modes = []
    for _ in range(3):
        A0, r = rng.normal(size=(3, 3)), C.T @ rng.normal(size=2)
        A = A0 + np.outer(g, r - A0.T @ g) / (g @ g)
        A *= 0.9 / max(abs(np.linalg.eigvals(A)))
        modes.append({"A": A.tolist(), "w": (0.1 * rng.normal(size=3)).tolist()})
    return {"name": "three-modes",
            "plant": {"time": "discrete", "dt": 0.5, "C": C.tolist(), "E": E.tolist(),
                      "B": rng.normal(size=(3, 1)).tolist(),
                      "modes": modes, "switching": {"rule": "random", "probabilities": [0.2, 0.3, 0.5], "seed": 3}},
            "observer": {"family": "switched", "decay": "max", "mode_prev0": 2}}


PROBLEMS = {"setup2": SETUP2, "three-modes": three_modes()}


def assert_close(a, b, what):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    assert a.shape == b.shape, what
    scale = 1.0 + np.abs(b)
    assert np.all(np.abs(a - b) <= RTOL * scale), f"{what}: max error {np.max(np.abs(a - b) / scale):.3g}"


# -- the observer -----------------------------------------------------------------------------------

def observer_outputs(fmu, rt=None):
    """``xhat, r, dhat`` of an FMU (or of the runtime ``rt``) as one vector."""
    if rt is not None:
        return np.concatenate([rt.xhat(), rt.residual(), rt.dhat()])
    return np.concatenate([fmu.get("xhat"), fmu.get("r"), fmu.get("dhat")])


def observer_inputs(card, seed: int):
    """A random mode sequence 1..N and random y, u for STEPS steps."""
    rng = np.random.default_rng(seed)
    d = card.dims
    return (rng.integers(1, card.schedule["modes"] + 1, STEPS), rng.normal(size=(STEPS, d["p"])) * 3,
            rng.normal(size=(STEPS, d["m"])))


def _observe(fmu, rt, card, modes, ys, us, t0=0.0, k0=0):
    """Steps k0.. of the inputs on the FMU (and the runtime); the outputs before each step and after the last."""
    h = card.schedule["dt"]
    got, want = [], []
    for k in range(k0, len(modes)):
        fmu.set("y", ys[k])
        fmu.set("u", us[k])
        fmu.set("mode", [modes[k]])
        got.append(observer_outputs(fmu))
        if rt is not None:
            rt.set_y(ys[k])
            rt.set_u(us[k])
            rt.set_mode(int(modes[k]))
            want.append(observer_outputs(None, rt).copy())
            rt.step(h)
        fmu.step(t0 + (k - k0) * h, h)
    got.append(observer_outputs(fmu))
    if rt is not None:
        want.append(observer_outputs(None, rt).copy())
    return np.array(got), np.array(want)


def check_observer(path, card) -> None:
    """(a), (b), (c) for the C observer FMU at ``path`` of ``card``."""
    N, h = card.schedule["modes"], card.schedule["dt"]
    modes, ys, us = observer_inputs(card, 5)
    # (a) equal to the runtime; and the mode port's start value is the design's mode_prev0
    with Fmu(path, "observer") as fmu:
        assert fmu.integer("mode") and fmu.integer("mode_prev0")
        assert fmu.get("mode_prev0")[0] == card.schedule["mode_prev0"]
        fmu.initialize(0.0)
        got, want = _observe(fmu, Runtime(card), card, modes, ys, us)
    assert_close(got, want, f"{card.name}: C observer against the runtime")
    # (b) bad modes, then the run goes on
    with Fmu(path, "observer") as fmu:
        fmu.initialize(0.0)
        rt = Runtime(card)
        _observe(fmu, rt, card, modes[:10], ys, us)
        before = observer_outputs(fmu)
        for bad in (0, N + 1, -7):
            fmu.set("mode", [bad])
            refused(lambda: fmu.step(10 * h, h), f"mode = {bad}", f"from 1 to {N}")
            assert np.array_equal(observer_outputs(fmu), before), "a refused step changed the outputs"
        got, want = _observe(fmu, rt, card, modes[:20], ys, us, t0=10 * h, k0=10)
        assert_close(got[1:], want[1:], "after the refused steps")
    for bad in (0, N + 1):
        with Fmu(path, "observer") as fmu:
            refused(lambda: fmu.initialize(0.0, {"mode_prev0": [bad]}), f"mode_prev0 = {bad}", f"from 1 to {N}")
    with Fmu(path, "observer") as fmu:                # another valid mode_prev0: the runtime with it
        other = N - card.schedule["mode_prev0"] + 1
        fmu.initialize(0.0, {"mode_prev0": [other]})
        got, want = _observe(fmu, Runtime(card, mode_prev0=other), card, modes[:10], ys, us)
        assert_close(got, want, f"mode_prev0 = {other}")
    # (c) states: a run from a restored state is the same run, bit for bit
    with Fmu(path, "observer") as a, Fmu(path, "observer") as b:
        a.initialize(0.0)
        _observe(a, None, card, modes[:30], ys, us)

        def restored(fmu):
            assert fmu.get("mode")[0] == modes[29]

        blob, _ = check_restores(a, b, lambda fmu: _observe(fmu, None, card, modes[:60], ys, us, t0=30 * h, k0=30)[0],
                                 restored)
        d = card.dims
        at = 5 + d["nz"] + 2 * d["p"] + d["n"] + d["m"]       # mode, mode_prev, mode_prev0 after u
        b.set_state(b.deserialize(_with_double(blob, at + 1, float(modes[29]))))   # the same: accepted
        for index, value, word in ((at + 1, 0.0, "mode_prev"), (at + 1, N + 1.0, "mode_prev"),
                                   (at + 1, 1.5, "mode_prev"), (at + 2, 0.0, "mode_prev0"), (at, 0.5, "mode"),
                                   (at, float("nan"), "mode")):
            refused(lambda: b.deserialize(_with_double(blob, index, value)), word)
        # the previous mode is what the restored state carries: another one gives other outputs
        other = 1 + modes[29] % N
        b.set_state(b.deserialize(_with_double(blob, at + 1, float(other))))
        b.set("y", ys[30])
        rt = Runtime(card)
        for k in range(30):
            rt.set_y(ys[k])
            rt.set_u(us[k])
            rt.set_mode(int(modes[k]))
            rt.step(h)
        rt.mode_prev = int(other)
        rt.set_y(ys[30])
        assert_close(b.get("xhat"), rt.xhat(), "xhat after a state with another previous mode")


# -- the plant --------------------------------------------------------------------------------------

def plant_inputs(data: dict, seed: int):
    """Random u, d and input modes for STEPS steps."""
    rng = np.random.default_rng(seed)
    n, N = len(data["C"][0]), len(data["modes"])
    m, q = np.asarray(data["modes"][0]["B"]).reshape(n, -1).shape[1], np.asarray(data["modes"][0]["E"]).shape[1]
    return rng.normal(size=(STEPS, m)), rng.normal(size=(STEPS, q)), rng.integers(1, N + 1, STEPS)


def _plant_run(fmu, rt, data, us, ds, modes, k0=0, t0=0.0):
    """Steps k0.. on the FMU (and the runtime): ``x, y, mode`` before each step and after the last."""
    rule = data["switching"]["rule"]

    def feed(k):
        fmu.set("u", us[k])
        fmu.set("d", ds[k])
        if rule == "input":
            fmu.set("mode", [modes[k]])
        if rt is not None:
            rt.u[:], rt.d[:] = us[k], ds[k]
            rt.mode_in = int(modes[k])

    return run_plant(fmu, rt, data["dt"], range(k0, len(us)), t0, feed, ("x", "y", "mode"),
                     lambda r: [r.x, r.y(), [r.mode()]])


def check_plant(path, data: dict) -> None:
    """(d) for the C switched plant FMU at ``path`` of ``data`` (SwitchedPlant.to_data())."""
    rule, N, h = data["switching"]["rule"], len(data["modes"]), data["dt"]
    us, ds, modes = plant_inputs(data, 9)
    seed = -123456789
    with Fmu(path, "plant") as fmu:
        assert fmu.integer("mode")
        rt = SwitchedPlantRuntime(data)
        assert fmu.get("mode")[0] == rt.mode(), "the mode before initialisation"
        params = {"seed": [seed]} if rule == "random" else {}
        fmu.initialize(0.0, params)
        rt.seed = seed if rule == "random" else rt.seed
        rt.reset()
        got, want = _plant_run(fmu, rt, data, us, ds, modes)
    assert_close(got, want, f"C switched plant (rule {rule}) against the runtime")
    used = set(want[:-1, -1].astype(int))
    assert len(used) > 1, f"rule {rule}: one mode only ({used})"
    # states: the same run after a restore, in the same and another instance
    with Fmu(path, "plant") as a, Fmu(path, "plant") as b:
        a.initialize(0.0, params)
        _plant_run(a, None, data, us[:40], ds, modes)
        blob, _ = check_restores(a, b, lambda fmu: _plant_run(fmu, None, data, us[:80], ds, modes, 40, 40 * h)[0])
        n, m, q = len(data["C"][0]), us.shape[1], ds.shape[1]
        at = 3 + 2 * n + m + q                              # mode_in, seed, rng_hi, rng_lo, drawn
        for index, value, word in ((at + 4, 0.0, "drawn"), (at + 4, N + 1.0, "drawn"), (at + 2, 2.0 ** 32, "rng_hi"),
                                   (at + 3, -1.0, "rng_lo"), (at, 0.5, "mode_in"), (at + 1, 2.0 ** 31, "seed"),
                                   (at - 2, -0.5, "mismatch = -0.5"), (at - 1, 0.5, "mismatch_seed")):
            refused(lambda: b.deserialize(_with_double(blob, index, value)), word)
    if rule == "random":                                # the generator's state is the reference's, bit for bit
        with Fmu(path, "plant") as fmu:
            fmu.initialize(0.0, params)
            _plant_run(fmu, None, data, us[:25], ds, modes)
            blob = fmu.serialize(fmu.get_state())
        rt = SwitchedPlantRuntime(data)
        rt.seed = seed
        rt.reset()
        for _ in range(25):
            rt.step(h)
        _, data_at = _layout(blob)
        hi, lo = np.frombuffer(blob[data_at + 8 * (at + 2):data_at + 8 * (at + 4)], dtype="<f8")
        assert int(hi) << 32 | int(lo) == rt.rng
    if rule == "input":
        with Fmu(path, "plant") as fmu:
            fmu.initialize(0.0)
            for bad in (0, N + 1):
                fmu.set("mode", [bad])
                x = fmu.get("x")
                refused(lambda: fmu.step(0.0, h), f"mode = {bad}", f"from 1 to {N}")
                assert np.array_equal(fmu.get("x"), x)
            fmu.set("mode", [1])
            fmu.step(0.0, h)


# -- the tests --------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def cards(setup2_card):
    """The designs of :data:`PROBLEMS`; setup 2's is conftest's (examples/seed002_setup2.toml, the same plant
    and observer), whose C FMU tests/test_conformance.py runs too."""
    return {"setup2": setup2_card[0], "three-modes": design(problem_from_data(PROBLEMS["three-modes"]))}


def test_the_three_mode_design_is_not_dead_beat(cards):
    card = cards["three-modes"]
    assert card.data["design_method"] == "lmi" and 0.3 < card.data["decay_bound"] < 1
    assert np.abs(card.matrices["N"]).max() > 0.1
    assert cards["setup2"].data["decay_bound"] < 1e-9


@pytest.mark.parametrize("name", ["three-modes"])   # setup 2 (and the sanitized runs): test_conformance.py, below
def test_the_c_observer_equals_the_runtime(cards, tmp_path, name):
    card = cards[name]
    path = build_observer(card, tmp_path / "o.fmu", backend="c")
    check_observer(path, card)


RULES = {"threshold": {"rule": "threshold", "state": 1, "thresholds": [-0.1, 0.2]},
         "input": {"rule": "input", "mode0": 2},
         "random": {"rule": "random", "probabilities": [0.2, 0.3, 0.5], "seed": 3}}


def switched_plant(rule: str):
    """The three-mode plant with the switching rule ``rule``."""
    plant = problem_from_data(PROBLEMS["three-modes"]).plant
    return dataclasses.replace(plant, switching=RULES[rule])


@pytest.mark.parametrize("rule", list(RULES))
def test_the_c_switched_plant_equals_the_runtime(tmp_path, rule):
    plant = switched_plant(rule)
    path = build_plant(plant, "three", tmp_path / "p.fmu", backend="c")
    md = read_model_description(str(path))
    assert "switched linear plant" in md.description
    names = [v.name for v in md.modelVariables]
    assert names.index("mode[1]") == (names.index("d[1]") + 1 if rule == "input" else len(names) - 3)
    assert names[-2:] == ["mismatch[1]", "mismatch_seed[1]"]
    assert ("seed[1]" in names) == (rule == "random")
    check_plant(path, plant.to_data())


def test_setup2_plant_under_its_threshold_rule_equals_the_runtime(tmp_path):
    plant = problem_from_data(SETUP2).plant
    path = build_plant(plant, "setup2", tmp_path / "p.fmu", backend="c")
    data = plant.to_data()
    us, ds, modes = plant_inputs(data, 1)
    with Fmu(path, "plant") as fmu:
        fmu.initialize(0.0)
        got, want = _plant_run(fmu, SwitchedPlantRuntime(data), data, us[:30], ds * 0.1, modes)
    assert_close(got, want, "setup 2 plant")


#: Hand edits of a mode observer's design_data.c and the words of fmi2Instantiate's refusal.
MODE_EDITS = [(".modes = 2, .mode_prev0 = 1", ".modes = 0, .mode_prev0 = 1", "modes = 0 is out of range"),
              (".modes = 2, .mode_prev0 = 1", ".modes = 2, .mode_prev0 = 3", "mode_prev0 = 3 is not a mode"),
              (".modes = 2, .mode_prev0 = 1", ".modes = 3, .mode_prev0 = 1", "matrix N has 4 blocks, expected 9"),
              (".policy = UIOFMU_POLICY_ERROR", ".policy = UIOFMU_POLICY_NEAREST", "does not go with a mode schedule")]


def test_instantiate_refuses_inconsistent_mode_design_data(cards, observer_fmus, tmp_path):
    _, path = observer_fmus("setup2_card", "c")
    refused_edits(path, c_backend.c_kernel(cards["setup2"]), MODE_EDITS, tmp_path, "edit")


@pytest.mark.skipif(not shutil.which("gcc"), reason="the sanitizers need gcc")
def test_the_observers_and_plants_under_asan_and_ubsan(cards, tmp_path):
    check_sanitized(__file__, cards, {rule: switched_plant(rule) for rule in RULES}, tmp_path)


if __name__ == "__main__":
    sys.exit(script_main(sys.argv[1:], check_observer, check_plant))
