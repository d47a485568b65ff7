"""Design speed: the direct conic assembly against the straightforward cvxpy formulation.

    .venv/bin/python benchmarks/design_speed.py [--quick] [--repeat R] [--only TEXT] [--backend B]
    .venv/bin/python benchmarks/design_speed.py --overhead [--repeat R]

For the building (seed 004), seed 000 Example 1 and random sampled-data problems (n = 4, 8, 16
states; 6 and 12 intervals, alpha = "max", except n = 16 with 12 intervals: one solve at
alpha = 0.1), side by side in one run, each with both LMI backends (the full run takes about
half an hour on 2 cores; ``--quick`` under a minute):

total       the whole ``uiofmu.design`` (existence analysis, LMI assembly, every solve of the
            search, re-checks, card), s
CLARABEL    the wall time inside CLARABEL (its solver object's construction and ``solve``),
            summed over the solves; measured the same way for both backends, s
ratio       total / CLARABEL
assembly    building the LMI problem once (tracing into conic form, or cvxpy's construction;
            cvxpy canonicalises again inside the first solve, which lands in ``total``), s
search      the "max" search (all its solves and re-checks), s
solves      solves of the search; per solve: CLARABEL / solves
found       the certified value (alpha, or the decay for Example 1), and whether the card's
            certificate re-checks

Designs faster than 0.2 s are repeated (``--repeat``, default 21) and the median run is shown.
The searches of the two backends may take different paths (a point one backend's solver
returns may fail the re-check where the other's passes), so compare the value found and the
time per solve as well as the total.

``--overhead`` measures what a design costs beyond CLARABEL, in CPU time (``time.process_time``), on
the building, seed 000 Example 1 and the three-mode switched plant (seed 002): ``uiofmu.design`` of
one problem ``--repeat`` times (default 40) after a first design, each run twice in turn, with its
LMIs traced afresh (``fresh``: :func:`uiofmu.conic.traced` emptied before) and with the traced forms
of the previous design kept (``reused``: a design made again, or at another decay). The anchor,
CLARABEL's CPU time (its solver object's construction and ``solve``), is measured inside the same
designs:

design ms   the median CPU time of a design
CLARABEL    the median CPU time inside CLARABEL in a design, ms
ratio       the summed design CPU time over the summed CLARABEL CPU time
goal        the ratio a design should stay within (``-``: none set)
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from unittest import mock

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import clarabel  # noqa: E402
import numpy as np  # noqa: E402

import uiofmu  # noqa: E402
from uiofmu import conic, lmi  # noqa: E402


def random_problem(n: int, intervals: int, seed: int, alpha="max"):
    """A stable continuous plant with 2 outputs and 1 unknown input; alpha = "max" by default."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    A -= (max(np.linalg.eigvals(A).real) + 0.5) * np.eye(n)
    C = rng.normal(size=(2, n))
    E = rng.normal(size=(n, 1))
    plant = uiofmu.Plant.create(A, C, E, rng.normal(size=(n, 1)), time="continuous")
    hs = list(np.linspace(0.05, 0.05 * intervals, intervals))
    return uiofmu.make_problem(plant, "sampled-data", name=f"random-n{n}-N{intervals}", intervals=hs, alpha=alpha)


class _TimedSolver:
    """Stands in for ``clarabel.DefaultSolver`` and adds its construction and solve time to a clock
    (``timer``: wall time, or CPU time for ``--overhead``)."""

    clock = 0.0
    timer = staticmethod(time.perf_counter)
    real = clarabel.DefaultSolver

    def __init__(self, *args):
        t0 = self.timer()
        self._solver = self.real(*args)
        type(self).clock += self.timer() - t0

    def solve(self):
        t0 = self.timer()
        try:
            return self._solver.solve()
        finally:
            type(self).clock += self.timer() - t0


#: The LMI backends compared.
BACKENDS = ("cvxpy", "direct")


def timed_design(problem, backend: str) -> dict:
    """One design with every LmiSystem on ``backend``; its card and times."""
    make = lmi.LmiSystem.__init__

    def init(self, *a, **kw):
        kw["backend"] = backend
        make(self, *a, **kw)

    _TimedSolver.clock = 0.0
    with mock.patch.object(lmi.LmiSystem, "__init__", init), mock.patch.object(clarabel, "DefaultSolver",
                                                                                _TimedSolver):
        t0 = time.perf_counter()
        card = uiofmu.design(problem)
        total = time.perf_counter() - t0
    timing, search = card.data["timing"], card.data.get("search") or {}
    return {"card": card, "total": total, "clarabel": _TimedSolver.clock, "assembly": timing["lmi_assembly_s"],
            "search": search.get("seconds"), "solves": timing["solves"]}


