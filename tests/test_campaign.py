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

from conftest import EXAMPLES, run_cli

from uiofmu.runtime.errors import ProblemError

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


@pytest.fixture(scope="module")
def counting_fmus(tmp_path_factory):
    """The ltv-auid observer of seed 000 Example 1 with step_policy = "count" (it takes a step of any length)
    and the same discrete plant (it takes steps of its dt = 0.1 s only): runs on other steps fail in the plant."""
    from uiofmu import design, load_problem
    from uiofmu.fmu.export import build_observer, build_plant

    folder = tmp_path_factory.mktemp("counting_fmus")
    text = (EXAMPLES / "seed000_example1_ltv.toml").read_text().replace("mu = 90.0", 'mu = 90.0\nstep_policy = "count"')
    (folder / "problem.toml").write_text(text)
    problem = load_problem(folder / "problem.toml")
    card = design(problem)
    observer = build_observer(card, folder / "observer.fmu")
    plant = build_plant(problem.plant, problem.name, folder / "plant.fmu", step=problem.options.step)
    return plant, observer, card


def campaign_file(folder, fmus, runs=60, steps='["fixed:0.1", "choice:0.1"]', extra="") -> str:
    plant, observer, _ = fmus
    path = folder / "campaign.toml"
    path.write_text(f'[campaign]\nobserver = "{observer}"\nplant = "{plant}"\nruns = {runs}\nseed = 5\n'
                    f"t_end = {T_END}\n{extra}\n[axes]\nsteps = {steps}\n"
                    'xhat0_error = {kind = "normal", std = 2.0}\n'
                    'd_scale = {kind = "uniform", low = 0.5, high = 1.5}\n'
                    'plant_parameters = {x0 = {kind = "normal", mean = 1.0, std = 0.5}}\n')
    return str(path)


FAILING_STEPS = "uniform:0.12:0.2"


@pytest.fixture(scope="module")
def campaign_run(counting_fmus, tmp_path_factory):
    """One campaign of 60 runs on a LocalCluster of 2 workers (a third of them on steps the plant refuses)."""
    folder = tmp_path_factory.mktemp("campaign")
    spec = campaign_file(folder, counting_fmus, steps=f'["fixed:0.1", "fixed:0.1", "{FAILING_STEPS}"]')
    out = folder / "out"
    result = run_cli("campaign", spec, "--out", out, "--workers", "2")
    assert result.code == 0, result.err
    return spec, out, result


def test_worst_case_equals_the_runs_one_by_one(campaign_run, counting_fmus):
    from uiofmu.cosim.campaign import load_campaign, prepare, read_table, scaled_inputs, scenario
    from uiofmu.cosim.master import cosimulate, default_inputs
    from uiofmu.cosim.steps import step_sequence
    from uiofmu.runtime.errors import FmuError

    spec, out, _ = campaign_run
    plant, observer, card = counting_fmus
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
    assert failed and all(r["steps"] == FAILING_STEPS and r["status"] == "failed" for r in failed)
    assert all("plant FMU refused step 0" in r["reason"] for r in failed)
    assert len({r["reason"] for r in failed}) == len(failed) > 1      # each run its own step h
    assert all(r["status"] == "ok" for r in table if r["steps"] == "fixed:0.1")
    summary = json.loads((out / "summary.json").read_text())
    [kind] = summary["failure_reasons"]                                 # one kind of failure
    assert kind["count"] == len(failed) and kind["status"] == "failed"
    assert kind["kind"] == ("the plant FMU refused step # (t = # s, h = # s): t = #: this discrete plant steps "
                            "at dt = # s and received h = # s")
    assert kind["rows"] == [int(r["row"]) for r in failed][:20]
    assert kind["example"] == failed[0]["reason"]
    assert f"{len(failed):>6} x failed   {kind['kind']}" in result.out
    assert f"e.g. row {failed[0]['row']}: {failed[0]['reason'][:160]}" in result.out


