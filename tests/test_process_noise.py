"""Process noise through ``[plant] W``: the plant FMUs' input ``w_noise`` and ``cosim --noise w=STD[,SEED]``.

(a) A plant whose problem declares ``W`` has the input ``w_noise[1..r]`` (held over the step like ``d``;
a continuous plant samples it as it samples ``E``): on both backends a discrete plant's step adds
``W w_noise`` exactly, a continuous one equals the reference runtime; a plant without ``W`` has no such
input. Non-finite process noise is refused like any input.
(b) The master drives it with seeded white noise and measures the noise part of the error against a
noise-free twin of the whole loop (a second plant without the noise, a second observer fed by it):
``noise_gain_w_measured = ||e - e_twin||_2 / ||w||_2`` is at most the card's certified ``noise.gain_w``.
(c) Without ``W`` the command exits 2 naming the key; the campaign axis ``noise_w`` measures every row.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import EXAMPLES, run_cli
from uiofmu import design, load_problem
from uiofmu.cosim.fmi import Fmu, FmuCallError
from uiofmu.cosim.master import cosimulate
from uiofmu.cosim.noise import Noise
from uiofmu.fmu.c_backend import c_compiler
from uiofmu.fmu.export import build_observer, build_plant
from uiofmu.plant import Plant
from uiofmu.problem import problem_from_data
from uiofmu.runtime.plant_runtime import PlantRuntime

BACKENDS = ["python"] + (["c"] if c_compiler() is not None else [])


def example1_with_w() -> dict:
    doc = load_problem(EXAMPLES / "seed000_example1.toml").data
    doc = json.loads(json.dumps(doc))
    n = len(doc["plant"]["A"])
    doc["plant"]["W"] = [[1.0 if i == 0 else 0.5] for i in range(n)]
    return doc


@pytest.fixture(scope="module")
def noisy_loop(tmp_path_factory):
    """Seed 000 Example 1 with ``W`` declared: its card (certifying gain_w), and its plant and observer FMUs."""
    d = tmp_path_factory.mktemp("process_noise")
    problem = problem_from_data(example1_with_w())
    card = design(problem)
    card.write(d / "card.json")
    fmus = {}
    for backend in BACKENDS:
        fmus[backend] = (build_plant(problem.plant, problem.name, d / f"plant-{backend}.fmu",
                                     step=problem.options.step, backend=backend),
                         build_observer(card, d / f"obs-{backend}.fmu", backend=backend))
    return problem, card, fmus, d


# (a) ---------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("backend", BACKENDS)
def test_a_discrete_plant_adds_w_times_the_noise(noisy_loop, backend):
    problem, _, fmus, _ = noisy_loop
    plant = problem.plant
    W = np.asarray(plant.W)
    with Fmu(fmus[backend][0], "plant") as fmu:
        assert fmu.ports("input")["w_noise"] == W.shape[1]
        fmu.initialize(0.0, {"x0": np.zeros(plant.n)})
        fmu.set("u", np.zeros(plant.m))
        fmu.set("d", np.zeros(plant.q))
        fmu.set("w_noise", [2.0])
        fmu.step(0.0, plant.dt)
        x1 = fmu.get("x")
        np.testing.assert_array_equal(x1, 2.0 * W[:, 0] + np.asarray(plant.w))
        fmu.set("w_noise", [float("nan")])
        with pytest.raises(FmuCallError) as info:
            fmu.step(plant.dt, plant.dt)
        assert "w_noise[1]" in " ".join(info.value.messages)
        np.testing.assert_array_equal(fmu.get("x"), x1)                  # nothing changed


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_continuous_plant_samples_the_noise_as_it_samples_e(tmp_path, backend):
    rng = np.random.default_rng(4)
    n = 3
    plant = Plant.create(rng.normal(size=(n, n)) / 2 - 0.5 * np.eye(n), rng.normal(size=(2, n)),
                         rng.normal(size=(n, 1)), rng.normal(size=(n, 1)), time="continuous",
                         x0=rng.normal(size=n), W=rng.normal(size=(n, 2)))
    path = build_plant(plant, "cw", tmp_path / "p.fmu", backend=backend)
    rt = PlantRuntime(plant.to_data())
    steps = [0.1, 0.25, 0.1, 0.4]
    with Fmu(path, "plant") as fmu:
        fmu.initialize(0.0)
        t = 0.0
        for k, h in enumerate(steps):
            w = rng.normal(size=2)
            fmu.set("u", [0.3])
            fmu.set("d", [-0.2])
            fmu.set("w_noise", w)
            rt.u[:], rt.d[:], rt.w_noise[:] = [0.3], [-0.2], w
            fmu.step(t, h)
            rt.step(h)
            t += h
            np.testing.assert_allclose(fmu.get("x"), rt.x, rtol=1e-12, atol=1e-14)
    # the sampled W of the design, as the plant steps it: x from 0 under w alone is W_sampled w
    rt = PlantRuntime(plant.to_data())
    rt.x[:] = 0.0
    rt.w_noise[:] = [1.0, 0.0]
    rt.step(0.1)
    np.testing.assert_allclose(rt.x, plant.sampled_noise(0.1)[:, 0], rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("backend", BACKENDS)
def test_the_fmu_state_carries_the_process_noise(noisy_loop, backend):
    """An instance restored from another's state steps with that state's w_noise (never set on it)."""
    problem, _, fmus, _ = noisy_loop
    plant = problem.plant
    with Fmu(fmus[backend][0], "a") as a, Fmu(fmus[backend][0], "b") as b:
        for f in (a, b):
            f.initialize(0.0, {"x0": np.ones(plant.n)})
            f.set("u", np.zeros(plant.m))
            f.set("d", np.zeros(plant.q))
        a.set("w_noise", [0.7])
        blob = a.serialize(a.get_state())
        a.step(0.0, plant.dt)
        b.set_state(b.deserialize(blob))
        b.step(0.0, plant.dt)
        np.testing.assert_array_equal(b.get("x"), a.get("x"))
        np.testing.assert_array_equal(b.get("w_noise"), [0.7])


def test_a_plant_without_w_has_no_process_noise_input(tmp_path):
    problem = load_problem(EXAMPLES / "seed000_example1.toml")
    path = build_plant(problem.plant, problem.name, tmp_path / "p.fmu", step=problem.options.step,
                       backend=BACKENDS[-1])
    with Fmu(path, "plant") as fmu:
        assert "w_noise" not in fmu.ports("input")


# (b) ---------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("backend", BACKENDS)
def test_process_noise_is_measured_against_a_noise_free_twin_loop(noisy_loop, backend, cli):
    _, card, fmus, d = noisy_loop
    gain_w = card.data["noise"]["gain_w"]
    assert gain_w is not None and gain_w > 0
    plant, obs = fmus[backend]
    run = d / f"run-{backend}"
    res = cli("cosim", "--plant", plant, "--observer", obs, "--steps", "fixed:0.1", "--t-end", "60",
              "--noise", "w=0.05,3", "--out", run)
    assert res.code == 0, res.err
    m = json.loads((run / "metrics.json").read_text())
    assert m["noise_gain_w_certified"] == gain_w
    assert 0 < m["noise_gain_w_measured"] <= gain_w and m["noise_gain_w_respected"] is True
    assert m["noise"]["w"]["std"] == [0.05] and m["noise"]["w"]["seed"] == 3
    assert m["bound_respected"] is True                               # the twin loop is noise-free
    assert "process noise gain" in res.out and "respected" in res.out
    # the same run through the API: the noise part of the error is not zero, and the twin's error is the
    # noise-free run's own
    steps = np.full(600, 0.1)
    noisy = cosimulate(plant, obs, steps, noise=Noise("w", (0.05,), 3))
    clean = cosimulate(plant, obs, steps)
    np.testing.assert_array_equal(noisy.xhat, clean.xhat)
    np.testing.assert_array_equal(noisy.x, clean.x)
    assert noisy.metrics["noise_gain_w_measured"] == m["noise_gain_w_measured"]


@pytest.mark.skipif("c" not in BACKENDS, reason="no C compiler: no C FMUs for the native loop")
def test_the_native_loop_steps_the_twin_plant_as_the_python_loop(noisy_loop):
    """With C FMUs the four of a process-noise run (plant, observer, twin observer, twin plant) are stepped by
    the C driver, to the same bits as the Python loop: histories, the noise's arrays and every metric."""
    _, _, fmus, _ = noisy_loop
    plant, obs = fmus["c"]
    steps = np.full(300, 0.1)
    python = cosimulate(plant, obs, steps, noise="w=0.05,3", show_progress=False, native=False)
    c = cosimulate(plant, obs, steps, noise="w=0.05,3", show_progress=False)
    assert c.timing["native"] is True and python.timing["native"] is False
    for name in ("x", "xhat", "y", "r"):
        assert getattr(c, name).tobytes() == getattr(python, name).tobytes(), name
    for key in ("w", "error", "twin_error"):
        assert c.noise_w[key].tobytes() == python.noise_w[key].tobytes(), key
    assert np.linalg.norm(c.noise_w["error"] - c.noise_w["twin_error"]) > 0
    assert json.dumps(c.metrics, sort_keys=True) == json.dumps(python.metrics, sort_keys=True)


