"""Small helpers shared by the example scripts (paths and the design-build-run chain)."""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "examples" / "out"


def design_and_build(problem_path, out: Path):
    """Design a problem, build its observer and plant FMUs; return (problem, card, observer, plant)."""
    import uiofmu
    from uiofmu.export import build_observer, build_plant

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