def test_every_run_at_the_bound_start_is_said_instead_of_a_row(campaign_run):
    """The ratio is measured from k = 1 on (at k = 0 it is 1 / overshoot by construction); the summary says
    whether every run is nearest its bound at k = 1, and then names no row."""
    from uiofmu.cosim.campaign import read_table

    _, out, result = campaign_run
    table = [r for r in read_table(out / "campaign.csv") if r["status"] == "ok"]
    worst = json.loads((out / "summary.json").read_text())["worst_max_bound_ratio"]
    steps = {int(r["max_bound_ratio_step"]) for r in table}
    assert min(steps) >= 1 and worst["step"] == int(table[[float(r["max_bound_ratio"]) for r in table].index(
        worst["value"])]["max_bound_ratio_step"])
    assert worst["every_run_at_bound_start"] == (steps == {1})
    line = next(line for line in result.out.splitlines() if "worst bound ratio" in line)
    if worst["every_run_at_bound_start"]:
        assert "every run nearest its bound at k = 1 (the bound's start" in line and "row" not in line, line
    else:
        assert f"row {worst['row']} at k = {worst['step']}" in line, line


def test_failure_reasons_are_grouped_by_kind():
    from uiofmu.cosim.campaign import Tally, reason_kind

    assert reason_kind("step 12 (t = 1.2 s, h = -1.5e-3 s) x[2] fmi2Discard dt = 0.1.") == \
        "step # (t = # s, h = # s) x[#] fmi2Discard dt = #."
    tally = Tally()
    reasons = [("failed", "refused step 3 (h = 0.13 s)"), ("failed", "refused step 7 (h = 0.1875 s)"),
               ("crashed", "refused step 4 (h = 0.5 s)"), ("failed", "y[1] is not finite")]
    for row, (status, reason) in enumerate(reasons):
        tally.add(row, {"status": status, "reason": reason})
    groups = sorted(tally.reasons.values(), key=lambda e: -e["count"])
    assert [(g["status"], g["kind"], g["count"], g["rows"], g["example"]) for g in groups] == [
        ("failed", "refused step # (h = # s)", 2, [0, 1], "refused step 3 (h = 0.13 s)"),
        ("crashed", "refused step # (h = # s)", 1, [2], "refused step 4 (h = 0.5 s)"),
        ("failed", "y[#] is not finite", 1, [3], "y[1] is not finite")]


STEPS_REFUSED = [
    ('["fixed:0.1", "uniform:0.05:0.2"]', "axes.steps[1] = 'uniform:0.05:0.2': steps from 0.05 to 0.2 s"),
    ('"fixed:0.15"', "axes.steps[0] = 'fixed:0.15': a step of 0.15 s"),
    ('["choice:0.1,0.10000005,0.1001"]', "axes.steps[0] = 'choice:0.1,0.10000005,0.1001': a step of 0.1001 s"),
    ('["dropout:0.1:0.3:2"]', "axes.steps[0] = 'dropout:0.1:0.3:2': a step of 0.2 s"),
]


@pytest.mark.parametrize("steps, message", STEPS_REFUSED)
def test_steps_the_observer_cannot_take_exit_2_before_any_run(fmus, tmp_path, steps, message):
    """A step SPEC that can give a step the observer refuses is refused at once, with its steps."""
    result = run_cli("campaign", campaign_file(tmp_path, fmus, steps=steps), "--out", tmp_path / "out")
    assert result.code == 2 and result.err.count("\n") == 1, result.err
    assert message in result.err and "the observer takes only its design period, 0.1 s (within 1e-06 relative; " \
        "schedule.step_policy = 'error'); e.g. fixed:0.1" in result.err, result.err
    assert "worker" not in result.out and not (tmp_path / "out" / "campaign.csv").exists()