def test_a_card_claiming_too_small_a_process_noise_gain_is_caught(noisy_loop):
    """The measured gain against a certified one a tenth of the card's: the comparison can fail."""
    from uiofmu.cosim.noise import process_noise_metrics

    _, card, fmus, _ = noisy_loop
    plant, obs = fmus[BACKENDS[-1]]
    result = cosimulate(plant, obs, np.full(600, 0.1), noise="w=0.05,3")
    e, e_twin, w = result.noise_w["error"], result.noise_w["twin_error"], result.noise_w["w"]
    honest = process_noise_metrics(card.data["noise"]["gain_w"], e, e_twin, w)
    low = process_noise_metrics(0.5 * honest["noise_gain_w_measured"], e, e_twin, w)
    assert honest["noise_gain_w_respected"] is True and low["noise_gain_w_respected"] is False
    assert low["noise_gain_w_ratio"] == pytest.approx(2.0)
    assert np.linalg.norm(e - e_twin) > 0


# (c) ---------------------------------------------------------------------------------------------------

def test_process_noise_without_w_exits_2_naming_the_key(tmp_path, example1_card, example1_path, cli):
    problem = load_problem(example1_path)
    plant = build_plant(problem.plant, problem.name, tmp_path / "p.fmu", step=problem.options.step)
    obs = build_observer(example1_card[0], tmp_path / "o.fmu")
    res = cli("cosim", "--plant", plant, "--observer", obs, "--steps", "fixed:0.1", "--t-end", "5",
              "--noise", "w=0.1", "--out", tmp_path / "run")
    assert res.code == 2 and "[plant] W" in res.err, res.err


