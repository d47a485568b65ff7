"""The main job, ``uiofmu demo``: the two-room building of seed 004 with packet drop-outs.

Design the observer of the building's problem file (``plants/two_room_building``) with the
largest certified decay, build the observer and plant FMUs, co-simulate them with random
drop-outs (nominal 10 min sampling, each sample lost with probability 0.3, at most 11 in a
row) over two simulated days, and report.
"""

from __future__ import annotations

import time
from importlib.resources import files
from pathlib import Path

from .cosim.summary import print_summary
from .runtime.files import check_output_dir

#: The demo's step sequence and horizon.
DEMO_STEPS = "dropout:600:0.3:11"
DEMO_T_END = 2 * 86400.0
DEMO_SEED = 1


def demo_problem_path() -> Path:
    """The embedded problem file (same as ``plants/two_room_building/problem.toml``)."""
    return Path(str(files("uiofmu") / "data" / "two_room_building.toml"))


def run_demo(out, say=print) -> dict:
    """Run the main job into ``out``; returns the metrics.

    Parameters
    ----------
    out : str or Path
        Output folder: the design card, both FMUs, results.csv, metrics.json, report.png.
    say : callable
        Where the progress lines go.
    """
    from .cosim.master import cosimulate, write_outputs
    from .fmu.export import build_observer, build_plant
    from .problem import load_problem
    from .cosim.steps import step_sequence
    from .synthesis import design

    out = check_output_dir(out, "--out folder")
    out.mkdir(parents=True, exist_ok=True)
    problem = load_problem(demo_problem_path())
    say(f"uiofmu demo: {problem.name}, {problem.family} observer, nominal 10 min sampling with drop-outs")
    t0 = time.perf_counter()
    card = design(problem)
    card.write(out / "design.json")
    cert = card.data["certificate"]
    size = card.data["lmi_size"]
    say(f"  design               alpha = {card.data['alpha']:.6g} (limit from the sampled zeros "
        f"{card.data['alpha_limit_from_zeros']:.6g}), {size['lmis']} LMIs of {size['lmi_dim']}x{size['lmi_dim']}, "
        f"{card.data['search']['solves']} solve(s) in {time.perf_counter() - t0:.2f} s, certificate "
        f"{'verified' if cert['verified'] else 'NOT verified'}")
    obs = build_observer(card, out / "observer.fmu")
    plant = build_plant(problem.plant, problem.name, out / "plant.fmu", step=problem.options.step,
                        experiment_steps=problem.experiment_steps, labels=problem.labels)
    say(f"  FMUs                 {obs}, {plant}")
    steps = step_sequence(DEMO_STEPS, DEMO_T_END, seed=DEMO_SEED)
    result = cosimulate(plant, obs, steps)
    paths = write_outputs(result, out, title=f"{problem.name}: {problem.family} observer under packet drop-outs "
                                              f"({DEMO_STEPS}, seed {DEMO_SEED})")

    print_summary(result.metrics, {"design card": out / "design.json", **paths})
    return result.metrics