def test_steps_the_observer_takes_pass_the_check(fmus, counting_fmus, tmp_path):
    from uiofmu.cosim.campaign import check_steps_axis

    (tmp_path / "steps.txt").write_text("0.1\n0.10000001\n# a comment\n0.3\n")
    taken = ["fixed:0.1", "choice:0.1,0.10000001", "dropout:0.1:0:5", "uniform:0.1:0.10000005",
             f"file:{tmp_path / 'steps.txt'}"]
    check_steps_axis(taken[:-1], fmus[2], 20.0)
    check_steps_axis(taken[-1:], fmus[2], 0.2)         # the line 0.3 lies past t_end
    with pytest.raises(ProblemError, match="a step of 0.3 s"):
        check_steps_axis(taken[-1:], fmus[2], 0.25)
    check_steps_axis(["uniform:0.01:5", "dropout:0.1:0.9:100"], counting_fmus[2], 20.0)   # step_policy count
    with pytest.raises(ProblemError) as info:                  # a long SPEC is shown by its start and length
        check_steps_axis(["choice:" + ",".join(["0.2"] * 100_000)], fmus[2], 20.0)
    assert "axes.steps[0] = 'choice:0.2,0.2" in str(info.value) and "(400006 characters)" in str(info.value)
    assert len(str(info.value)) < 400


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


# --------------------------------------------------------------------------------------------
# a campaign of any size starts at once, in bounded memory
# --------------------------------------------------------------------------------------------
def test_scenarios_are_made_as_they_are_asked_for(fmus, tmp_path):
    """The scenario iterator of 10,000,000 runs builds only what is asked, the same rows as scenario(); a batch is
    its rows' indices."""
    import tracemalloc
    from itertools import islice

    from uiofmu.cosim.campaign import batches, load_campaign, prepare, scenario, scenarios

    campaign = load_campaign(campaign_file(tmp_path, fmus, runs=10_000_000))
    setup = prepare(campaign)
    tracemalloc.start()
    try:
        t0 = time.perf_counter()
        first = list(islice(scenarios(campaign, setup), 1000))
        batch = next(batches(campaign, 64))
        elapsed = time.perf_counter() - t0
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert elapsed < 2.0 and peak < 5_000_000, (elapsed, peak)
    assert first == [scenario(campaign, setup, r) for r in range(1000)] and batch == range(64)
    assert list(scenarios(campaign, setup, start=9_999_999)) == [scenario(campaign, setup, 9_999_999)]


def _rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS")) / 1024


def test_a_huge_campaign_gives_rows_at_once_and_keeps_them_when_interrupted(fmus, tmp_path):
    """runs = 10,000,000: rows reach the disk within seconds in a small process; Ctrl-C writes all outputs.
    The interrupt reaches the whole process group, as a terminal's Ctrl-C does: the workers ignore it and
    print nothing, the command ends with one line."""
    from uiofmu.cosim.campaign import read_table

    spec = campaign_file(tmp_path, fmus, runs=10_000_000)
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "uiofmu", "campaign", spec, "--out", str(out), "--workers", "1"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path,
                            start_new_session=True)
    try:
        t0, rows = time.perf_counter(), 0
        while time.perf_counter() - t0 < 60 and proc.poll() is None and rows == 0:
            time.sleep(0.2)
            rows = sum(p.stat().st_size for p in out.glob("campaign.partial-*/rows.part"))
        first_rows_s, rss = time.perf_counter() - t0, _rss_mb(proc.pid)
        assert rows > 0, f"no row after {first_rows_s:.0f} s"
        time.sleep(1.0)
        assert _rss_mb(proc.pid) < rss + 50 and rss < 400, (rss, _rss_mb(proc.pid))
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    summary = json.loads((out / "summary.json").read_text())
    table = [int(r["row"]) for r in read_table(out / "campaign.csv")]
    assert summary["cancelled"] and summary["runs"] == 10_000_000 and summary["finished"] == len(table) > 0
    assert table == sorted(set(table)) and (out / "campaign.png").stat().st_size > 10_000
    assert not list(out.glob("campaign.partial-*"))


# --------------------------------------------------------------------------------------------
# --scheduler: checked addresses, and a deadline on the scheduler's answer
# --------------------------------------------------------------------------------------------
def run_cli_within(seconds: float, *argv):
    """``run_cli`` in a thread: its result, or None when it has not returned within ``seconds``."""
    import threading

    box = {}
    thread = threading.Thread(target=lambda: box.update(result=run_cli(*argv)), daemon=True)
    thread.start()
    thread.join(seconds)
    return box.get("result")


