"""A plant other than the design model on purpose: the parameters mismatch and mismatch_seed of plant FMUs.

(a) The law (uiofmu/runtime/mismatch.py): mismatch 0 is the design model exactly; every entry moves by a
relative amount within sqrt(3) mismatch, drawn in the documented order from SplitMix64 (an entry's factor
checked against the generator's output by hand); the same seed draws the same plant, another seed another.
(b) Both backends perturb to the same bits: a discrete plant stepped once from basis vectors shows the
columns of its A, B, E exactly (x1 = A e_j with u = d = 0, ...), for a linear and a switched plant (every
mode), equal to the reference runtime's matrices bit for bit.
(c) Both backends refuse a mismatch that is not a finite number >= 0 at fmi2ExitInitializationMode with a
log line naming it; a restored state (the Python backend) recomputes the perturbed matrices.
(d) The plant FMUs declare the two parameters last (the other value references unchanged); a MuJoCo
plant's declaration has none.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from fmpy import read_model_description

from conftest import EXAMPLES, run_cli
from uiofmu.cosim.fmi import Fmu, FmuCallError
from uiofmu.fmu.c_backend import c_compiler
from uiofmu.fmu.export import build_plant
from uiofmu.plant import Plant
from uiofmu.problem import problem_from_data
from uiofmu.runtime.mismatch import perturb
from uiofmu.runtime.plant_runtime import PlantRuntime
from uiofmu.runtime.ports import plant_ports
from uiofmu.runtime.splitmix import splitmix64
from uiofmu.runtime.switching import SwitchedPlantRuntime

BACKENDS = ["python"] + (["c"] if c_compiler() is not None else [])


def discrete_plant() -> Plant:
    rng = np.random.default_rng(3)
    n, m, q, p = 3, 2, 1, 2
    return Plant.create(0.3 * rng.normal(size=(n, n)), rng.normal(size=(p, n)), rng.normal(size=(n, q)),
                        rng.normal(size=(n, m)), time="discrete", dt=0.1, x0=np.zeros(n))


def switched_plant():
    """Two modes, rule input, no affine term (so a step from a basis vector shows a column exactly)."""
    rng = np.random.default_rng(5)
    modes = [{"A": (0.3 * rng.normal(size=(3, 3))).tolist(), "E": rng.normal(size=(3, 1)).tolist()}
             for _ in range(2)]
    data = {"name": "two-modes",
            "plant": {"time": "discrete", "dt": 0.5, "C": rng.normal(size=(2, 3)).tolist(),
                      "B": rng.normal(size=(3, 1)).tolist(), "modes": modes,
                      "switching": {"rule": "input", "mode0": 1}},
            "observer": {"family": "switched"}}
    return problem_from_data(data).plant


# (a) ---------------------------------------------------------------------------------------------------

def test_mismatch_zero_is_the_design_model():
    plant = discrete_plant()
    rt = PlantRuntime(plant.to_data())
    design = (rt.A.copy(), rt.B.copy(), rt.E.copy())
    rt.set_mismatch(0.0, 99)
    for got, want in zip((rt.A, rt.B, rt.E), design):
        assert np.array_equal(got, want)


def test_the_perturbation_follows_its_law():
    rng = np.random.default_rng(0)
    A, B, E = rng.normal(size=(4, 4)), rng.normal(size=(4, 2)), rng.normal(size=(4, 3))
    s = 0.05
    [(A1, B1, E1)] = perturb([(A, B, E)], s, 7)
    rel = np.concatenate([(M1 / M - 1).ravel() for M1, M in ((A1, A), (B1, B), (E1, E))])
    assert np.all(np.abs(rel) <= math.sqrt(3) * s * (1 + 1e-12))
    assert np.all(rel != 0)
    assert abs(np.std(rel) - s) < 0.35 * s                        # unit variance times s (28 draws)
    # the order: A row by row, then B, then E; the 17th draw is E[0, 0] (16 of A before it... and 8 of B)
    state, word = 7, 0
    for _ in range(16 + 8 + 1):
        state, word = splitmix64(state)
    g = math.sqrt(3.0) * (2.0 * ((word >> 11) * 2.0 ** -53) - 1.0)
    assert E1[0, 0] == E[0, 0] * (1.0 + s * g)
    [(A2, _, _)] = perturb([(A, B, E)], s, 7)
    [(A3, _, _)] = perturb([(A, B, E)], s, 8)
    assert np.array_equal(A1, A2) and not np.array_equal(A1, A3)


def test_a_switched_plant_draws_block_by_block():
    rt = SwitchedPlantRuntime(switched_plant().to_data())
    design = [tuple(M.copy() for M in block) for block in rt.blocks()]
    rt.set_mismatch(0.1, -3)
    blocks = perturb(design, 0.1, -3)
    for mode, block in zip(rt.modes, blocks):
        for got, want in zip(mode[:3], block):
            assert np.array_equal(got, want)
    # the second mode's A continues the generator where the first mode's E ended
    assert not np.array_equal(blocks[1][0], perturb([design[1]], 0.1, -3)[0][0])


# (b) ---------------------------------------------------------------------------------------------------

def columns(fmu, n: int, m: int, q: int, mismatch: float, seed: int, mode: int | None = None) -> tuple:
    """``(A, B, E)`` of a discrete FMU with ``w = 0`` from one step out of each basis vector (a fresh
    initialisation for each: x0 = e_j, or u = e_j, or d = e_j)."""
    out = [np.zeros((n, n)), np.zeros((n, m)), np.zeros((n, q))]
    for which, size in enumerate((n, m, q)):
        for j in range(size):
            fmu.reset()
            e = np.zeros(size)
            e[j] = 1.0
            fmu.initialize(0.0, {"mismatch": [mismatch], "mismatch_seed": [seed],
                                 **({"x0": e} if which == 0 else {})})
            fmu.set("u", e if which == 1 else np.zeros(m))
            fmu.set("d", e if which == 2 else np.zeros(q))
            if mode is not None:
                fmu.set("mode", [mode])
            fmu.step(0.0, fmu_dt(fmu))
            out[which][:, j] = fmu.get("x")
    return tuple(out)


def fmu_dt(fmu) -> float:
    return float(fmu.description.defaultExperiment.stepSize)


@pytest.mark.parametrize("backend", BACKENDS)
def test_the_linear_plant_fmu_perturbs_to_the_runtimes_bits(tmp_path, backend):
    plant = discrete_plant()
    path = build_plant(plant, "mm", tmp_path / "p.fmu", backend=backend)
    rt = PlantRuntime(plant.to_data())
    rt.set_mismatch(0.04, 123)
    with Fmu(path, "plant") as fmu:
        got = columns(fmu, plant.n, plant.m, plant.q, 0.04, 123)
        design = columns(fmu, plant.n, plant.m, plant.q, 0.0, 123)
    for g, want, zero, exact in zip(got, (rt.A, rt.B, rt.E), design, (plant.A, plant.B, plant.E)):
        assert np.array_equal(g, want)                  # the runtime's perturbed matrices, bit for bit
        assert np.array_equal(zero, exact)              # mismatch 0: the design's
        assert not np.array_equal(g, exact)


@pytest.mark.parametrize("backend", BACKENDS)
def test_the_switched_plant_fmu_perturbs_every_mode_to_the_runtimes_bits(tmp_path, backend):
    plant = switched_plant()
    path = build_plant(plant, "sw", tmp_path / "p.fmu", backend=backend)
    rt = SwitchedPlantRuntime(plant.to_data())
    rt.set_mismatch(0.2, -77)
    with Fmu(path, "plant") as fmu:
        for mode in (1, 2):
            got = columns(fmu, 3, 1, 1, 0.2, -77, mode)
            for g, want in zip(got, rt.modes[mode - 1][:3]):
                assert np.array_equal(g, want)


# (c) ---------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("bad", [-0.01, math.nan, math.inf])
def test_a_bad_mismatch_is_refused_when_initialisation_ends(tmp_path, backend, bad):
    path = build_plant(discrete_plant(), "bad", tmp_path / "p.fmu", backend=backend)
    with Fmu(path, "plant") as fmu:
        with pytest.raises(FmuCallError) as info:
            fmu.initialize(0.0, {"mismatch": [bad]})
            fmu.step(0.0, 0.1)                       # the Python backend refuses to step after the logged error
        assert "mismatch" in " ".join(info.value.messages)


def test_the_runtime_refuses_an_overflowing_perturbation():
    rt = PlantRuntime({"time": "discrete", "dt": 1.0, "A": [[1e308]], "E": [[1.0]], "C": [[1.0]]})
    with pytest.raises(Exception, match="not finite"):
        rt.set_mismatch(1e10, 1)
    assert rt.A[0, 0] == 1e308 and rt.mismatch == 0.0     # nothing changed


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_restored_state_runs_the_perturbed_plant(tmp_path, backend):
    plant = discrete_plant()
    path = build_plant(plant, "st", tmp_path / "p.fmu", backend=backend)
    with Fmu(path, "a") as a, Fmu(path, "b") as b:
        a.initialize(0.0, {"mismatch": [0.05], "mismatch_seed": [4], "x0": [1.0, -1.0, 0.5]})
        b.initialize(0.0, {"x0": [1.0, -1.0, 0.5]})
        for f in (a, b):
            f.set("u", [0.3, -0.2])
            f.set("d", [0.1])
            f.step(0.0, 0.1)
        blob = a.serialize(a.get_state())
        a.step(0.1, 0.1)
        want = a.get("x")
        b.step(0.1, 0.1)
        assert not np.array_equal(b.get("x"), want)       # the design model goes elsewhere
        b.set_state(b.deserialize(blob))
        b.step(0.1, 0.1)
        assert np.array_equal(b.get("x"), want)


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_plant_with_feedthrough_and_process_noise_takes_the_mismatch(tmp_path, backend):
    """y = C x + D u + F d with A, B, E perturbed and W w_noise added: the feedthrough and W stay the design's,
    the FMU's y and x are the runtime's (to 1e-12, its sums in another order) and differ from the design
    model's x after a step."""
    rng = np.random.default_rng(8)
    n, m, q, p, r = 3, 2, 1, 2, 1
    plant = Plant.create(0.3 * rng.normal(size=(n, n)), rng.normal(size=(p, n)), rng.normal(size=(n, q)),
                         rng.normal(size=(n, m)), time="discrete", dt=0.1, x0=np.zeros(n),
                         W=rng.normal(size=(n, r)), D=rng.normal(size=(p, m)), F=rng.normal(size=(p, q)))
    path = build_plant(plant, "ft", tmp_path / "p.fmu", backend=backend)
    rt, design = PlantRuntime(plant.to_data()), PlantRuntime(plant.to_data())
    rt.set_mismatch(0.05, 11)
    x0, u, d, w = np.array([1.0, -0.5, 0.25]), np.array([0.3, -0.2]), np.array([0.7]), np.array([0.4])
    for runtime in (rt, design):
        runtime.x0 = x0
        runtime.reset()
        runtime.u[:], runtime.d[:], runtime.w_noise[:] = u, d, w
    with Fmu(path, "plant") as fmu:
        assert set(fmu.ports("input")) == {"u", "d", "w_noise"}
        fmu.initialize(0.0, {"mismatch": [0.05], "mismatch_seed": [11], "x0": x0})
        fmu.set("u", u)
        fmu.set("d", d)
        fmu.set("w_noise", w)
        np.testing.assert_allclose(fmu.get("y"), rt.y(), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(rt.y(), design.y(), rtol=1e-12, atol=1e-12)     # C, D, F unperturbed
        fmu.step(0.0, 0.1)
        rt.step(0.1)
        design.step(0.1)
        np.testing.assert_allclose(fmu.get("x"), rt.x, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(fmu.get("y"), rt.y(), rtol=1e-12, atol=1e-12)
        assert np.max(np.abs(fmu.get("x") - design.x)) > 1e-6                      # the perturbed A, B, E moved x


# (d) ---------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("backend", BACKENDS)
def test_the_plant_fmus_declare_the_parameters_last(tmp_path, backend):
    plant = discrete_plant()
    md = read_model_description(str(build_plant(plant, "md", tmp_path / "p.fmu", backend=backend)))
    variables = {v.name: v for v in md.modelVariables}
    names = list(variables)
    assert names[-2:] == ["mismatch[1]", "mismatch_seed[1]"]
    assert names.index("x[1]") == plant.n + plant.m + plant.q + plant.p      # the others where they were
    mm, seed = variables["mismatch[1]"], variables["mismatch_seed[1]"]
    assert (mm.causality, mm.type, float(mm.start)) == ("parameter", "Real", 0.0)
    assert (seed.causality, seed.type, int(seed.start)) == ("parameter", "Integer", 0)


def test_a_plant_without_matrices_has_no_mismatch():
    names = [port.name for port in plant_ports(2, 1, 1, 1, mismatch=False)]
    assert "mismatch" not in names and "mismatch_seed" not in names


# (e) the campaign axis ---------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def example1_fmus(example1_card, example1_path, tmp_path_factory):
    """Seed 000 Example 1: its observer and plant (C backend where there is a compiler)."""
    from uiofmu.fmu.export import build_observer
    from uiofmu.problem import load_problem

    d = tmp_path_factory.mktemp("mismatch_campaign")
    problem = load_problem(example1_path)
    backend = BACKENDS[-1]
    plant = build_plant(problem.plant, problem.name, d / "plant.fmu", step=problem.options.step, backend=backend)
    observer = build_observer(example1_card[0], d / "observer.fmu", backend=backend)
    return plant, observer, d


def test_a_campaign_along_plant_mismatch_draws_a_plant_per_row_and_replays_it(example1_fmus, tmp_path):
    """A grid of three mismatch levels, two rows each: every row its own seed; the design model (0) respects
    its bound, a mismatched plant settles above it and says it is a model mismatch; the summary gives the
    quantiles of the error floor, the figure its panel, and a row replays bit for bit."""
    from uiofmu.cosim.campaign import read_table

    plant, observer, _ = example1_fmus
    spec = tmp_path / "campaign.toml"
    spec.write_text(f'[campaign]\nobserver = "{observer}"\nplant = "{plant}"\nruns = 6\nseed = 2\ngrid = true\n'
                    't_end = 20.0\n[axes]\nsteps = "fixed:0.1"\nplant_mismatch = [0.0, 0.01, 0.2]\n')
    out = tmp_path / "out"
    res = run_cli("campaign", spec, "--out", out, "--workers", "1")
    assert res.code == 0, res.err
    table = read_table(out / "campaign.csv")
    assert len(table) == 6 and all(r["status"] == "ok" for r in table)
    assert {r["plant_mismatch"] for r in table} == {"0.0", "0.01", "0.2"}
    assert len({r["mismatch_seed"] for r in table}) == 6
    floor = {level: [float(r["error_floor"]) for r in table if r["plant_mismatch"] == level]
             for level in ("0.0", "0.01", "0.2")}
    assert all(r["bound_respected"] == "true" for r in table if r["plant_mismatch"] == "0.0")
    assert min(floor["0.2"]) > 1.2 * max(floor["0.0"])            # the slow observer's floor at 20 s is 0.16
    summary = json.loads((out / "summary.json").read_text())
    assert summary["quantiles"]["error_floor"]["count"] == 6
    assert summary["axes"]["plant_mismatch"]
    assert (out / "campaign.png").stat().st_size > 10_000
    row = next(i for i, r in enumerate(table) if r["plant_mismatch"] == "0.2")
    replay = run_cli("campaign", spec, "--out", out, "--replay", str(row))
    assert replay.code == 0, replay.err
    if table[row]["bound_respected"] == "false":
        assert "perturbed by a relative mismatch of 0.2" in replay.out
    assert f"{float(table[row]['final_error_norm']):.3g}" in replay.out


def test_a_mismatched_run_is_a_model_mismatch(example1_fmus):
    """The run's metrics name the mismatch; a violated bound is never put on round-off or the design model."""
    from uiofmu.cosim.master import cosimulate

    plant, observer, _ = example1_fmus
    result = cosimulate(plant, observer, np.full(200, 0.1), plant_parameters={"mismatch": [0.2], "mismatch_seed": [1]})
    m = result.metrics
    assert m["plant"]["mismatch"] == 0.2
    assert m["bound_respected"] is False and m["plant"]["is_design_model"] is False
    exact = cosimulate(plant, observer, np.full(200, 0.1))
    assert exact.metrics["bound_respected"] is True and "plant" not in exact.metrics
    assert m["error_floor"] > 5 * exact.metrics["error_floor"]


@pytest.mark.parametrize("axis, message", [
    ("-0.1", "a standard deviation is >= 0"),
    ('{kind = "normal", std = 0.1}', "a normal draw is not always"),
])
def test_bad_mismatch_axes_exit_2(example1_fmus, tmp_path, axis, message):
    plant, observer, _ = example1_fmus
    spec = tmp_path / "campaign.toml"
    spec.write_text(f'[campaign]\nobserver = "{observer}"\nplant = "{plant}"\nruns = 2\n[axes]\n'
                    f"plant_mismatch = {axis}\n")
    res = run_cli("campaign", spec, "--out", tmp_path / "out")
    assert res.code == 2 and message in res.err, res.err


def test_a_plant_without_matrices_refuses_the_mismatch_axis(tmp_path):
    """An LPV plant (seed 003) takes no mismatch: the campaign exits 2 before any run, saying which plants do."""
    from uiofmu import design, load_problem
    from uiofmu.fmu.export import build_observer

    problem = load_problem(EXAMPLES / "seed003_example.toml")
    plant = build_plant(problem.plant, problem.name, tmp_path / "plant.fmu", step=problem.options.step)
    observer = build_observer(design(problem), tmp_path / "observer.fmu")
    spec = tmp_path / "campaign.toml"
    spec.write_text(f'[campaign]\nobserver = "{observer}"\nplant = "{plant}"\nruns = 2\n[axes]\n'
                    "plant_mismatch = 0.01\n")
    res = run_cli("campaign", spec, "--out", tmp_path / "out")
    assert res.code == 2 and "axes.plant_mismatch: the plant FMU" in res.err and "LPV" in res.err, res.err
    assert res.err.count("\n") <= 2
