"""Per-fmi2DoStep cost of the observer and plant FMUs, side by side in one run.

    .venv/bin/python benchmarks/fmu_step_cost.py [--steps 20000]

For the sampled-data observer of the two-room building (n = 2, 12 intervals, aperiodic steps)
and the LTV observer of seed 000 Example 1: the C observer FMU, the same C FMU whose doStep
returns at once (the FMI call floor), and the pythonfmu observer FMU; each through fmpy (ctypes)
and through uiofmu's C host (dlopen; for pythonfmu with libpython preloaded; the host times whole
passes of fmi2SetReal(y) + fmi2DoStep, so its floor includes the input call). Then the same for
the linear plant FMUs (``uiofmu plant --backend c`` against ``--backend python``): the continuous
plant of the two-room building on the observer's aperiodic steps (the exact discretisation of
each step length from the C plant's cache) and the discrete plant of seed 000 Example 1 at its
dt; their input is u. Median of 5 runs.

Then the delayed UIO of seed 001 (``examples/seed001_example.toml``), whose observer integrates itself
between communication points: its C FMU and its pythonfmu FMU fed the same plant signals (y, ydot, u of
the plant runtime at 1 ms steps) through fmpy; past the premise's start (1 s) the CPU time of
``--delayed-steps`` steps (fmi2SetReal of y, ydot, u and fmi2DoStep), per step, and python / C.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import sysconfig
import tempfile
import time
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
from fmpy import read_model_description  # noqa: E402

import uiofmu  # noqa: E402
from uiofmu.fmu.export import build_observer, build_plant, model_identifier  # noqa: E402
from uiofmu.fmu.c_backend import build_c_observer, build_c_plant, build_host  # noqa: E402
from uiofmu.cosim.fmi import Fmu  # noqa: E402


def via_fmpy(path, steps, n, port="y"):
    """Median seconds per doStep through fmpy's FMU2Slave (the input ``port`` set to ones)."""
    with Fmu(path, "bench") as fmu:
        fmu.initialize(0.0)
        fmu.set(port, np.ones(len(fmu.refs(port))))
        step = fmu.slave.doStep
        times = []
        for _ in range(5):
            t0 = time.perf_counter()
            for k in range(n):
                step(0.0, steps[k % len(steps)])
            times.append((time.perf_counter() - t0) / n)
    return statistics.median(times)