@pytest.fixture
def fake_service():
    """A TCP server on 127.0.0.1 that accepts connections and, by its mode, never answers or answers
    HTTP; yields a function of the mode giving the server's tcp:// address."""
    import socket
    import threading

    servers = []

    def serve(server, mode):
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            servers.append(conn)
            if mode == "http":
                conn.recv(65536)
                conn.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 11\r\n\r\nbad request" * 4)

    def start(mode: str) -> str:
        server = socket.socket()
        server.bind(("127.0.0.1", 0))
        server.listen(8)
        servers.append(server)
        threading.Thread(target=serve, args=(server, mode), daemon=True).start()
        return f"tcp://127.0.0.1:{server.getsockname()[1]}"

    yield start
    for s in servers:
        s.close()


@pytest.mark.parametrize("mode, message", [
    ("silent", "no answer of a Dask scheduler within 3 s"),
    ("http", "the service there answers in another protocol than Dask's"),
])
def test_a_service_that_is_not_a_scheduler_exits_2_within_the_deadline(fmus, tmp_path, fake_service, monkeypatch,
                                                                       mode, message):
    from uiofmu.cosim.campaign import scheduler

    monkeypatch.setattr(scheduler, "SCHEDULER_TIMEOUT_S", 3.0)
    address = fake_service(mode)
    t0 = time.perf_counter()
    result = run_cli_within(30, "campaign", campaign_file(tmp_path, fmus), "--out", tmp_path / "out",
                            "--scheduler", address)
    assert result is not None, "the campaign still waits for the service after 30 s"
    assert result.code == 2 and f"--scheduler {address}: {message}" in result.err, result.err
    assert result.err.count("\n") == 1 and "Traceback" not in result.err
    assert time.perf_counter() - t0 < 10


@pytest.mark.parametrize("value, message", [
    ("garbage", "no port"),
    ("inproc://x", "the protocol 'inproc' is not supported"),
    ("tls://node:8786", "the protocol 'tls' is not supported"),
    ("ucx://node:8786", "the protocol 'ucx' is not supported"),
    ("file:///etc/passwd", "the protocol 'file' is not supported"),
    ("tcp://" + "a" * 300 + ":8786", "a host of 300 characters, more than 253"),
    ("tcp://no host:8786", "not a host name"),
    ("tcp://node:0", "the port '0' is not a number from 1 to 65535"),
    ("tcp://node:65536", "the port '65536' is not a number from 1 to 65535"),
    ("", "an empty address"),
])
def test_scheduler_addresses_are_checked_before_any_work(fmus, tmp_path, value, message):
    t0 = time.perf_counter()
    result = run_cli("campaign", campaign_file(tmp_path, fmus), "--out", tmp_path / "out", "--scheduler", value)
    assert result.code == 2 and message in result.err and "expected tcp://HOST:PORT" in result.err, result.err
    assert f"--scheduler {value[:80]!r}" in result.err and result.err.count("\n") == 1
    assert time.perf_counter() - t0 < 5 and not (tmp_path / "out" / "campaign.csv").exists()


def test_scheduler_addresses_that_are_accepted():
    from uiofmu.cosim.campaign import scheduler_address

    assert scheduler_address("127.0.0.1:8786") == "tcp://127.0.0.1:8786"
    assert scheduler_address("tcp://node-1.example.org:8786") == "tcp://node-1.example.org:8786"
    assert scheduler_address("tcp://[::1]:08786") == "tcp://[::1]:8786"


