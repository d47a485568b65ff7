"""CPU time per step of the co-simulation master against the bare FMI calls it makes, side by side.

    .venv/bin/python benchmarks/master_overhead.py [--repeat 7] [--t-end 600600] [--steps dropout:600:0.3:11]

The two-room building (``plants/two_room_building``, sampled-data observer with its C FMU) under
drop-outs, with the C plant FMU and with the pythonfmu plant FMU. For each pair, alternately in one
process, ``--repeat`` times:

(a) ``cosimulate`` (uiofmu's master) on its Python loop (``native=False``): its own CPU clocks
    (``CosimResult.timing``) give the stepping loop, the steps (the loop with the input evaluation for
    all points, the buffers and the histories) and the whole call (design card re-check, FMU loading,
    initialisation, metrics);
(b) the bare loop: the same FMI calls on the same step sequence through fmpy's ctypes functions with
    value references and buffers prepared beforehand, and nothing else (no inputs, no histories, no
    status checks), on freshly loaded and initialised instances of the same FMUs;
(c) ``cosimulate`` on its native loop (the default: the C driver of :mod:`uiofmu.cosim.native` makes the
    calls where both FMUs have native binaries; a pythonfmu plant keeps the Python loop);
(d) a campaign worker's run, both ways: ``cosimulate`` on FMU instances kept open and a card read once
    (``instances=``, ``card=``), the whole call's CPU time.

Medians over the repeats; the ratio (a)/(b) is the master's overhead over the FMI calls it makes, (a)/(c)
and the two runs of (d) what the native loop gains (the goal: a worker's building run with C FMUs at
least 2x faster). Wall times vary with the other work on the machine; the ratios, measured side by side,
much less.
"""

from __future__ import annotations

import argparse
import ctypes
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import uiofmu  # noqa: E402
from uiofmu.cosim.fmi import Fmu  # noqa: E402
from uiofmu.cosim.master import (_VALUES_FUNCTION, communication_points, cosimulate, default_inputs,  # noqa: E402
                                 observer_card)
from uiofmu.cosim.steps import step_sequence  # noqa: E402
from uiofmu.fmu.export import build_observer, build_plant  # noqa: E402


def build(tmp: Path) -> tuple[Path, dict]:
    """The building's C observer FMU and its plant FMUs (C, pythonfmu)."""
    problem = uiofmu.load_problem(ROOT / "plants" / "two_room_building")
    card = uiofmu.design(problem)
    observer = build_observer(card, tmp / "observer_c.fmu", backend="c")
    plants = {backend: build_plant(problem.plant, "building", tmp / f"plant_{backend}.fmu", backend=backend)
              for backend in ("c", "python")}
    return observer, plants


def bare_loop(plant_path, observer_path, steps, addresses: bool = False) -> tuple[float, int]:
    """CPU seconds of the bare FMI calls of the master's loop (the building's ports), and their number per
    step: plant fmi2SetReal(u, d), fmi2GetReal(y, x); observer fmi2SetReal(y, u), fmi2GetReal(xhat, r, dhat);
    both fmi2DoStep; at the last point the sets and gets only. Through fmpy's ctypes functions on ctypes
    arrays, or (``addresses``) through the master's own prototype of the same functions on addresses."""
    with Fmu(plant_path, "plant") as plant, Fmu(observer_path, "observer") as obs:
        plant.initialize(0.0)
        obs.initialize(0.0)
        source = default_inputs_at_zero(observer_path)
        specs = [(plant, "fmi2SetReal", ["u", "d"], [source["u"], source["d"]]),
                 (plant, "fmi2GetReal", ["y", "x"], None),
                 (obs, "fmi2SetReal", ["y", "u"], [[22.0], source["u"]]),
                 (obs, "fmi2GetReal", [n for n in ("xhat", "r", "dhat") if obs.has(n)], None)]
        calls, keep = [], []
        for fmu, name, vectors, values in specs:
            refs = fmu.value_references(vectors)
            buffer = (ctypes.c_double * len(refs))(*[v for vec in (values or []) for v in vec])
            function = fmu.function(name)
            if addresses:
                function = _VALUES_FUNCTION(ctypes.cast(function, ctypes.c_void_p).value)
                keep.append((refs, buffer))
                refs, buffer = ctypes.addressof(refs), ctypes.addressof(buffer)
            calls.append((function, fmu.component, refs, len(refs) if not addresses else len(keep[-1][0]), buffer))
        (ps, pc, pr, pn, pb), (pg, _, gr, gn, gb), (os_, oc, orr, on, ob), (og, _, xr, xn, xb) = calls
        odo, pdo = obs.function("fmi2DoStep"), plant.function("fmi2DoStep")
        times, hs = communication_points(steps).tolist(), list(steps.tolist())
        cpu = time.process_time()
        for t, h in zip(times, hs):
            ps(pc, pr, pn, pb)
            pg(pc, gr, gn, gb)
            os_(oc, orr, on, ob)
            og(oc, xr, xn, xb)
            odo(oc, t, h, 1)
            pdo(pc, t, h, 1)
        ps(pc, pr, pn, pb)
        pg(pc, gr, gn, gb)
        os_(oc, orr, on, ob)
        og(oc, xr, xn, xb)
        return time.process_time() - cpu, len(calls) + 2


