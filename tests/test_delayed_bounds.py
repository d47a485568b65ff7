"""The delayed UIO's work is bounded before it starts: the premise grid, its simulation, the
substeps of one communication step; and a restored buffer cannot make a step fail unchecked."""

from __future__ import annotations

import copy
import re
import time
from pathlib import Path

import numpy as np
import pytest

from uiofmu.runtime.delayed import MAX_SUBSTEPS, DelayedRuntime
from uiofmu.runtime.schedules import StepRejected
from uiofmu.runtime.state import StateRejected

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = (ROOT / "examples" / "seed001_example.toml").read_text()


@pytest.mark.parametrize("old, new, says", [
    ("samples = 300", "samples = 100000", "= 600000 premise points, more than the 20000"),
    ("count = 6", "count = 100", "100 x 300 = 30000 premise points"),
    ("duration = 5.0", "duration = 1e9", "needs 4e+10 simulation steps"),
    ("delays = [0.5]", "delays = [1e-300]", "the shortest delay 1e-300 s needs 1e+302 simulation steps"),
])
def test_a_premise_beyond_the_limits_is_refused_before_any_work(old, new, says, tmp_path, cli):
    assert old in EXAMPLE
    path = tmp_path / "p.toml"
    path.write_text(EXAMPLE.replace(old, new))
    began = time.perf_counter()
    res = cli("check", path)
    assert res.code == 2 and says in res.err and len(res.err.strip().splitlines()) == 1, res
    assert time.perf_counter() - began < 5.0


def test_an_observer_step_beyond_the_substep_limit_is_refused_by_the_design(tmp_path, cli):
    path = tmp_path / "p.toml"
    path.write_text(EXAMPLE.replace("\ndt = 0.001", "\ndt = 10.0"))
    res = cli("design", path, "-o", tmp_path / "card.json")
    assert res.code == 2 and re.search(r"observer.dt: communication step h = 10 s needs \S+ RK4 substeps of the "
                                       r"observer \(at most \S+ s each\), more than the 10000", res.err), res
    assert not (tmp_path / "card.json").exists()


@pytest.fixture(scope="module")
def card():
    """The example's design card (designed once for the module)."""
    import uiofmu

    return uiofmu.design(uiofmu.load_problem(ROOT / "examples" / "seed001_example.toml"))


def _running(card):
    """The example's observer driven by its plant past its premise's start: running."""
    import uiofmu
    from uiofmu.runtime.parametric_plant import ParametricPlantRuntime

    problem = uiofmu.load_problem(ROOT / "examples" / "seed001_example.toml")
    plant = ParametricPlantRuntime(problem.plant.to_data())
    rt = DelayedRuntime(card)
    for k in range(int(round(card.schedule["valid_from"] / 1e-3)) + 100):
        plant.u[:] = [s(k * 1e-3) for s in problem.u]
        rt.set_y(plant.y())
        rt.set_ydot(plant.ydot())
        rt.set_u(plant.u)
        rt.step(1e-3)
        plant.step(1e-3)
    assert rt.running and rt.valid
    return rt


def test_a_long_step_is_refused_and_changes_nothing(card):
    rt = _running(card)
    before = rt.get_state()
    began = time.perf_counter()
    with pytest.raises(StepRejected, match=rf"more than the {MAX_SUBSTEPS} a step may take: take steps of at most"):
        rt.step(10.0)
    assert time.perf_counter() - began < 1.0 and rt.get_state() == before
    rt.step(1e-3)


def test_a_forged_buffer_of_huge_values_is_refused_never_an_internal_error(card):
    """Every entry of a restored buffer set to 1e308 (the red team's forged state): the state is refused, or
    the step that would overflow is refused with the state left as it was."""
    rt = _running(card)
    state = rt.get_state()
    outcomes = set()
    for i in range(len(state["buffer"])):
        forged = copy.deepcopy(state)
        forged["buffer"][i] = 1e308
        try:
            rt.set_state(forged)
        except StateRejected:
            outcomes.add("state refused")
            continue
        restored = rt.get_state()
        try:
            with np.errstate(all="ignore"):
                rt.step(1e-3)
            outcomes.add("stepped")
            assert all(np.all(np.isfinite(v)) for v in (rt.xhat(), rt.theta()))
        except StepRejected as exc:
            outcomes.add("step refused")
            assert "overflows" in str(exc) and rt.get_state() == restored
    # a huge buffer value puts ||Gamma|| far above the certified bound: the estimate is invalid and held, or the
    # step that would overflow is refused; either way nothing non-finite and no internal error
    assert outcomes <= {"state refused", "stepped", "step refused"} and outcomes, outcomes
