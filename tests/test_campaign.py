"""``uiofmu campaign``: many co-simulations on Dask, the worst case, replay, failures, a remote scheduler."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from conftest import run_cli

pytest.importorskip("distributed")

T_END = 20.0   # 200 steps of seed 000 Example 1


@pytest.fixture(scope="module")
def fmus(example1_card, example1_path, tmp_path_factory):
    """Observer and plant FMUs of seed 000 Example 1 (default backend)."""
    from uiofmu.fmu.export import build_observer, build_plant
    from uiofmu.problem import load_problem

    card, _ = example1_card
    folder = tmp_path_factory.mktemp("campaign_fmus")
    problem = load_problem(example1_path)
    observer = build_observer(card, folder / "observer.fmu")
    plant = build_plant(problem.plant, problem.name, folder / "plant.fmu", step=problem.options.step)
    return plant, observer, card


def campaign_file(folder, fmus, runs=60, steps='["fixed:0.1", "fixed:0.1", "fixed:0.15"]', extra="") -> str:
    plant, observer, _ = fmus
    path = folder / "campaign.toml"
    path.write_text(f'[campaign]\nobserver = "{observer}"\nplant = "{plant}"\nruns = {runs}\nseed = 5\n'
                    f"t_end = {T_END}\n{extra}\n[axes]\nsteps = {steps}\n"
                    'xhat0_error = {kind = "normal", std = 2.0}\n'
                    'd_scale = {kind = "uniform", low = 0.5, high = 1.5}\n'
                    'plant_parameters = {x0 = {kind = "normal", mean = 1.0, std = 0.5}}\n')
    return str(path)


@pytest.fixture(scope="module")
def campaign_run(fmus, tmp_path_factory):
    """One campaign of 60 runs on a LocalCluster of 2 workers (a third of them on a step the FMUs refuse)."""
    folder = tmp_path_factory.mktemp("campaign")
    spec = campaign_file(folder, fmus)
    out = folder / "out"
    result = run_cli("campaign", spec, "--out", out, "--workers", "2")
    assert result.code == 0, result.err
    return spec, out, result


def test_worst_case_equals_the_runs_one_by_one(campaign_run, fmus):
    from uiofmu.cosim.campaign import load_campaign, prepare, read_table, scaled_inputs, scenario
    from uiofmu.cosim.master import cosimulate, default_inputs
    from uiofmu.cosim.steps import step_sequence
    from uiofmu.runtime.errors import FmuError

    spec, out, _ = campaign_run
    plant, observer, card = fmus
    summary = json.loads((out / "summary.json").read_text())
    table = read_table(out / "campaign.csv")
    assert summary["runs"] == summary["finished"] == len(table) == 60
    assert (out / "campaign.png").stat().st_size > 10_000

    campaign = load_campaign(spec)
    setup = prepare(campaign)
    base, xhat0 = default_inputs(card), np.asarray(card.data["initial"]["xhat0"])
    ratios, refused = {}, set()
    for row in range(campaign.runs):
        sc = scenario(campaign, setup, row)
        steps = step_sequence(sc["steps"], T_END, seed=sc["steps_seed"])
        try:
            result = cosimulate(plant, observer, steps, scaled_inputs(base, sc["d_scale"]),
                                xhat0=xhat0 + sc["xhat0_error"], plant_parameters={"x0": sc["plant.x0"]},
                                show_progress=False)
        except FmuError:
            refused.add(row)
            continue
        ratios[row] = result.metrics["max_bound_ratio"]
        assert table[row]["max_bound_ratio"] == repr(ratios[row])
    worst = max(ratios, key=ratios.get)
    assert summary["worst_max_bound_ratio"]["row"] == worst
    assert summary["worst_max_bound_ratio"]["value"] == ratios[worst]
    assert summary["worst_max_bound_ratio"]["scenario"] == scenario(campaign, setup, worst)
    assert summary["ok"] == len(ratios) and summary["failures"] == len(refused) > 0
    quant = summary["quantiles"]["max_bound_ratio"]
    assert quant["q100"] == ratios[worst] and quant["q00"] == min(ratios.values())


def test_a_refused_step_is_recorded_and_the_campaign_goes_on(campaign_run):
    from uiofmu.cosim.campaign import read_table

    _, out, result = campaign_run
    table = read_table(out / "campaign.csv")
    failed = [r for r in table if r["status"] != "ok"]
    assert failed and all(r["steps"] == "fixed:0.15" and r["status"] == "failed" for r in failed)
    assert all("refused step 0" in r["reason"] and "h = 0.15 s" in r["reason"] for r in failed)
    assert all(r["status"] == "ok" for r in table if r["steps"] == "fixed:0.1")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["failure_reasons"][0]["count"] == len(failed)
    assert "failure(s)" in result.out


def test_replay_reproduces_a_row_bit_for_bit(campaign_run):
    from uiofmu.cosim.campaign import read_table

    spec, out, _ = campaign_run
    table = read_table(out / "campaign.csv")
    row = next(int(r["row"]) for r in table if r["status"] == "ok")
    result = run_cli("campaign", spec, "--out", out, "--replay", str(row))
    assert result.code == 0, result.err
    assert "reproduced bit for bit" in result.out
    metrics = json.loads((out / f"row-{row}" / "metrics.json").read_text())
    for key in ("max_bound_ratio", "final_error_norm", "initial_error_norm", "error_floor"):
        assert repr(metrics[key]) == table[row][key]
    scenario = json.loads((out / f"row-{row}" / "scenario.json").read_text())
    assert repr(scenario["d_scale"]) == table[row]["d_scale"]
    failed = next(int(r["row"]) for r in table if r["status"] != "ok")
    result = run_cli("campaign", spec, "--out", out, "--replay", str(failed))
    assert result.code == 0 and "failed" in result.out and "reproduced bit for bit" in result.out
    assert run_cli("campaign", spec, "--out", out, "--replay", "60").code == 2


def test_the_same_file_runs_on_a_scheduler_by_its_address(campaign_run, tmp_path):
    """A LocalCluster in its own processes, reached only by its scheduler address: the same table."""
    from uiofmu.cosim.campaign import read_table

    spec, out, _ = campaign_run
    code = ("import sys, time\nfrom distributed import LocalCluster\n"
            "c = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)\n"
            "print(c.scheduler_address, flush=True)\nwhile True: time.sleep(1)\n")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                            text=True, cwd=tmp_path, start_new_session=True)
    try:
        address = proc.stdout.readline().strip()
        assert address.startswith("tcp://"), address
        remote = tmp_path / "remote"
        result = run_cli("campaign", spec, "--out", remote, "--scheduler", address)
        assert result.code == 0, result.err
        assert "scheduler tcp://" in result.out
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=30)
    strip = lambda rows: [{k: v for k, v in r.items() if k != "wall_s"} for r in rows]  # noqa: E731
    assert strip(read_table(remote / "campaign.csv")) == strip(read_table(out / "campaign.csv"))


def test_a_grid_enumerates_every_combination(fmus, tmp_path):
    from uiofmu.cosim.campaign import load_campaign, prepare, scenario

    spec = campaign_file(tmp_path, fmus, runs=12, steps='["fixed:0.1", "choice:0.1"]', extra="grid = true")
    text = open(spec).read().replace('{kind = "uniform", low = 0.5, high = 1.5}', "[0.5, 1.0, 1.5]")
    open(spec, "w").write(text)
    campaign = load_campaign(spec)
    setup = prepare(campaign)
    assert campaign.grid_size() == 6
    points = [(s["steps"], s["d_scale"]) for s in (scenario(campaign, setup, r) for r in range(12))]
    assert sorted(set(points)) == sorted((a, b) for a in ("fixed:0.1", "choice:0.1") for b in (0.5, 1.0, 1.5))
    assert points[:6] == points[6:]
    assert scenario(campaign, setup, 7) == scenario(campaign, setup, 7)
    assert scenario(campaign, setup, 7)["xhat0_error"] != scenario(campaign, setup, 1)["xhat0_error"]


BAD = [
    ("[campaign]\nrunz = 3", "campaign.runz: unknown key"),
    ("[campaign]\nruns = 3", "campaign.problem: required key is missing"),
    ("[campaign]\nproblem = 'p.toml'\nobserver = 'o.fmu'\nruns = 3", "campaign.problem: give either"),
    ("[campaign]\nproblem = 'p.toml'\nruns = 0", "campaign.runs: expected an integer in [1"),
    ("[campaign]\nproblem = 'p.toml'\nruns = 2.5", "campaign.runs: expected an integer"),
    ("[campaign]\nproblem = 'p.toml'", "campaign.runs: required key is missing"),
    ("[campaign]\nproblem = 'p.toml'\nruns = 3\nseed = -1", "campaign.seed"),
    ("[campaign]\nproblem = 'p.toml'\nruns = 3\nt_end = -1.0", "campaign.t_end"),
    ("[campaign]\nproblem = 'p.toml'\nruns = 3\ngrid = 'yes'", "campaign.grid"),
    ("[campaign]\nproblem = 'p.toml'\nruns = 3\n[axes]\nsteps = ['wobble:3']", "axes.steps[0]: unknown kind"),
    ("[campaign]\nproblem = 'p.toml'\nruns = 3\n[axes]\nsteps = []", "axes.steps: expected"),
    ("[campaign]\nproblem = 'p.toml'\nruns = 3\n[axes]\nd_scale = {kind = 'gamma'}", "axes.d_scale.kind"),
    ("[campaign]\nproblem = 'p.toml'\nruns = 3\n[axes]\nd_scale = {kind = 'uniform', low = 2.0, high = 1.0}",
     "axes.d_scale: low = 2 > high = 1"),
    ("[campaign]\nproblem = 'p.toml'\nruns = 3\n[axes]\nxhat0_error = {kind = 'normal', std = -1.0}",
     "axes.xhat0_error.std"),
    ("[campaign]\nproblem = 'p.toml'\nruns = 3\n[axes]\nxhat0_error = {kind = 'normal', sd = 1.0}",
     "axes.xhat0_error.std: required key is missing"),
    ("[campaign]\nproblem = 'p.toml'\nruns = 3\n[axes]\nxhat0_error = 'big'", "axes.xhat0_error: expected"),
    ("[campaign]\nproblem = 'p.toml'\nruns = 3\n[axes]\nseeds = [1]", "axes.seeds: unknown key"),
    ("[campaign]\nproblem = 'p.toml'\nruns = 4\ngrid = true\n[axes]\nsteps = ['fixed:1', 'fixed:2', 'fixed:3']",
     "campaign.runs: with grid = true, a multiple"),
    ("[campaign\n", "TOML"),
]


@pytest.mark.parametrize("text, message", BAD, ids=[m.split(":")[0] + f"-{i}" for i, (_, m) in enumerate(BAD)])
def test_bad_campaign_files_exit_2_naming_the_key(tmp_path, text, message):
    spec = tmp_path / "bad.toml"
    spec.write_text(text)
    result = run_cli("campaign", spec, "--out", tmp_path / "out")
    assert result.code == 2, result.err
    assert message in result.err and "Traceback" not in result.err
    assert result.err.count("\n") == 1


@pytest.mark.parametrize("axes, message", [
    ("plant_parameters = {gain = 1.0}", "axes.plant_parameters.gain: the plant FMU has no parameter gain"),
    ("plant_parameters = {x0 = [[1.0, 2.0, 3.0]]}", "axes.plant_parameters.x0[0]: expected 2 value(s)"),
    ("xhat0_error = {kind = 'constant', value = [1.0]}", "axes.xhat0_error: expected 2 value(s)"),
])
def test_axes_the_fmus_cannot_take_exit_2(fmus, tmp_path, axes, message):
    plant, observer, _ = fmus
    spec = tmp_path / "bad.toml"
    spec.write_text(f'[campaign]\nobserver = "{observer}"\nplant = "{plant}"\nruns = 3\n[axes]\n{axes}\n')
    t0 = time.perf_counter()
    result = run_cli("campaign", spec, "--out", tmp_path / "out")
    assert result.code == 2 and message in result.err, result.err
    assert time.perf_counter() - t0 < 10     # refused before any cluster starts