def test_a_campaign_along_noise_w_measures_every_row(noisy_loop, tmp_path):
    from uiofmu.cosim.campaign import read_table

    _, _, fmus, _ = noisy_loop
    plant, obs = fmus[BACKENDS[-1]]
    spec = tmp_path / "campaign.toml"
    spec.write_text(f'[campaign]\nobserver = "{obs}"\nplant = "{plant}"\nruns = 6\nseed = 4\ngrid = true\n'
                    't_end = 20.0\n[axes]\nsteps = "fixed:0.1"\nnoise_w = [0.0, 0.01, 0.1]\n')
    out = tmp_path / "out"
    res = run_cli("campaign", spec, "--out", out, "--workers", "1")
    assert res.code == 0, res.err
    table = read_table(out / "campaign.csv")
    assert len(table) == 6 and all(r["status"] == "ok" for r in table)
    assert len({r["noise_w_seed"] for r in table}) == 6
    noisy = [r for r in table if float(r["noise_w[1]"]) > 0]
    assert len(noisy) == 4 and all(r["noise_gain_w_respected"] == "true" for r in noisy)
    assert all(r["noise_gain_w_measured"] == "" for r in table if float(r["noise_w[1]"]) == 0)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["noise_gain_violations"] == 0
    assert summary["quantiles"]["noise_gain_w_measured"]["count"] == 4
    # a plant without W: exit 2 before any run, naming the key
    problem = load_problem(EXAMPLES / "seed000_example1.toml")
    bare = build_plant(problem.plant, problem.name, tmp_path / "bare.fmu", step=problem.options.step)
    spec.write_text(f'[campaign]\nobserver = "{obs}"\nplant = "{bare}"\nruns = 2\n[axes]\nnoise_w = 0.1\n')
    res = run_cli("campaign", spec, "--out", tmp_path / "out2")
    assert res.code == 2 and "axes.noise_w" in res.err and "[plant] W" in res.err, res.err