def median_design(problem, backend: str, repeat: int) -> dict:
    """The median-time run of ``repeat`` designs (one when a design takes over 0.2 s)."""
    runs = [timed_design(problem, backend)]
    if runs[0]["total"] < 0.2:
        runs += [timed_design(problem, backend) for _ in range(repeat - 1)]
    return sorted(runs, key=lambda r: r["total"])[len(runs) // 2]


#: The cases of ``--overhead``: label, problem file, and the ratio its design should stay within (None: none set).
OVERHEAD_CASES = (("building (seed 004)", "plants/two_room_building", 1.5),
                  ("seed 000 Example 1", "examples/seed000_example1.toml", 3.0),
                  ("three modes (seed 002)", "examples/seed002_three_modes.toml", None))


def cpu_design(problem, fresh: bool) -> tuple:
    """One ``uiofmu.design`` of ``problem``: its CPU time and CLARABEL's CPU time in it, s; ``fresh``: its LMIs
    traced afresh."""
    if fresh:
        conic._TRACED.clear()
    _TimedSolver.clock = 0.0
    t0 = time.process_time()
    uiofmu.design(problem)
    return time.process_time() - t0, _TimedSolver.clock


def overhead(repeat: int):
    """The ``--overhead`` table (see the module docstring)."""
    print(f"{'case':24s} {'LMIs':7s} {'design ms':>10s} {'CLARABEL':>9s} {'ratio':>6s} {'goal':>5s}")
    with mock.patch.object(_TimedSolver, "timer", staticmethod(time.process_time)), \
            mock.patch.object(clarabel, "DefaultSolver", _TimedSolver):
        for label, path, goal in OVERHEAD_CASES:
            problem = uiofmu.load_problem(ROOT / path)
            cpu_design(problem, fresh=False)                 # first calls and imports out of the way
            runs = {True: [], False: []}
            for _ in range(repeat):                          # in turn, so that the machine's load falls on both
                for fresh in (True, False):
                    runs[fresh].append(cpu_design(problem, fresh))
            for fresh in (True, False):
                total, anchor = np.array(runs[fresh]).T
                ratio = total.sum() / max(anchor.sum(), 1e-12)
                print(f"{label:24s} {'fresh' if fresh else 'reused':7s} {np.median(total) * 1e3:10.2f} "
                      f"{np.median(anchor) * 1e3:9.2f} {ratio:6.2f} {goal if goal else '-':>5}", flush=True)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="only the building, Example 1 and n = 4")
    parser.add_argument("--repeat", type=int, help="runs of designs under 0.2 s (median shown; default 21), "
                        "or of each --overhead case (default 40)")
    parser.add_argument("--only", metavar="TEXT", help="only the cases whose label contains TEXT")
    parser.add_argument("--backend", choices=BACKENDS, action="append",
                        help="only this LMI backend (repeatable; default both)")
    parser.add_argument("--overhead", action="store_true",
                        help="design CPU time against CLARABEL's on three problems (direct backend)")
    args = parser.parse_args()
    if args.overhead:
        return overhead(args.repeat or 40)
    backends = tuple(args.backend or BACKENDS)
    example1 = uiofmu.load_problem(ROOT / "examples" / "seed000_example1.toml")
    cases = [("building (seed 004)", uiofmu.load_problem(ROOT / "plants" / "two_room_building")),
             ("seed 000 Example 1", example1)]
    sizes = [(4, 6), (4, 12)] if args.quick else [(4, 6), (4, 12), (8, 6), (8, 12), (16, 6)]
    cases += [(f"random n={n}, {N} intervals", random_problem(n, N, seed=n * 100 + N)) for n, N in sizes]
    if not args.quick:       # a "max" search is 16 solves; one solve of this size takes minutes
        cases.append(("random n=16, 12 int., a=0.1", random_problem(16, 12, seed=1612, alpha=0.1)))
    if args.only:
        cases = [c for c in cases if args.only in c[0]]
    for backend in backends:                # imports and first-call costs out of the way
        timed_design(example1, backend)
    print(f"{'case':26s} {'backend':7s} {'total s':>9s} {'CLARABEL':>9s} {'ratio':>6s} {'assembly':>9s} "
          f"{'search s':>9s} {'solves':>6s} {'s/solve':>8s}  found")
    for label, problem in cases:
        for backend in backends:
            try:
                r = median_design(problem, backend, args.repeat or 21)
            except uiofmu.UserError as exc:
                print(f"{label:26s} {backend:7s} failed: {str(exc)[:100]}", flush=True)
                continue
            card = r["card"]
            found = card.data.get("alpha", card.data.get("decay_bound"))
            verified = "verified" if all(c.holds for c in uiofmu.verify(card)) else "NOT VERIFIED"
            search = f"{r['search']:.4f}" if r["search"] is not None else "-"
            print(f"{label:26s} {backend:7s} {r['total']:9.4f} {r['clarabel']:9.4f} "
                  f"{r['total'] / max(r['clarabel'], 1e-12):6.2f} {r['assembly']:9.4f} {search:>9s} "
                  f"{r['solves']:6d} {r['clarabel'] / max(r['solves'], 1):8.4f}  {found:.6g} {verified}", flush=True)


if __name__ == "__main__":
    main()
