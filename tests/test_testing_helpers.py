"""uiofmu.testing: the assertions pass on the designed observer and fail, for the right reason and with a
message naming what was expected, what was measured and where, on observers built from cards whose gain
was perturbed; the example suite a user copies runs green as a pytest subprocess."""

from __future__ import annotations

import copy
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from tests.conftest import EXAMPLES
from uiofmu.fmu.export import build_observer
from uiofmu.runtime.card import card_from_data
from uiofmu.synthesis import recheck
from uiofmu.testing import (assert_bound_respected, assert_converges, assert_exact_functional, assert_matches_runtime,
                            build_fmus, certificate_problem, seeds_from_environment)

BACKEND = "python"      # the helpers' logic, away from C compiler timings; the example suite uses the default


@pytest.fixture(scope="session")
def right(tmp_path_factory):
    """Seed 000 Example 1: its designed card and its observer and plant FMUs."""
    return build_fmus(EXAMPLES / "seed000_example1.toml", tmp_path_factory.mktemp("right"), backend=BACKEND)


def _perturbed(card, dk: list, plant_too: bool, name: str) -> dict:
    """The card's data with the gain K changed by ``dk`` and N and L recomputed (N = PA - KC, L = K - NM): the
    identities hold, the Lyapunov check no longer does (a stale card). ``plant_too`` instead edits the card's
    plant model with it so that N stays and every check still holds: a certified observer of another plant.

    The card is renamed: pythonfmu imports an FMU's slave module by its model identifier, so two pythonfmu FMUs
    of one identifier do not load side by side in one process (uiofmu's guard refuses the second)."""
    data = copy.deepcopy(card.data)
    data["name"] = name
    m = {k: np.array(v, dtype=float) for k, v in data["matrices"].items()}
    m["K"] = m["K"] + np.array(dk)
    if plant_too:                     # P A' = P A + dK C keeps N = P A' - K' C; P = diag(0, 1) here
        m["A_sampled"] = m["A_sampled"] + np.array(dk) @ m["C"]
    else:
        m["N"] = m["P"] @ m["A_sampled"] - m["K"] @ m["C"]
    m["L"] = m["K"] - m["N"] @ m["M"]
    for key in ("K", "N", "L", "A_sampled"):
        data["matrices"][key] = m[key].tolist()
    return data


@pytest.fixture(scope="session")
def stale(right, tmp_path_factory):
    """An observer FMU whose card's gain was edited after the design: N gets the eigenvalue -1.2, the error
    diverges, and the certificate no longer holds (built directly, as uiofmu build re-checks and refuses)."""
    card = card_from_data(_perturbed(right.card, [[1.2], [0.0]], False, "stale"))
    assert "eig_min(rho^2 X - N'XN)" in certificate_problem(card)
    return build_observer(card, tmp_path_factory.mktemp("stale") / "stale.fmu", backend=BACKEND)


@pytest.fixture(scope="session")
def other_plant(right, tmp_path_factory):
    """An observer FMU from a card whose gain and plant model were edited together: certified, for a plant that
    is not the one simulated, so the master runs it and the error settles far from zero."""
    card = card_from_data(_perturbed(right.card, [[0.0], [0.3]], True, "other"))
    recheck(card)
    return build_observer(card, tmp_path_factory.mktemp("other") / "other.fmu", backend=BACKEND)


@pytest.mark.parametrize("seed", [0, 1])
def test_the_helpers_pass_on_the_designed_observer(right, seed):
    run = assert_converges(right.observer, right.plant, within=0.75, seed=seed, xhat0_error=0.5)
    assert run.certificate_problem is None and run.result.metrics["steps_to_1pct"] <= 0.75 * len(run.steps)
    run = assert_bound_respected(right.observer, right.plant, seed=seed, xhat0_error=0.5)
    assert run.result.metrics["bound_respected"] is True
    assert_matches_runtime(right.observer, seed=seed)
    assert_matches_runtime(right.observer, card=right.card_path, seed=seed)
    assert_matches_runtime(right.observer, card=right.card, steps=50, seed=seed)


def test_the_seed_draws_the_initial_error(right):
    e0 = [assert_converges(right.observer, right.plant, within=0.75, seed=s, xhat0_error=0.5).result.metrics[
        "initial_error_norm"] for s in (0, 1, 0)]
    assert e0[0] == e0[2] != e0[1]


def test_a_diverging_stale_observer_fails_convergence_with_what_it_measured(right, stale):
    with pytest.raises(AssertionError) as info:
        assert_converges(stale, right.plant, within=0.75)
    text = str(info.value)
    assert text.startswith("stale.fmu does not converge within 522 of 695 steps: expected ||x - xhat|| <= 0.01 x ")
    assert "from step 522 (t = 52.2 s) on; measured " in text and "it never gets there" in text
    assert "step 695 (t = 69.5 s)" in text and "[695 steps fixed:0.1, seed 0" in text
    assert "the certificate does not hold at the stored matrices: eig_min(rho^2 X - N'XN)" in text
    assert "uiofmu.testing's own loop" in text


def test_a_stale_observer_has_no_certified_bound_and_leaves_the_claimed_one(right, stale):
    with pytest.raises(AssertionError) as info:
        assert_bound_respected(stale, right.plant)
    text = str(info.value)
    assert text.startswith("stale.fmu: expected a certified bound (||e_k|| <= overshoot_bound * decay_bound**k")
    assert "so the card certifies no bound; measured against the bound it claims: the error leaves it at step 1 " \
           "(t = 0.1 s): ||x - xhat|| = " in text


