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


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=20000)
    n = parser.parse_args().steps
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
    us = lambda v: f"{v * 1e6:8.3f}" if v is not None else "     n/a"  # noqa: E731
    print(f"per fmi2DoStep, median of 5 runs ({n} steps through fmpy, {10 * n} through the C host), in µs")
    for what, table in (("observer", rows), ("plant", plants)):
        print(f"{what:36s} {'importer':8s} {'C FMU':>8s} {'floor':>8s} {'python':>8s}  C/floor  python/C")
        for r in table:
            for imp in ("fmpy", "host"):
                c, f, p = r[f"c_{imp}"], r[f"floor_{imp}"], r[f"py_{imp}"]
                ratio = f"{p / c:8.1f}" if p else "     n/a"
                print(f"{r['case']:36s} {imp:8s} {us(c)} {us(f)} {us(p)}  {c / f:7.2f}  {ratio}")


if __name__ == "__main__":
    main()