# --------------------------------------------------------------------------------------------
# integers of the campaign file and of the plant FMU, limits of the axes
# --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def random_switched_plant(tmp_path_factory):
    """A plant FMU whose switching is random, with its FMI Integer parameter ``seed``."""
    from uiofmu.fmu.export import build_plant
    from uiofmu.problem import load_problem

    folder = tmp_path_factory.mktemp("switched")
    text = (EXAMPLES / "seed002_setup1.toml").read_text()
    text = text[:text.index("[plant.switching]")] + '[plant.switching]\nrule = "random"\nseed = 3\n\n' + \
        text[text.index("[observer]"):]
    (folder / "problem.toml").write_text(text)
    problem = load_problem(folder / "problem.toml")
    return build_plant(problem.plant, problem.name, folder / "plant.fmu", step=problem.options.step)


def _integer_campaign(tmp_path, fmus, plant, seed_axis: str) -> str:
    _, observer, _ = fmus
    spec = tmp_path / "c.toml"
    spec.write_text(f'[campaign]\nobserver = "{observer}"\nplant = "{plant}"\nruns = 4\n'
                    f"[axes]\nplant_parameters = {{seed = {seed_axis}}}\n")
    return str(spec)


@pytest.mark.parametrize("axis, key, found", [
    ("2147483648", "axes.plant_parameters.seed", "found 2147483648"),
    ("-2147483649", "axes.plant_parameters.seed", "found -2147483649"),
    ("1.5", "axes.plant_parameters.seed", "found 1.5"),
    ("1e20", "axes.plant_parameters.seed", "found 1e+20"),
    ("[7, 2.5]", "axes.plant_parameters.seed[1]", "found 2.5"),
    ("{kind = 'normal', mean = 3.0, std = 1.0}", "axes.plant_parameters.seed", "a normal draw is not one"),
])
def test_an_integer_plant_parameter_takes_32_bit_integers_only(fmus, random_switched_plant, tmp_path, axis, key,
                                                                found):
    result = run_cli("campaign", _integer_campaign(tmp_path, fmus, random_switched_plant, axis),
                     "--out", tmp_path / "out")
    assert result.code == 2 and result.err.count("\n") == 1, result.err
    assert f"{key}: the plant FMU's seed, an Integer parameter, takes integers in [-2147483648, 2147483647]" \
        in result.err and found in result.err


def test_an_integer_plant_parameter_is_recorded_as_the_fmu_gets_it(fmus, random_switched_plant, tmp_path):
    from uiofmu.cosim.campaign import load_campaign, prepare, scenario

    campaign = load_campaign(_integer_campaign(tmp_path, fmus, random_switched_plant, "[-2147483648, 2147483647]"))
    setup = prepare(campaign)
    assert setup.integers == ("seed",)
    values = {tuple(scenario(campaign, setup, r)["plant.seed"]) for r in range(campaign.runs)}
    assert values <= {(-2147483648,), (2147483647,)} and all(type(v[0]) is int for v in values)


@pytest.mark.parametrize("key, value, message", [
    ("seed", "1.5", "campaign.seed: expected an integer, found 1.5"),
    ("seed", "true", "campaign.seed: expected an integer, found True"),
    ("seed", "-2147483648", "campaign.seed: expected an integer in [0, 4294967295], found -2147483648"),
    ("seed", "4294967296", "campaign.seed: expected an integer in [0, 4294967295], found 4294967296"),
    ("runs", "2.0", "campaign.runs: expected an integer, found 2.0"),
    ("runs", "10000001", "campaign.runs: expected an integer in [1, 10000000], found 10000001"),
    ("batch", "0", "campaign.batch: expected an integer in [1, 100000], found 0"),
    ("batch", "1e3", "campaign.batch: expected an integer, found 1000.0"),
])
def test_integer_keys_of_the_campaign_file(tmp_path, key, value, message):
    spec = tmp_path / "c.toml"
    lines = {"problem": "'p.toml'", "runs": "3", key: value}
    spec.write_text("[campaign]\n" + "".join(f"{k} = {v}\n" for k, v in lines.items()))
    result = run_cli("campaign", spec, "--out", tmp_path / "out")
    assert result.code == 2 and message in result.err, result.err


