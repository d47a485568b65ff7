"""Large gains: ``design`` prints the largest gain and warns when it is large against the plant;
``observer.gain_cap`` bounds it in every family's design (an LMI of the system, so a ``"max"`` search
finds the best value within the cap), and ``verify`` refuses a card whose gain exceeds its cap."""

from __future__ import annotations

import copy
import json
import tomllib
from pathlib import Path

import pytest

import uiofmu
from uiofmu.certificate import figure_text
from uiofmu.gains import GAIN_DIGITS, LARGE_GAIN_RATIO, gain_figures
from uiofmu.problem import problem_from_data
from uiofmu.runtime.card import card_from_data
from uiofmu.runtime.errors import CardError, InfeasibleError
from uiofmu.synthesis import recheck, verify

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def three_tanks(family: str, **observer) -> dict:
    """Three tanks in a row, the middle one coupled to the outer two by 1e-5 only: the leak (the unknown
    input) enters tank 1, tanks 1 and 3 are measured, and tank 2 is seen only through that weak coupling."""
    plant = {"time": "continuous", "A": [[-0.5, 0.5, 0.0], [0.5, -0.50001, 1e-5], [0.0, 1e-5, -0.101]],
             "B": [[1.0], [0.0], [0.0]], "E": [[1.0], [0.0], [0.0]], "C": [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]}
    return {"name": "three-tanks", "plant": plant, "observer": {"family": family, **observer}}


def example(name: str, **observer) -> dict:
    doc = tomllib.loads((EXAMPLES / f"{name}.toml").read_text())
    doc["observer"].update(observer)
    return doc


def design(doc: dict):
    return uiofmu.design(problem_from_data(copy.deepcopy(doc)))


def largest(card) -> float:
    return gain_figures(card.data)[0]


CAPPED = [  # (problem without a cap, the cap): the design without it has a larger gain
    pytest.param(three_tanks("lti-uio", dt=1.0, decay="max"), 1.0, id="lti-uio"),
    pytest.param(three_tanks("sampled-data", intervals=[1.0], alpha="max"), 1000.0, id="sampled-data"),
    pytest.param(example("seed000_example1_ltv", mu="max"), 0.8, id="ltv-auid"),
    pytest.param(example("seed002_three_modes"), 0.3, id="switched"),
]


@pytest.mark.parametrize("doc, cap", CAPPED)
def test_the_cap_bounds_the_gain_of_every_lmi_family(doc, cap):
    free = design(doc)
    assert largest(free) > cap
    capped_doc = copy.deepcopy(doc)
    capped_doc["observer"]["gain_cap"] = cap
    capped = design(capped_doc)
    assert capped.data["certificate"]["verified"] is True
    assert largest(capped) <= cap
    checks = recheck(capped)
    assert any(c.name.startswith("largest gain") and c.holds for c in checks)


def test_the_cap_costs_decay_on_a_weakly_observable_plant():
    free = design(three_tanks("sampled-data", intervals=[1.0], alpha="max"))
    capped = design(three_tanks("sampled-data", intervals=[1.0], alpha="max", gain_cap=1000.0))
    assert largest(free) > 1e4 and free.data["decay_bound"] < 0.05
    assert largest(capped) <= 1000.0
    # the weak mode near 0.6127 (tank 2 seen through 1e-5) is what the gain moved, and now stays
    assert 0.5 < capped.data["decay_bound"] < 0.6127


def test_switched_auto_leaves_dead_beat_for_the_lmi_when_its_gain_exceeds_the_cap():
    doc = example("seed002_setup2")
    free = design(doc)
    assert free.data["design_method"] == "deadbeat" and largest(free) > 1.0
    capped = design(example("seed002_setup2", gain_cap=1.0))
    assert capped.data["design_method"] == "lmi" and largest(capped) <= 1.0
    assert capped.data["decay_bound"] > free.data["decay_bound"]


def test_deadbeat_functional_refuses_a_formula_above_the_cap(tmp_path, cli):
    doc = example("seed003_example", gain_cap=5.0)
    with pytest.raises(InfeasibleError, match=r"largest gain \(2-norm\) 11\.18.* exceeds observer.gain_cap = 5"):
        design(doc)
    assert largest(design(example("seed003_example", gain_cap=12.0))) <= 12.0
    path = tmp_path / "p.toml"
    path.write_text(uiofmu.problem.to_toml(doc))
    result = cli("design", path, "-o", tmp_path / "c.json")
    assert result.code == 2 and "gain_cap = 5" in result.err and "Traceback" not in result.err


def test_a_cap_the_lmis_cannot_meet_says_so():
    with pytest.raises(InfeasibleError, match="observer.gain_cap = 0.8"):
        design(example("seed000_example1_ltv", gain_cap=0.8))             # mu = 90 fixed: no room


def test_verify_refuses_a_card_whose_gain_exceeds_its_cap(tmp_path, cli):
    card = design(three_tanks("lti-uio", dt=1.0, decay="max", gain_cap=100.0))
    gain = largest(card)
    data = json.loads(json.dumps(card.data))
    data["problem"]["observer"]["gain_cap"] = 0.5 * gain
    forged = card_from_data(data)
    failed = [c for c in verify(forged) if not c.holds]
    assert [c.name for c in failed] == [f"largest gain (2-norm) <= observer.gain_cap = {0.5 * gain:g}"]
    with pytest.raises(CardError, match="largest gain"):
        recheck(forged)
    path = tmp_path / "forged.json"
    forged.write(path)
    result = cli("verify", path)
    assert result.code == 2 and "largest gain" in result.err


def test_design_prints_the_largest_gain_and_warns_when_it_is_large(tmp_path, cli):
    path = tmp_path / "tanks.toml"
    path.write_text(uiofmu.problem.to_toml(three_tanks("sampled-data", intervals=[1.0], alpha="max")))
    result = cli("design", path, "-o", tmp_path / "c.json")
    assert result.code == 0
    line = next(ln for ln in result.out.splitlines() if ln.startswith("  largest gain"))
    gain, ratio = gain_figures(json.loads((tmp_path / "c.json").read_text()))
    assert f"largest gain     {figure_text(gain, GAIN_DIGITS)} (2-norm" in line and ratio > LARGE_GAIN_RATIO
    assert any(ln.startswith("  [warning] the gain is large") and "gain_cap" in ln for ln in result.out.splitlines())
    path.write_text(uiofmu.problem.to_toml(three_tanks("sampled-data", intervals=[1.0], alpha="max",
                                                       gain_cap=100.0)))
    result = cli("design", path, "-o", tmp_path / "c.json")
    assert result.code == 0 and "[warning]" not in result.out and "gain_cap 100" in result.out


def test_gain_cap_must_be_positive():
    with pytest.raises(uiofmu.runtime.errors.ProblemError, match="observer.gain_cap"):
        problem_from_data(three_tanks("lti-uio", dt=1.0, gain_cap=0.0))
