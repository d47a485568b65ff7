"""Design speed: the direct conic assembly against the straightforward cvxpy formulation.

    .venv/bin/python benchmarks/design_speed.py [--quick]

For the building (seed 004), seed 000 Example 1 and random sampled-data problems (n = 4, 8, 16
states; 6 and 12 intervals), side by side in one run, each with both LMI backends:
total design time, CLARABEL's own time as reported (summed over the solves), their ratio, and
the number of solves of the "max" search. The searches of the two backends may take different
paths (a point one backend's solver returns may fail the re-check where the other's passes), so
compare the value found as well as the time. Every design's certificate is re-checked (the same
check for both backends); the table says whether both verified and the value each found.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from unittest import mock

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

import uiofmu  # noqa: E402
from uiofmu import lmi  # noqa: E402


def random_problem(n: int, intervals: int, seed: int):
    """A stable continuous plant with 2 outputs and 1 unknown input, tunable alpha = "max"."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    A -= (max(np.linalg.eigvals(A).real) + 0.5) * np.eye(n)
    C = rng.normal(size=(2, n))
    E = rng.normal(size=(n, 1))
    plant = uiofmu.Plant.create(A, C, E, rng.normal(size=(n, 1)), time="continuous")
    hs = list(np.linspace(0.05, 0.05 * intervals, intervals))
    return uiofmu.make_problem(plant, "sampled-data", name=f"random-n{n}-N{intervals}", intervals=hs, alpha="max")


def timed_design(problem, backend: str):
    """Design with every LmiSystem on ``backend``; returns (card, total s, solver s, solves)."""
    solver = {"time": 0.0, "solves": 0}
    original = lmi.LmiSystem.solve

    def counting(self, **kw):
        sol = original(self, **kw)
        solver["time"] += sol.solve_time
        solver["solves"] += 1
        return sol

    make = lmi.LmiSystem.__init__

    def init(self, *a, **kw):
        kw["backend"] = backend
        make(self, *a, **kw)

    with mock.patch.object(lmi.LmiSystem, "solve", counting), mock.patch.object(lmi.LmiSystem, "__init__", init):
        t0 = time.perf_counter()
        card = uiofmu.design(problem)
        total = time.perf_counter() - t0
    return card, total, solver["time"], solver["solves"]


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="only the building, Example 1 and n = 4")
    quick = parser.parse_args().quick
    cases = [("building (seed 004)", uiofmu.load_problem(ROOT / "plants" / "two_room_building")),
             ("seed 000 Example 1", uiofmu.load_problem(ROOT / "examples" / "seed000_example1.toml"))]
    sizes = [(4, 6), (4, 12)] if quick else [(4, 6), (4, 12), (8, 6), (8, 12), (16, 6)]
    cases += [(f"random n={n}, {N} intervals", random_problem(n, N, seed=n * 100 + N)) for n, N in sizes]
    uiofmu.design(cases[1][1])        # imports and first-call costs out of the way
    print(f"{'case':28s} {'backend':8s} {'total s':>9s} {'solver s':>9s} {'ratio':>6s} {'solves':>6s} "
          f"{'verified':>8s}  value found")
    for label, problem in cases:
        for backend in ("cvxpy", "direct"):
            try:
                card, total, solver, solves = timed_design(problem, backend)
            except uiofmu.UserError as exc:
                print(f"{label:28s} {backend:8s} failed: {str(exc)[:90]}", flush=True)
                continue
            found = card.data.get("alpha", card.data.get("decay_bound"))
            print(f"{label:28s} {backend:8s} {total:9.3f} {solver:9.3f} {total / max(solver, 1e-9):6.1f} "
                  f"{solves:6d} {str(all(c.holds for c in uiofmu.verify(card))):>8s}  {found:.6g}", flush=True)


if __name__ == "__main__":
    main()
