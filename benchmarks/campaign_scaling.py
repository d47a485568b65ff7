"""Campaign scaling on this machine: runs per second with 1 and 2 Dask workers, the per-run overhead
(FMU load and instantiation, the card's re-check) against the run itself, and one large campaign timed.

The runs are the two-room building (seed 004) with C FMUs under packet drop-outs (``dropout:600:0.3:11``
and ``choice:600,1200,1800``), t_end = 840,000 s: about 700 communication steps a run, as the issue asks::

    .venv/bin/python benchmarks/campaign_scaling.py                  # 1 and 2 workers, 200 runs each
    .venv/bin/python benchmarks/campaign_scaling.py --full 10000     # and a 10,000-run campaign

Prints one JSON document (also written to OUT/scaling.json).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
T_END = 840_000.0


def campaign_text(runs: int) -> str:
    """The building campaign (C FMUs built from the problem file)."""
    return (f'[campaign]\nproblem = "{ROOT / "plants" / "two_room_building"}"\nruns = {runs}\nseed = 1\n'
            f't_end = {T_END}\nbackend = "c"\n\n[axes]\n'
            'steps = ["dropout:600:0.3:11", "dropout:600:0.5:11", "choice:600,1200,1800"]\n'
            'xhat0_error = {kind = "normal", std = 2.0}\n'
            'd_scale = {kind = "uniform", low = 0.5, high = 1.5}\n')


def campaign(out: Path, runs: int, workers: int) -> dict:
    """Run the building campaign of ``runs`` runs on ``workers`` local workers; its summary."""
    from uiofmu.cosim.campaign import load_campaign, run_campaign

    spec = out / f"campaign_{runs}.toml"
    spec.write_text(campaign_text(runs))
    return run_campaign(load_campaign(spec), out / f"runs{runs}_workers{workers}", workers=workers,
                        show_progress=False)


def overhead(out: Path, repeats: int = 30) -> dict:
    """Per-run costs in this process (median wall times in s): FMU load + instantiate + initialise
    (both FMUs), the card's read and re-check, a run as a campaign worker makes it (the FMUs loaded
    once, reset before each run) and a run from the FMU files (``cosimulate`` loading them)."""
    from uiofmu.cosim.campaign import load_campaign, load, prepare, run_scenario, scenario
    from uiofmu.cosim.fmi import Fmu
    from uiofmu.cosim.master import cosimulate, observer_card
    from uiofmu.cosim.steps import step_sequence

    spec = out / "campaign_overhead.toml"
    spec.write_text(campaign_text(repeats))
    camp = load_campaign(spec)
    setup = prepare(camp, out / "runs_overhead")
    loaded = load(setup)
    times = {"load_instantiate_initialize": [], "card_recheck": [], "worker_run": [], "run_from_files": []}
    steps = []
    for row in range(repeats):
        t = time.perf_counter()
        with Fmu(loaded.plant, "plant") as p, Fmu(loaded.observer, "observer") as o:
            p.initialize(0.0)
            o.initialize(0.0)
        times["load_instantiate_initialize"].append(time.perf_counter() - t)
        t = time.perf_counter()
        observer_card(loaded.observer)
        times["card_recheck"].append(time.perf_counter() - t)
        sc = scenario(camp, setup, row)
        t = time.perf_counter()
        result = run_scenario(setup, sc)
        times["worker_run"].append(time.perf_counter() - t)
        steps.append(result.metrics["steps"])
        t = time.perf_counter()
        cosimulate(loaded.plant, loaded.observer, step_sequence(sc["steps"], loaded.t_end, seed=sc["steps_seed"]),
                   show_progress=False)
        times["run_from_files"].append(time.perf_counter() - t)
    med = {k: statistics.median(v) for k, v in times.items()}
    return {**{f"{k}_s": v for k, v in med.items()}, "steps_per_run": statistics.median(steps),
            "worker_run_per_step_us": med["worker_run"] / statistics.median(steps) * 1e6,
            "load_and_recheck_saved_per_run_s": med["run_from_files"] - med["worker_run"]}


def main(argv=None) -> int:
    """Measure and print the numbers."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=200, help="runs of the 1- and 2-worker campaigns")
    parser.add_argument("--full", type=int, default=0, help="also time a campaign of this many runs on 2 workers")
    parser.add_argument("--out", default=str(ROOT / "out" / "campaign_scaling"), help="output folder")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    report = {"cpus": os.cpu_count(), "t_end": T_END, "backend": "c"}
    report["per_run"] = overhead(out)
    print(json.dumps(report["per_run"], indent=2), file=sys.stderr)
    rates = {}
    for workers in (1, 2):
        s = campaign(out, args.runs, workers)
        rates[workers] = s["runs_per_s"]
        report[f"workers_{workers}"] = {"runs": s["finished"], "failures": s["failures"], "elapsed_s": s["elapsed_s"],
                                        "runs_per_s": s["runs_per_s"], "cluster_startup_s": s["cluster_startup_s"]}
        print(json.dumps(report[f"workers_{workers}"]), file=sys.stderr)
    report["speedup_2_over_1"] = rates[2] / rates[1]
    if args.full:
        t = time.perf_counter()
        s = campaign(out, args.full, 2)
        report["full"] = {"runs": s["finished"], "failures": s["failures"], "workers": 2,
                          "elapsed_s": s["elapsed_s"], "wall_with_startup_and_outputs_s": time.perf_counter() - t,
                          "runs_per_s": s["runs_per_s"], "worst_max_bound_ratio": s["worst_max_bound_ratio"]["value"],
                          "bound_violations": s["bound_violations"],
                          "steps_to_1pct_median": s["quantiles"]["steps_to_1pct"].get("q50")}
        report["goal_10000_runs_under_300_s"] = s["elapsed_s"] * 10_000 / max(1, s["finished"]) < 300
    report["goal_speedup_1_7"] = report["speedup_2_over_1"] >= 1.7
    text = json.dumps(report, indent=2)
    (out / "scaling.json").write_text(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
