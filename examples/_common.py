"""Small helpers shared by the example scripts (paths, the design-build-run chain and figures).

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


def output_folder(name: str) -> Path:
    """The script's output folder ``OUT / name``, made if needed.

    Parameters
    ----------
    name : str
        The script's name.

    Returns
    -------
    Path
    """
    out = OUT / name
    out.mkdir(parents=True, exist_ok=True)
    return out


def pyplot():
    """matplotlib's pyplot on the Agg backend (the scripts write figures, they show none).

    Returns
    -------
    module
        ``matplotlib.pyplot``.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def panels(rows: int, figsize: tuple):
    """A figure of ``rows`` panels on top of each other, over one shared x axis.

    Parameters
    ----------
    rows : int
        The number of panels.
    figsize : tuple of float
        The figure's size in inches.

    Returns
    -------
    fig : Figure
    axes : ndarray of Axes
    """
    return pyplot().subplots(rows, 1, figsize=figsize, sharex=True, constrained_layout=True)


def savefig(fig, path) -> None:
    """Write the figure at 110 dpi and close it.

    Parameters
    ----------
    fig : Figure
    path : str or Path
        The file; its suffix gives the format.
    """
    fig.savefig(path, dpi=110)
    pyplot().close(fig)


def design_and_build(problem_path, out: Path):
    """Design a problem, build its observer and plant FMUs; return (problem, card, observer, plant)."""
    import uiofmu
    from uiofmu.fmu.export import build_observer, build_plant

    problem = uiofmu.load_problem(problem_path)
    card = uiofmu.design(problem)
    out.mkdir(parents=True, exist_ok=True)
    card.write(out / f"{problem.name}.design.json")
    obs = build_observer(card, out / f"{problem.name}_observer.fmu")
    plant = build_plant(problem.plant, problem.name, out / f"{problem.name}_plant.fmu",
                        experiment_steps=problem.experiment_steps)
    return problem, card, obs, plant


def main_guard(fn):
    """Run ``fn`` and turn uiofmu's user errors into exit code 2 with one line."""
    import uiofmu

    try:
        fn()
    except uiofmu.UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(2)
