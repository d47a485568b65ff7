"""A validation suite for an observer FMU: copy this file into your project's tests and edit PROBLEM.

Run it with ``pytest test_my_observer.py``. It designs the problem, builds the observer and plant
FMUs once per session into a temporary folder (fixture ``uiofmu_fmus``), and checks, driven by fmpy
through uiofmu's co-simulation master, for each of three seeds (a random initial estimation error
drawn from the seed; with a random step SPEC, the steps too):

- the estimation error falls to 1 % of its initial norm within three quarters of the run;
- it stays inside the certified bound of the design card at every step;
- the observer FMU computes exactly what the reference runtime of the card computes.

To check FMUs you already have (built elsewhere, or shipped to you), pass their paths to the
assertions instead of using the fixture, and the card you keep under version control as
``card=`` of ``assert_matches_runtime``. ``UIOFMU_SEEDS=0-9 pytest ...`` runs the tests that take
``uiofmu_seed`` without parametrising it over those seeds.
"""

from pathlib import Path

import pytest

from uiofmu.testing import assert_bound_respected, assert_converges, assert_matches_runtime

pytest_plugins = ["uiofmu.testing"]          # the fixtures uiofmu_seed and uiofmu_fmus

PROBLEM = Path(__file__).with_name("seed000_example1.toml")   # your problem file
STEPS = None          # the steps the observer is designed for; or a SPEC such as "dropout:600:0.3:11"
SEEDS = [0, 1, 2]


@pytest.fixture(scope="session")
def fmus(uiofmu_fmus):
    """The designed card and the observer and plant FMUs of PROBLEM (built once per session)."""
    return uiofmu_fmus(PROBLEM)


@pytest.mark.parametrize("uiofmu_seed", SEEDS)
def test_converges(fmus, uiofmu_seed):
    assert_converges(fmus.observer, fmus.plant, steps=STEPS, within=0.75, seed=uiofmu_seed, xhat0_error=0.5)


@pytest.mark.parametrize("uiofmu_seed", SEEDS)
def test_bound_respected(fmus, uiofmu_seed):
    assert_bound_respected(fmus.observer, fmus.plant, steps=STEPS, seed=uiofmu_seed, xhat0_error=0.5)


@pytest.mark.parametrize("uiofmu_seed", SEEDS)
def test_matches_runtime(fmus, uiofmu_seed):
    assert_matches_runtime(fmus.observer, card=fmus.card_path, steps=200, seed=uiofmu_seed)
