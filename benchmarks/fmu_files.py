"""A co-simulation from the FMU files against one with the FMUs kept, side by side in one process.

    .venv/bin/python benchmarks/fmu_files.py [--repeat 15] [--t-end 840000] [--backend c]

The two-room building (``plants/two_room_building``) with its observer and plant FMUs under packet
drop-outs (``dropout:600:0.3:11``; t_end = 840,000 s is about 700 steps, a campaign's run). Alternately,
``--repeat`` times, CPU time of:

(a) kept: ``cosimulate(..., card=card, instances=(plant, observer))``, the FMUs loaded once and reset
    before each run (what a campaign worker does);
(b) files: ``cosimulate(plant.fmu, observer.fmu, ..., card=card)``, the FMUs instantiated from their files
    for every run (the card read once, as a loop over scenarios holds it);
(c) files, card from the FMU: ``cosimulate(plant.fmu, observer.fmu, ...)``, the public call with nothing
    but the paths (it also reads the card from the observer FMU);

and, as the anchor of what :mod:`uiofmu.cosim.fmu_cache` saves, (d) unpacking both FMUs into a new folder
and removing it again (what every run from the files paid before). The first run from the files (the
unpacking) is timed once. Medians; prints one JSON document with the ratios (b)/(a) and (c)/(a).
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import uiofmu  # noqa: E402
from uiofmu.cosim.fmi import Fmu  # noqa: E402
from uiofmu.cosim.master import cosimulate, observer_card  # noqa: E402
from uiofmu.cosim.steps import step_sequence  # noqa: E402
from uiofmu.fmu.export import build_observer, build_plant  # noqa: E402


def build(tmp: Path, backend: str) -> tuple[Path, Path]:
    """The building's observer and plant FMUs."""
    problem = uiofmu.load_problem(ROOT / "plants" / "two_room_building")
    card = uiofmu.design(problem)
    observer = build_observer(card, tmp / "observer.fmu", backend=backend)
    plant = build_plant(problem.plant, "building", tmp / "plant.fmu", backend=backend)
    return Path(plant), Path(observer)


def cpu(run) -> float:
    """CPU seconds of ``run()``."""
    t = time.process_time()
    run()
    return time.process_time() - t


def unpack_and_remove(paths) -> None:
    """What a run from the files paid before: each FMU unpacked into a new folder, removed at the end."""
    from fmpy import extract

    for path in paths:
        folder = tempfile.mkdtemp(prefix="uiofmu_bench_")
        extract(str(path), unzipdir=folder)
        shutil.rmtree(folder)


def main(argv=None) -> int:
    """Measure and print the numbers."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=15)
    parser.add_argument("--t-end", type=float, default=840_000.0)
    parser.add_argument("--steps", default="dropout:600:0.3:11")
    parser.add_argument("--backend", choices=["c", "python"], default="c")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        plant, observer = build(Path(tmp), args.backend)
        steps = step_sequence(args.steps, args.t_end, seed=0)
        first = cpu(lambda: cosimulate(plant, observer, steps, show_progress=False))    # unpacks both FMUs
        card = observer_card(observer)
        kept = (Fmu(plant, "plant"), Fmu(observer, "observer"))
        runs = {
            "kept": lambda: cosimulate(plant, observer, steps, card=card, instances=kept, show_progress=False),
            "files": lambda: cosimulate(plant, observer, steps, card=card, show_progress=False),
            "files_public": lambda: cosimulate(plant, observer, steps, show_progress=False),
            "unpack_and_remove": lambda: unpack_and_remove((plant, observer)),
        }
        times: dict = {name: [] for name in runs}
        for _ in range(args.repeat):
            for name, run in runs.items():
                times[name].append(cpu(run))
        for fmu in kept:
            fmu.close()
    med = {name: statistics.median(v) for name, v in times.items()}
    report = {
        "backend": args.backend, "steps": len(steps), "repeat": args.repeat,
        "first_run_from_files_ms": first * 1e3,
        **{f"{name}_ms": value * 1e3 for name, value in med.items()},
        "files_over_kept": med["files"] / med["kept"],
        "files_public_over_kept": med["files_public"] / med["kept"],
        "unpack_and_remove_over_kept": med["unpack_and_remove"] / med["kept"],
    }
    report["goal_files_within_1_5_of_kept"] = max(report["files_over_kept"], report["files_public_over_kept"]) <= 1.5
    print(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
