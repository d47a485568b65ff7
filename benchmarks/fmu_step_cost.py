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

Last, the building's whole observer step as a master makes it, in a C host (benchmarks/observer_step.c:
fmi2SetReal of y and u, fmi2GetReal of xhat, r and dhat, fmi2DoStep, on 1000 random aperiodic steps
played over and over): the process CPU time per step (median of 5 runs, the C sources of
``--reference``, the commit before the step was made lean, alternating with today's in the same run),
the instructions per step where valgrind is installed (callgrind, the timed passes only), and the
ratio to the step's own arithmetic at 1 flop/ns: its flops counted from the design's sizes
(:func:`step_flops`; goal: within 1.5x). Both builds run the same design data, and their outputs are
compared bit for bit. ``--host-step-only`` runs this part alone.
"""

from __future__ import annotations

import argparse
import os
import shutil
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
from uiofmu.fmu.c_backend import (build_c_observer, build_c_plant, build_host, c_compiler, fmi_headers,  # noqa: E402
                                   rebuild_c_fmu)
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


#: The C sources before the observer step was made lean (xhat computed twice a step, every matrix
#: looked up by its schedule, every element's checks in turn).
REFERENCE = "a3d145ba2275e44649a75706c549f998693cfeef"
C_DIR = "uiofmu/fmu/c"


def step_flops(dims: dict, has_dhat: bool) -> int:
    """Flops of one observer step of the affine kernel (outputs and doStep), counted from its sizes: an
    r x c product costs r c multiplications and r (c - 1) additions, a vector sum or difference one per
    element.

    xhat = Xz z + Xy y, r = y - C xhat, dhat = Dy (y - pred), pred = Yx xhat + Yu u + Yc,
    z = N z + L y + G u + c.
    """
    n, m, p, q, nz = (dims[k] for k in ("n", "m", "p", "q", "nz"))

    def product(rows, cols):
        return rows * (2 * cols - 1) if cols else 0

    def plus(rows, cols):   # adding an r x c product to a vector
        return product(rows, cols) + (rows if cols else 0)

    flops = product(n, nz) + plus(n, p) + product(p, n) + p
    if has_dhat:
        flops += p + product(q, p) + product(p, n) + plus(p, m) + p
    return flops + product(nz, nz) + plus(nz, p) + plus(nz, m) + nz


def git_sources(rev: str) -> dict | None:
    """``{name: text}`` of the C sources at ``rev``, or None (no git, or no such commit)."""
    def git(*args):
        return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, check=True).stdout

    try:
        names = git("ls-tree", "--name-only", f"{rev}:{C_DIR}").split()
        return {name: git("show", f"{rev}:{C_DIR}/{name}") for name in names}
    except (OSError, subprocess.CalledProcessError):
        return None


def step_host(tmp) -> Path:
    """benchmarks/observer_step.c compiled."""
    exe = Path(tmp) / "observer_step"
    subprocess.run([c_compiler(), "-std=c99", "-O2", f"-I{fmi_headers()}", "-o", str(exe),
                    str(ROOT / "benchmarks" / "observer_step.c"), "-ldl"], check=True)
    return exe


def step_run(host, fmu: Path, plan: Path, repeat: int, tmp, callgrind: bool = False):
    """(CPU ns a step, the first pass's outputs) of one run of the C host, or with ``callgrind`` the
    instructions a step of its timed passes."""
    unzip = Path(tmp) / f"{fmu.stem}_x"
    if not unzip.exists():
        with zipfile.ZipFile(fmu) as z:
            z.extractall(unzip)
    md = read_model_description(str(fmu))
    lib = unzip / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so"
    refs = lambda causality: ",".join(str(v.valueReference) for v in md.modelVariables  # noqa: E731
                                      if v.causality == causality)
    args = [str(host), str(lib), md.guid, refs("input"), refs("output"), str(plan), str(repeat)]
    if callgrind:
        out = Path(tmp) / f"{fmu.stem}.callgrind"
        proc = subprocess.run(["valgrind", "--tool=callgrind", "--toggle-collect=run_passes",
                               f"--callgrind-out-file={out}", *args], capture_output=True, text=True)
        steps = [float(line.split()[1]) for line in proc.stderr.splitlines() if line.startswith("steps ")]
        events = [line for line in out.read_text().splitlines() if line.startswith("summary:")]
        return int(events[0].split()[1]) / steps[0] if steps and events else None
    proc = subprocess.run(args, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"{lib.name} in the C host: {proc.stderr.strip()[-300:]}")
    cpu = [float(line.split()[1]) for line in proc.stderr.splitlines() if line.startswith("cpu_ns_per_step")]
    return cpu[0], proc.stdout


def host_step(reference: str, tmp) -> None:
    """The building's observer step in a C host, today's C sources against ``reference``'s."""
    card = uiofmu.design(uiofmu.load_problem(ROOT / "plants" / "two_room_building"))
    now = build_observer(card, Path(tmp) / "step_now.fmu", backend="c")
    sources = git_sources(reference)
    builds = {"current": now}
    if sources is None:
        print(f"note: no git history with {reference}: the current C sources alone", file=sys.stderr)
    else:
        with zipfile.ZipFile(now) as z:
            carried = {name[len("sources/"):] for name in z.namelist() if name.startswith("sources/")}
        builds = {f"{reference[:7]} (before)": rebuild_c_fmu(now, Path(tmp) / "step_reference.fmu",
                                                             {k: v for k, v in sources.items() if k in carried}),
                  **builds}
    steps = uiofmu.Runtime(card).schedule.admissible_steps()
    md = read_model_description(str(now))
    width = sum(v.causality == "input" for v in md.modelVariables)
    rng = np.random.default_rng(11)
    plan = Path(tmp) / "step_plan.txt"
    plan.write_text("".join(" ".join(repr(float(v)) for v in (steps[rng.integers(len(steps))], *rng.normal(size=width)))
                            + "\n" for _ in range(1000)))
    host = step_host(tmp)
    cpu = {label: [] for label in builds}
    shown = {}
    for _ in range(5):                      # alternating, so that both see the same load
        for label, fmu in builds.items():
            ns, text = step_run(host, fmu, plan, 1000, tmp)
            cpu[label].append(ns)
            shown[label] = text
    grind = shutil.which("valgrind") is not None
    flops = step_flops(card.data["dims"], card.has_dhat)
    print(f"\nthe building's observer step in a C host (fmi2SetReal y, u; fmi2GetReal xhat, r, dhat; fmi2DoStep), "
          f"{flops} flops; CPU time, median of 5 runs of 1e6 steps")
    print(f"{'C sources':22s} {'CPU ns/step':>11s} {'instructions/step':>17s} {'ns/flop (goal <= 1.5)':>22s}")
    for label, fmu in builds.items():
        ns = statistics.median(cpu[label])
        ir = step_run(host, fmu, plan, 5, tmp, callgrind=True) if grind else None
        print(f"{label:22s} {ns:11.1f} {f'{ir:.0f}' if ir else 'n/a':>17s} {ns / flops:22.2f}")
    if len(shown) > 1:
        same = len(set(shown.values())) == 1
        print(f"outputs of the first 1000 steps: {'equal bit for bit' if same else 'DIFFERENT'}")


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
    parser.add_argument("--reference", default=REFERENCE, help="the git revision of the C sources to compare with")
    parser.add_argument("--host-step-only", action="store_true", help="only the observer step in a C host")
    args = parser.parse_args()
    n = args.steps
    if args.host_step_only:
        with tempfile.TemporaryDirectory() as tmp:
            host_step(args.reference, tmp)
        return
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
    with tempfile.TemporaryDirectory() as tmp:
        host_step(args.reference, tmp)


if __name__ == "__main__":
    main()
