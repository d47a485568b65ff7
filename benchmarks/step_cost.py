"""Per-doStep cost of the observer FMU through fmpy, side by side with the reference runtime.

    .venv/bin/python benchmarks/step_cost.py [--steps 20000]

Measured in one run on one machine: the observer FMU (pythonfmu) for the classical UIO of
seed 000 Example 1 and for the sampled-data UIO of the building, their reference runtime
steps, and the linear plant FMU. Median over repeats of the time per call.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

import uiofmu  # noqa: E402
from uiofmu.export import build_observer, build_plant  # noqa: E402
from uiofmu.fmi import Fmu  # noqa: E402
from uiofmu.runtime import Runtime  # noqa: E402


def per_call(fn, steps: int, repeats: int = 5) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn(steps)
        times.append((time.perf_counter() - t0) / steps)
    return statistics.median(times)


def fmu_steps(path, h_list, input_name):
    with Fmu(path, "bench") as fmu:
        fmu.initialize(0.0)
        fmu.set(input_name, np.ones(len(fmu.refs(input_name))))

        def run(n):
            t = 0.0
            for k in range(n):
                h = h_list[k % len(h_list)]
                fmu.step(t, h)
                t += h
        return per_call(run, ARGS.steps)


def runtime_steps(card, h_list):
    rt = Runtime(card)
    rt.set_y(np.ones(rt.p))

    def run(n):
        for k in range(n):
            rt.step(h_list[k % len(h_list)])
    return per_call(run, ARGS.steps)


def main():
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for path, label in ((ROOT / "examples" / "seed000_example1.toml", "lti-uio, n=2 (seed 000 Ex. 1)"),
                            (ROOT / "plants" / "two_room_building" / "problem.toml", "sampled-data, n=2, 12 intervals")):
            problem = uiofmu.load_problem(path)
            card = uiofmu.design(problem)
            obs = build_observer(card, tmp / f"{problem.name}_obs.fmu")
            plant = build_plant(problem.plant, problem.name, tmp / f"{problem.name}_plant.fmu")
            steps = uiofmu.Runtime(card).schedule.admissible_steps()
            rows.append((f"observer FMU via fmpy: {label}", fmu_steps(obs, steps, "y")))
            rows.append((f"reference runtime step: {label}", runtime_steps(card, steps)))
            rows.append((f"plant FMU via fmpy: {problem.name}", fmu_steps(plant, steps, "u")))
    width = max(len(r[0]) for r in rows)
    print(f"{'per fmi2DoStep (median of 5 x ' + str(ARGS.steps) + ' calls)':{width}s}   time")
    for name, sec in rows:
        print(f"{name:{width}s}   {sec * 1e6:7.2f} µs")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=20000)
    ARGS = parser.parse_args()
    main()