def test_a_stale_observer_does_not_match_the_designed_card(right, stale):
    with pytest.raises(AssertionError) as info:
        assert_matches_runtime(stale, card=right.card_path)
    text = str(info.value)
    assert text.startswith("stale.fmu: expected the FMU to run the given card (seed000-example1); the card packed "
                           "in it differs in matrices.K by up to 1.2 (entry [0, 0]: FMU 1.2, card ")
    assert "matrices.N by up to 1.2 (entry [0, 0]: FMU -1.2, card " in text
    assert "its xhat parts from the card's runtime at step 1: FMU [" in text and "> rtol 1e-12)" in text
    with pytest.raises(AssertionError, match=r"^stale\.fmu: expected a reference card whose certificate holds; the "
                                             r"card packed in it: design card: the certificate does not hold"):
        assert_matches_runtime(stale)


def test_an_observer_certified_for_another_plant_fails_in_the_master_run(right, other_plant):
    with pytest.raises(AssertionError) as info:
        assert_converges(other_plant, right.plant, within=0.75)
    text = str(info.value)
    assert text.startswith("other.fmu does not converge within 522 of 695 steps") and "certificate" not in text
    with pytest.raises(AssertionError) as info:
        assert_bound_respected(other_plant, right.plant)
    text = str(info.value)
    assert text.startswith("other.fmu: expected ||x - xhat|| inside the certified bound (||e_k|| <= ")
    assert "the error leaves it at step 6 (t = 0.6 s): ||x - xhat|| = " in text and "largest ratio" in text
    assert "certificate" not in text
    assert_matches_runtime(other_plant)                # it computes what its own card says...
    with pytest.raises(AssertionError, match=r"differs in matrices\.A_sampled by up to 0\.3 .*matrices\.K by up to "
                                             r"0\.3 .*matrices\.L by up to 0\.3 .*parts from the card's runtime at "
                                             r"step 1"):
        assert_matches_runtime(other_plant, card=right.card)   # ...which is not the designed one


def test_within_and_the_kinds_of_observer(right):
    with pytest.raises(ValueError, match="within: a fraction of the run must be in"):
        assert_converges(right.observer, right.plant, within=1.5)
    with pytest.raises(AssertionError, match=r"does not converge within 10 of 695 steps"):
        assert_converges(right.observer, right.plant, within=10)
    with pytest.raises(AssertionError, match=r"expected a functional observer \(kernel window\), found a lti-uio"):
        assert_exact_functional(right.observer, right.plant)
    with pytest.raises(AssertionError, match=r"the co-simulation did not run to its end .*refused step 0"):
        assert_converges(right.observer, right.plant, steps="fixed:0.25", t_end=1.0)


def test_exact_functional_on_the_deadbeat_observer(tmp_path_factory):
    fmus = build_fmus(EXAMPLES / "seed003_example.toml", tmp_path_factory.mktemp("deadbeat"), backend=BACKEND)
    run = assert_exact_functional(fmus.observer, fmus.plant, t_end=12.0)
    assert run.result.metrics["exact_from_first_full_window"] is True
    with pytest.raises(AssertionError, match=r"expected a card with a certified error bound; the deadbeat-functional "
                                             r"card \(kernel window\) certifies none .*assert_exact_functional"):
        assert_bound_respected(fmus.observer, fmus.plant, t_end=12.0)


def test_seeds_from_the_environment(monkeypatch):
    monkeypatch.setenv("UIOFMU_SEEDS", "0-2,7")
    assert seeds_from_environment() == [0, 1, 2, 7]
    monkeypatch.setenv("UIOFMU_SEEDS", "a")
    with pytest.raises(ValueError, match="UIOFMU_SEEDS: expected seeds like"):
        seeds_from_environment()
    monkeypatch.delenv("UIOFMU_SEEDS")
    assert seeds_from_environment() == [0]


def test_the_seed_fixture_follows_the_environment(tmp_path):
    (tmp_path / "test_seeds.py").write_text(
        'import pytest\npytest_plugins = ["uiofmu.testing"]\n\n'
        "def test_default(uiofmu_seed):\n    assert isinstance(uiofmu_seed, int)\n\n"
        '@pytest.mark.parametrize("uiofmu_seed", [5, 6])\n'
        "def test_given(uiofmu_seed):\n    assert uiofmu_seed in (5, 6)\n")
    env = {**os.environ, "UIOFMU_SEEDS": "0-3"}
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "test_seeds.py"],
                          capture_output=True, text=True, cwd=tmp_path, env=env)
    assert proc.returncode == 0 and "6 passed" in proc.stdout and "warning" not in proc.stdout, proc.stdout


@pytest.mark.slow
def test_the_example_suite_runs_green_in_a_project_of_its_own(tmp_path):
    """A user copies examples/test_my_observer.py (and here its problem file) into a project and runs pytest."""
    for name in ("test_my_observer.py", "seed000_example1.toml"):
        shutil.copy(EXAMPLES / name, tmp_path / name)
    env = {k: v for k, v in os.environ.items() if k != "UIOFMU_SEEDS"}
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "test_my_observer.py"],
                          capture_output=True, text=True, cwd=tmp_path, env=env)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "9 passed" in proc.stdout and "warning" not in proc.stdout, proc.stdout