@pytest.mark.parametrize("axis, message", [
    ("xhat0_error = {kind = 'normal', std = 1e300}", "axes.xhat0_error.std: expected a value in [0, 1e+100], "
                                                      "found 1e+300"),
    ("xhat0_error = {kind = 'normal', mean = -1e200, std = 1.0}", "axes.xhat0_error.mean: expected a value in "
                                                                  "[-1e+100, 1e+100], found -1e+200"),
    ("d_scale = {kind = 'uniform', low = -1e308, high = 1e308}", "axes.d_scale.low: expected a value in [-1e+100"),
    ("d_scale = {kind = 'uniform', low = 0.0, high = inf}", "axes.d_scale.high: expected a finite number"),
    ("d_scale = [1.0, 1e101]", "axes.d_scale[1]: expected a value in [-1e+100, 1e+100], found 1e+101"),
    ("xhat0_error = {kind = 'constant', value = [nan, 0.0]}", "axes.xhat0_error.value[0]: expected a finite number"),
])
def test_axes_whose_draws_could_overflow_exit_2_at_load(tmp_path, axis, message):
    spec = tmp_path / "c.toml"
    spec.write_text(f"[campaign]\nproblem = 'p.toml'\nruns = 3\n[axes]\n{axis}\n")
    result = run_cli("campaign", spec, "--out", tmp_path / "out")
    assert result.code == 2 and message in result.err and result.err.count("\n") == 1, result.err


def test_the_figure_and_summary_skip_non_finite_figures(tmp_path):
    from uiofmu.cosim.campaign import Tally, plot_campaign

    tally = Tally()
    for row, (t, ratio) in enumerate([(1.0, 0.5), (float("inf"), float("nan")), (2.0, float("inf"))]):
        tally.add(row, {"status": "ok", "time_to_1pct": t, "max_bound_ratio": ratio})
    tally.add(3, {"status": "failed", "reason": "refused"})
    assert tally.worst == (float("inf"), 2, None, None)
    quant = tally.quantiles()
    assert quant["time_to_1pct"]["count"] == 3 and quant["time_to_1pct"]["non_finite"] == 1
    assert quant["time_to_1pct"]["q100"] == 2.0 and quant["max_bound_ratio"]["q00"] == 0.5
    assert plot_campaign(tally, None, None, tmp_path / "c.png").stat().st_size > 10_000


# --------------------------------------------------------------------------------------------
# the outputs are replaced together
# --------------------------------------------------------------------------------------------
def test_a_failing_campaign_leaves_the_old_outputs_as_they_were(campaign_run, fmus, tmp_path, monkeypatch):
    import shutil

    from uiofmu.cosim import campaign
    from uiofmu.cosim.campaign import run as running

    _, old, _ = campaign_run
    out = tmp_path / "out"
    out.mkdir()
    for name in campaign.OUTPUTS:
        shutil.copy(old / name, out / name)
    before = {name: (out / name).read_bytes() for name in campaign.OUTPUTS}

    def broken_figure(*args, **kwargs):
        raise RuntimeError("the figure failed")

    monkeypatch.setattr(running, "plot_campaign", broken_figure)
    result = run_cli("campaign", campaign_file(tmp_path, fmus, runs=4), "--out", out, "--workers", "1")
    assert result.code == 1 and "the figure failed" in result.err, result.err
    assert {name: (out / name).read_bytes() for name in campaign.OUTPUTS} == before
    assert sorted(p.name for p in out.iterdir()) == sorted(campaign.OUTPUTS)
    assert not list(old.glob("campaign.partial-*"))


# --------------------------------------------------------------------------------------------
# files that are not what they should be
# --------------------------------------------------------------------------------------------
def test_a_campaign_file_that_is_not_a_text_file_exits_2_naming_it(tmp_path):
    folder, missing, binary, fifo = tmp_path / "dir", tmp_path / "missing.toml", tmp_path / "b.toml", tmp_path / "f"
    folder.mkdir()
    binary.write_bytes(bytes(range(256)))
    os.mkfifo(fifo)
    for path, message in [(folder, "a folder, not a campaign file"), (missing, "no such campaign file"),
                          (binary, "the campaign file is not UTF-8 text"), (fifo, "not a regular file")]:
        result = run_cli("campaign", path, "--out", tmp_path / "out")
        assert result.code == 2 and result.err.startswith(f"uiofmu campaign: error: {path}: "), result.err
        assert message in result.err and result.err.count("\n") == 1


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads a file of mode 000")
def test_an_unreadable_campaign_file_exits_2_naming_it(tmp_path):
    spec = tmp_path / "c.toml"
    spec.write_text("[campaign]\n")
    spec.chmod(0)
    result = run_cli("campaign", spec, "--out", tmp_path / "out")
    assert result.code == 2 and f"{spec}: cannot read the campaign file" in result.err, result.err