def default_inputs_at_zero(observer_path) -> dict:
    """The building's signals at t = 0 (the bare loop's buffers hold them throughout)."""
    return {k: [float(v) for v in vec] for k, vec in default_inputs(observer_card(observer_path)).values(0.0).items()}


def measure(plant, observer, steps, repeat: int) -> dict:
    K = len(steps)
    card = observer_card(observer)
    runs = {key: [] for key in ("loop", "steps", "total", "bare", "bare_addresses", "native_loop", "native_steps",
                                "native_total", "worker", "native_worker")}
    native = set()
    with Fmu(plant, "plant") as p, Fmu(observer, "observer") as o:
        for _ in range(repeat):
            for prefix, loop in (("", False), ("native_", True)):
                result = cosimulate(plant, observer, steps, show_progress=False, native=loop)
                for key in ("loop", "steps", "total"):
                    runs[prefix + key].append(result.timing[key] / K)
                kept = cosimulate(plant, observer, steps, show_progress=False, native=loop, instances=(p, o), card=card)
                runs[prefix + "worker"].append(kept.timing["total"])
                native |= {result.timing["native"], kept.timing["native"]} - {False}
            for key, addresses in (("bare", False), ("bare_addresses", True)):
                bare, calls = bare_loop(plant, observer, steps, addresses)
                assert calls == result.timing["fmi_calls_per_step"], (calls, result.timing)
                runs[key].append(bare / K)
    out = {key: statistics.median(v) * (1e3 if "worker" in key else 1e6) for key, v in runs.items()}
    out["calls"], out["native"] = calls, bool(native)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--steps", default="dropout:600:0.3:11")
    parser.add_argument("--t-end", type=float, default=600600.0,
                        help="end time in s (default 600600 s, the observer's default horizon: about 700 steps)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    steps = step_sequence(args.steps, args.t_end, seed=args.seed)
    with tempfile.TemporaryDirectory() as tmp:
        observer, plants = build(Path(tmp))
        rows = []
        for backend, label in (("c", "C observer, C plant"), ("python", "C observer, pythonfmu plant")):
            m = measure(plants[backend], observer, steps, args.repeat)
            rows.append((label, m))
    print(f"building, steps {args.steps} over {args.t_end:g} s: {len(steps)} steps; CPU time per step, "
          f"median of {args.repeat} side-by-side runs")
    print()
    print("| pair | FMI calls a step | bare calls, fmpy's functions (µs) | bare calls, master's prototypes (µs) "
          "| master loop (µs) | master steps (µs) | steps / bare fmpy | steps / bare prototypes "
          "| whole `cosimulate` (µs a step) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for label, m in rows:
        print(f"| {label} | {m['calls']} | {m['bare']:.1f} | {m['bare_addresses']:.1f} | {m['loop']:.1f} | "
              f"{m['steps']:.1f} | {m['steps'] / m['bare']:.2f} | {m['steps'] / m['bare_addresses']:.2f} | "
              f"{m['total']:.0f} |")
    print()
    print("The native loop against the Python loop (a worker's run: FMUs kept, card read once; CPU ms a run)")
    print()
    print("| pair | stepped in C | Python loop (µs) | native loop (µs) | loop ratio | Python steps (µs) "
          "| native steps (µs) | steps ratio | worker run, Python (ms) | worker run, native (ms) | worker ratio |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for label, m in rows:
        print(f"| {label} | {'yes' if m['native'] else 'no (pythonfmu)'} | {m['loop']:.2f} | {m['native_loop']:.2f} | "
              f"{m['loop'] / m['native_loop']:.1f}x | {m['steps']:.2f} | {m['native_steps']:.2f} | "
              f"{m['steps'] / m['native_steps']:.1f}x | {m['worker']:.2f} | {m['native_worker']:.2f} | "
              f"{m['worker'] / m['native_worker']:.2f}x |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