def via_host(path, steps, n, host, tmp, python=False, port="y"):
    """Median seconds per doStep through the C host (None when the host cannot load it)."""
    unzip = Path(tmp) / Path(path).stem
    with zipfile.ZipFile(path) as z:
        z.extractall(unzip)
    md = read_model_description(str(path))
    refs = {v.name: v.valueReference for v in md.modelVariables}
    file = Path(tmp) / f"{Path(path).stem}.txt"
    file.write_text("".join(f"{steps[k % len(steps)]!r} 1.0\n" for k in range(1000)))
    env = dict(os.environ)
    if python:   # a pythonfmu binary needs libpython in the process and the venv's packages
        env["LD_PRELOAD"] = str(Path(sysconfig.get_config_var("LIBDIR")) / sysconfig.get_config_var("INSTSONAME"))
        env["PYTHONHOME"] = sys.base_prefix
        env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p)
    lib = unzip / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so"
    times = []
    for _ in range(5):
        proc = subprocess.run([str(host), str(lib), md.guid, (unzip / "resources").as_uri(), str(refs[f"{port}[1]"]),
                               "-", str(file), str(max(2, n // 1000 + 1))], capture_output=True, text=True, env=env)
        timing = [line for line in proc.stderr.splitlines() if line.startswith("ns_per_step")]
        if not timing:
            print(f"{lib.name} in the C host: {proc.stderr.strip()[-300:]}", file=sys.stderr)
            return None
        if proc.returncode != 0:   # the steps were timed; a failure at unload is reported, not hidden
            print(f"note: {lib.name} ended the C host with status {proc.returncode} after its steps "
                  f"({proc.stderr.strip().splitlines()[-1]})", file=sys.stderr)
        times.append(float(timing[-1].split()[1]) * 1e-9)
    return statistics.median(times)


def plant_signals(problem, card, h: float, count: int) -> list:
    """``count`` points of the plant's signals at steps of ``h``: ``(y, ydot, u)`` with the problem's input (the
    ``[signals]`` its card records)."""
    from uiofmu.cosim.master import default_inputs
    from uiofmu.runtime.parametric_plant import ParametricPlantRuntime

    plant = ParametricPlantRuntime(problem.plant.to_data())
    source = default_inputs(card)
    points = []
    for k in range(count):
        plant.u[:] = source.values(k * h)["u"]
        points.append((plant.y().copy(), plant.ydot().copy(), plant.u.copy()))
        plant.step(h)
    return points


def delayed_cost(path, points, lead_in: int, h: float):
    """CPU seconds per step of the delayed observer FMU at ``path`` (inputs set, then fmi2DoStep) over the
    points after the first ``lead_in``, and the fraction of those steps it was valid at."""
    with Fmu(path, "bench") as fmu:
        fmu.initialize(0.0)
        refs = [fmu.refs(name) for name in ("y", "ydot", "u")]
        set_real, step, get_integer = fmu.slave.setReal, fmu.slave.doStep, fmu.slave.getInteger
        valid_ref = fmu.refs("valid")
        valid, t0 = 0, 0.0
        for k, values in enumerate(points):
            if k == lead_in:
                t0 = time.process_time()
            for ref, value in zip(refs, values):
                set_real(ref, value)
            step(k * h, h)
            if k >= lead_in:
                valid += get_integer(valid_ref)[0]
        spent = time.process_time() - t0
    timed = len(points) - lead_in
    return spent / timed, valid / timed


def delayed_row(tmp, n: int) -> dict:
    """The delayed UIO's observer, C against pythonfmu (:func:`delayed_cost`)."""
    problem = uiofmu.load_problem(ROOT / "examples" / "seed001_example.toml")
    card = uiofmu.design(problem)
    h = float(card.schedule["step"])
    lead_in = int(round(float(card.schedule["valid_from"]) / h)) + 50
    points = plant_signals(problem, card, h, lead_in + n)
    c = build_observer(card, Path(tmp) / f"{card.name}_c.fmu", backend="c")
    py = build_observer(card, Path(tmp) / f"{card.name}_py.fmu", backend="python")
    (c_cost, c_valid), (py_cost, py_valid) = (delayed_cost(p, points, lead_in, h) for p in (c, py))
    return {"case": f"{card.family} ({card.name})", "c": c_cost, "py": py_cost, "valid": (c_valid, py_valid),
            "from": lead_in * h, "steps": n, "h": h}


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=20000)
    parser.add_argument("--delayed-steps", type=int, default=500)
    args = parser.parse_args()
    n = args.steps
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        host = build_host(Path(tmp) / "host")
        for path in (ROOT / "plants" / "two_room_building", ROOT / "examples" / "seed000_example1_ltv.toml"):
            card = uiofmu.design(uiofmu.load_problem(path))
            steps = uiofmu.Runtime(card).schedule.admissible_steps()
            c = build_observer(card, Path(tmp) / f"{card.name}_c.fmu", backend="c")
            floor = build_c_observer(card, Path(tmp) / f"{card.name}_floor.fmu",
                                     model_identifier(card.name, "observer"), call_floor=True)
            py = build_observer(card, Path(tmp) / f"{card.name}_py.fmu", backend="python")
            r = {"case": f"{card.family} ({card.name})"}
            r["c_fmpy"], r["floor_fmpy"], r["py_fmpy"] = (via_fmpy(p, steps, n) for p in (c, floor, py))
            r["c_host"], r["floor_host"] = (via_host(p, steps, n * 10, host, tmp) for p in (c, floor))
            r["py_host"] = via_host(py, steps, n, host, tmp, python=True)
            rows.append(r)
        plants = []
        for path in (ROOT / "plants" / "two_room_building", ROOT / "examples" / "seed000_example1.toml"):
            problem = uiofmu.load_problem(path)
            plant = problem.plant
            card = uiofmu.design(problem) if plant.continuous else None
            steps = uiofmu.Runtime(card).schedule.admissible_steps() if card else [plant.dt]
            c = build_plant(plant, problem.name, Path(tmp) / f"{problem.name}_plant_c.fmu", backend="c")
            floor = build_c_plant(plant, Path(tmp) / f"{problem.name}_plant_floor.fmu",
                                  model_identifier(problem.name, "plant"), call_floor=True)
            py = build_plant(plant, problem.name, Path(tmp) / f"{problem.name}_plant_py.fmu", backend="python")
            r = {"case": f"{plant.time} plant ({problem.name})"}
            r["c_fmpy"], r["floor_fmpy"], r["py_fmpy"] = (via_fmpy(p, steps, n, "u") for p in (c, floor, py))
            r["c_host"], r["floor_host"] = (via_host(p, steps, n * 10, host, tmp, port="u") for p in (c, floor))
            r["py_host"] = via_host(py, steps, n, host, tmp, python=True, port="u")
            plants.append(r)
        delayed = delayed_row(tmp, args.delayed_steps)
    us = lambda v: f"{v * 1e6:8.3f}" if v is not None else "     n/a"  # noqa: E731
    print(f"per fmi2DoStep, median of 5 runs ({n} steps through fmpy, {10 * n} through the C host), in µs")
    for what, table in (("observer", rows), ("plant", plants)):
        print(f"{what:36s} {'importer':8s} {'C FMU':>8s} {'floor':>8s} {'python':>8s}  C/floor  python/C")
        for r in table:
            for imp in ("fmpy", "host"):
                c, f, p = r[f"c_{imp}"], r[f"floor_{imp}"], r[f"py_{imp}"]
                ratio = f"{p / c:8.1f}" if p else "     n/a"
                print(f"{r['case']:36s} {imp:8s} {us(c)} {us(f)} {us(p)}  {c / f:7.2f}  {ratio}")
    d = delayed
    print(f"\ndelayed observer: CPU per step (fmi2SetReal of y, ydot, u + fmi2DoStep of {d['h']:g} s) through fmpy, "
          f"{d['steps']} steps from t = {d['from']:g} s (valid at {d['valid'][0]:.0%} of them in C, "
          f"{d['valid'][1]:.0%} in python), in µs")
    print(f"{'observer':36s} {'C FMU':>10s} {'python':>10s}  python/C")
    print(f"{d['case']:36s} {d['c'] * 1e6:10.1f} {d['py'] * 1e6:10.1f}  {d['py'] / d['c']:8.1f}")


if __name__ == "__main__":
    main()