def test_folders_where_the_campaign_wants_files_exit_2_naming_the_key(fmus, tmp_path):
    plant, _, _ = fmus
    spec = tmp_path / "c.toml"
    spec.write_text(f'[campaign]\nobserver = "{tmp_path}"\nplant = "{plant}"\nruns = 3\n')
    result = run_cli("campaign", spec, "--out", tmp_path / "out")
    assert result.code == 2 and f"campaign.observer: {tmp_path}: a folder, not an FMU file" in result.err, result.err
    spec.write_text(f'[campaign]\nobserver = "o.fmu"\nplant = "{plant}"\nruns = 3\n[axes]\nsteps = "file:."\n')
    result = run_cli("campaign", spec, "--out", tmp_path / "out")
    assert result.code == 2 and f"axes.steps[0]: {tmp_path}: a folder, not a step file" in result.err, result.err


def test_an_error_never_quotes_a_step_file(tmp_path):
    """A campaign file may name any file as its steps: its lines are not shown in the message."""
    (tmp_path / "secret.txt").write_text("root:x:0:0:SECRET-LINE:/root:/bin/bash\n")
    spec = tmp_path / "c.toml"
    spec.write_text("[campaign]\nproblem = 'p.toml'\nruns = 3\n[axes]\nsteps = ['file:secret.txt']\n")
    result = run_cli("campaign", spec, "--out", tmp_path / "out")
    assert result.code == 2 and "axes.steps[0]: line 1 of" in result.err and "must be a number" in result.err
    assert "SECRET" not in result.err and "root:x" not in result.err, result.err


@pytest.mark.parametrize("values", [[1 - 1e-9 * k for k in range(60)], np.linspace(0.999, 0.9999999, 60).tolist(),
                                    [0.9766093529235645 + 1e-16 * k for k in range(60)]])
def test_the_bound_ratio_axis_is_in_plain_numbers(values):
    """No axis labelled ``1e-6+1``: an offset-free axis, one bar for values within 1e-6 of each other."""
    from uiofmu.cosim.campaign import _hist
    from uiofmu.cosim.report import pyplot

    plt = pyplot()[0]
    fig, ax = plt.subplots()
    try:
        assert _hist(ax, values, "tab:green", marks=(1.0,)) == 60
        ax.axvline(1.0)
        fig.canvas.draw()
        assert ax.xaxis.get_offset_text().get_text() == ""
        labels = [t.get_text() for t in ax.get_xticklabels()]
        if max(values) - min(values) < 1e-6:
            assert len(ax.patches) == 1 and labels[0] == f"{min(values):.6g}", labels
            text = ax.texts[0].get_text()
            assert text.startswith("all 60 ") and f"{min(values):.10g}" in text
    finally:
        plt.close(fig)


def test_the_tally_knows_when_every_run_is_at_the_bound_start():
    from uiofmu.cosim.campaign import Tally

    tally = Tally()
    for row, ratio in enumerate([0.5, 0.75, 0.75]):
        tally.add(row, {"status": "ok", "max_bound_ratio": ratio, "max_bound_ratio_step": 1})
    assert tally.ratios == tally.ratios_at_start == 3 and tally.worst == (0.75, 1, None, 1)
    tally.add(3, {"status": "ok", "max_bound_ratio": 0.25, "max_bound_ratio_step": 7})
    assert tally.ratios == 4 and tally.ratios_at_start == 3
