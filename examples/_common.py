"""Small helpers shared by the example scripts (paths and the design-build-run chain).

Each script writes into ``OUT / NAME``: ``OUT`` is the folder named by the environment variable
``UIOFMU_EXAMPLES_OUT`` when it is set (the tests point it at a temporary folder), else
``examples/out``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = Path(os.environ.get("UIOFMU_EXAMPLES_OUT") or ROOT / "examples" / "out").resolve()


def design_and_build(problem_path, out: Path):
    """Design a problem, build its observer and plant FMUs; return (problem, card, observer, plant)."""
    import uiofmu
    from uiofmu.fmu.export import build_observer, build_plant

    problem = uiofmu.load_problem(problem_path)
    card = uiofmu.design(problem)
    out.mkdir(parents=True, exist_ok=True)
    card.write(out / f"{problem.name}.design.json")
    obs = build_observer(card, out / f"{problem.name}_observer.fmu")
    plant = build_plant(problem.plant, problem.name, out / f"{problem.name}_plant.fmu")
    return problem, card, obs, plant


def main_guard(fn):
    """Run ``fn`` and turn uiofmu's user errors into exit code 2 with one line."""
    import uiofmu

    try:
        fn()
    except uiofmu.UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(2)
