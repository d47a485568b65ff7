"""The C observer step made lean gives the bits it gave before.

The plumbing and the kernels were reworked for speed (xhat computed once a step, the matrices found by
offsets, the design intervals bisected, set/get through the variables' storage). The numbers must not
move: an example card of each schedule kind the rework touched (:data:`PROBLEMS`) gets its C observer FMU
built twice from the same generated design data, once with today's C sources and once with those of
:data:`REFERENCE` (the commit before the rework), and both run the same random aperiodic plan (random
inputs, modes and design steps) from the same random ``xhat0``: every output at every point equal bit for
bit.
"""

from __future__ import annotations

import subprocess
import zipfile
from pathlib import Path

import numpy as np
import pytest

import uiofmu
from cfmu import NEEDS_CC
from test_conformance import drive, random_plan
from uiofmu.cosim.fmi import Fmu
from uiofmu.fmu import c_backend
from uiofmu.fmu.export import build_observer

ROOT = Path(__file__).resolve().parents[1]
C_DIR = "uiofmu/fmu/c"
#: The last commit whose C sources computed xhat twice a step and looked each matrix up by its schedule.
REFERENCE = "a3d145ba2275e44649a75706c549f998693cfeef"
#: One example problem per schedule kind of the reworked kernels (constant, geometric, interval, mode, the
#: window kernel) and the feedthrough term ``Xu``: what the rework touched, each once.
PROBLEMS = [ROOT / "examples" / name for name in (
    "seed000_example1.toml", "seed000_example1_ltv.toml", "seed002_three_modes.toml", "seed003_example.toml",
    "accelerometer_feedthrough.toml")] + [ROOT / "plants" / "two_room_building" / "problem.toml"]

def reference_sources() -> dict | None:
    """``{name: text}`` of the C sources at :data:`REFERENCE`, or None outside a git checkout holding it."""
    try:
        names = subprocess.run(["git", "ls-tree", "--name-only", f"{REFERENCE}:{C_DIR}"], cwd=ROOT,
                               capture_output=True, text=True, check=True).stdout.split()
        return {name: subprocess.run(["git", "show", f"{REFERENCE}:{C_DIR}/{name}"], cwd=ROOT, capture_output=True,
                                     text=True, check=True).stdout for name in names}
    except (OSError, subprocess.CalledProcessError):
        return None


SOURCES = reference_sources()
NEEDS_HISTORY = pytest.mark.skipif(SOURCES is None, reason=f"needs the git history with commit {REFERENCE[:12]}")


def outputs_of(path: Path, card, plan, xhat0) -> np.ndarray:
    with Fmu(path, "observer") as fmu:
        fmu.initialize(0.0, {"xhat0": xhat0} if fmu.has("xhat0") else None)
        return drive(fmu, None, card, plan)[0]


@NEEDS_CC
@NEEDS_HISTORY
@pytest.mark.parametrize("problem", PROBLEMS, ids=lambda p: str(p.relative_to(ROOT)))
def test_the_c_observer_gives_the_bits_of_the_reference_sources(problem, tmp_path):
    card = uiofmu.design(uiofmu.load_problem(problem))
    new = build_observer(card, tmp_path / "observer.fmu", backend="c")
    with zipfile.ZipFile(new) as z:
        carried = {name[len("sources/"):] for name in z.namelist() if name.startswith("sources/")}
    reference = {name: text for name, text in SOURCES.items() if name in carried}
    assert set(c_backend.c_sources(card)) - {"design_data.c"} <= set(reference), sorted(reference)
    old = c_backend.rebuild_c_fmu(new, tmp_path / "reference.fmu", reference)
    with Fmu(new, "probe") as fmu:
        inputs, n = fmu.ports("input"), len(fmu.refs("xhat0")) if fmu.has("xhat0") else 0
    plan = random_plan(card, inputs, 300, seed=13)
    xhat0 = np.random.default_rng(17).normal(size=n)
    got, want = outputs_of(new, card, plan, xhat0), outputs_of(old, card, plan, xhat0)
    assert np.all(np.isfinite(got)) and np.ptp(got) > 0, "a run that shows nothing"
    assert got.tobytes() == want.tobytes(), f"{problem.name}: largest difference {np.max(np.abs(got - want)):.3g}"
