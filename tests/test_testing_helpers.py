"""uiofmu.testing: the assertions pass on the designed observer and fail, for the right reason and with a
message naming what was expected, what was measured and where, on observers built from cards whose gain
was perturbed; the example suite a user copies runs green as a pytest subprocess."""

from __future__ import annotations

import copy
import os
import shutil
import subprocess
import sys
import tracemalloc
import warnings

import numpy as np
import pytest

from tests.conftest import EXAMPLES
from uiofmu.existence import complex_list
from uiofmu.families import lti_uio
from uiofmu.fmu.export import build_observer
from uiofmu.problem import problem_from_data
from uiofmu.scaling import state_scaling
from uiofmu.scaling import to_data as scaling_data
from uiofmu.runtime.card import card_from_data, to_lists
from uiofmu.synthesis import recheck
from uiofmu.testing import (MAX_SEEDS, assert_bound_respected, assert_converges, assert_exact_functional,
                            assert_noise_gain_respected,
                            assert_matches_runtime, build_fmus, certificate_problem, seeds_from_environment)

BACKEND = "python"      # the helpers' logic, away from C compiler timings; the example suite uses the default


@pytest.fixture(scope="session")
def right(tmp_path_factory):
    """Seed 000 Example 1: its designed card and its observer and plant FMUs."""
    return build_fmus(EXAMPLES / "seed000_example1.toml", tmp_path_factory.mktemp("right"), backend=BACKEND)


def _perturbed(card, dk: list, plant_too: bool, name: str) -> dict:
    """The card's data with the gain K changed by ``dk`` and N and L recomputed (N = PA - KC, L = K - NM): the
    identities hold, the Lyapunov check no longer does (a stale card). ``plant_too`` instead edits the card's
    plant model with it (and the plant of the problem the card records, so that the card is what its problem
    determines) so that N stays and every check still holds: a certified observer of another plant.

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
    if plant_too:                     # a discrete plant: its A is the sampled one
        data["problem"]["plant"]["A"] = m["A_sampled"].tolist()
    # what the card lists of its plant and of N, made to match as well (a consistent card)
    problem = problem_from_data(data["problem"])
    analysis = lti_uio.analyse(problem)
    data["scaling"] = scaling_data(state_scaling(problem.plant.A, problem.options.scaling), problem.options.scaling)
    eig = np.linalg.eigvals(m["N"])
    data.update(existence=analysis.existence.to_data(), fixed_modes=complex_list(analysis.data["fixed"]),
                invariant_zeros=analysis.existence.value("stable invariant zeros", "zeros"),
                eigenvalues_N=complex_list(eig), spectral_radius_N=float(np.abs(eig).max()),
                noise=to_lists(lti_uio.noise_section(m)))         # the noise gains of the edited L
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


def test_the_noise_gain_helper_measures_below_the_certified_gain_and_names_a_card_without_one(right, deadbeat,
                                                                                          tmp_path):
    run = assert_noise_gain_respected(right.observer, right.plant, noise_std=0.05, seed=3)
    m = run.result.metrics
    assert 0 < m["noise_gain_measured"] <= m["noise_gain_certified"] == right.card.data["noise"]["gain_y"]
    with pytest.raises(ValueError, match="noise_std"):
        assert_noise_gain_respected(right.observer, right.plant, noise_std=-1.0)
    data = {k: v for k, v in right.card.data.items() if k != "noise"}        # a card from before noise gains
    old = build_observer(card_from_data(data), tmp_path / "old.fmu", backend=BACKEND)
    with pytest.raises(AssertionError, match="certifies none .it has no noise section"):
        assert_noise_gain_respected(old, right.plant)


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


@pytest.fixture(scope="session")
def deadbeat(tmp_path_factory):
    """Seed 003: a dead-beat functional observer (kernel window, a window of 4 samples) and its plant."""
    return build_fmus(EXAMPLES / "seed003_example.toml", tmp_path_factory.mktemp("deadbeat"), backend=BACKEND)


def test_exact_functional_on_the_deadbeat_observer(deadbeat):
    fmus = deadbeat
    run = assert_exact_functional(fmus.observer, fmus.plant, t_end=12.0)
    assert run.result.metrics["exact_from_first_full_window"] is True
    with pytest.raises(AssertionError, match=r"expected a card with a certified error bound; the deadbeat-functional "
                                             r"card \(kernel window\) certifies none .*assert_exact_functional"):
        assert_bound_respected(fmus.observer, fmus.plant, t_end=12.0)


def test_seeds_from_the_environment(monkeypatch):
    monkeypatch.setenv("UIOFMU_SEEDS", "0-2,7")
    assert seeds_from_environment() == [0, 1, 2, 7]
    monkeypatch.setenv("UIOFMU_SEEDS", "a")
    with pytest.raises(ValueError, match="UIOFMU_SEEDS='a': 'a' is not a seed or a range LO-HI; expected seeds and"):
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


# What the red team found: ways for a validation test to pass without checking anything.

@pytest.mark.parametrize("value, problem", [
    ("5-1", "the range 5-1 names no seed (it runs backwards)"),
    ("a-b", "'a-b' is not a seed or a range LO-HI"),
    ("1-", "'1-' is not a seed or a range LO-HI"),
    ("-3", "'-3' is not a seed or a range LO-HI"),
    ("1.5", "'1.5' is not a seed or a range LO-HI"),
    ("0-1.5", "'0-1.5' is not a seed or a range LO-HI"),
    ("+3", "'+3' is not a seed or a range LO-HI"),
    ("1_0", "'1_0' is not a seed or a range LO-HI"),               # int() would take it
    ("\u0663", "'\u0663' is not a seed or a range LO-HI"),          # an Arabic-Indic 3: int() would take it
    ("1,,2", "an empty item"),
    ("0,", "an empty item"),
    ("99999999999", "99999999999 is above the largest seed 4294967295"),
    ("0-" + "9" * 5000, "999999999999999999999999... is above the largest seed 4294967295"),
    ("0-3,2", "seed 2 is named twice"),
])
def test_a_seed_list_that_names_no_seed_or_is_malformed_is_an_error(monkeypatch, value, problem):
    monkeypatch.setenv("UIOFMU_SEEDS", value)
    with pytest.raises(ValueError) as info:
        seeds_from_environment()
    text = str(info.value)
    shown = repr(value) if len(value) <= 80 else repr(value[:77] + "...")
    assert text.startswith(f"UIOFMU_SEEDS={shown}: {problem}; expected seeds and inclusive ranges LO-HI with LO <= "
                           "HI, separated by commas"), text
    assert "integers from 0 to 4294967295, each seed once, at most 10000 seeds in all" in text


def test_seed_lists_that_are_well_formed(monkeypatch):
    for value, seeds in ((" 3 , 4-5 ", [3, 4, 5]), ("5-5", [5]), ("9,0-1", [9, 0, 1]), ("007", [7]),
                         ("4294967295", [4294967295]), ("   ", [0])):
        monkeypatch.setenv("UIOFMU_SEEDS", value)
        assert seeds_from_environment() == seeds, value


def test_a_seed_range_above_the_limit_is_refused_before_any_list_is_made(monkeypatch):
    """0-3000000 used to make a list of 3 million seeds (120 MB) and then 3 million pytest items (8.5 GB)."""
    monkeypatch.setenv("UIOFMU_SEEDS", f"0-{MAX_SEEDS - 1}")
    assert seeds_from_environment() == list(range(MAX_SEEDS))
    for value, count in (("0-3000000", 3000001), (f"0-{MAX_SEEDS}", MAX_SEEDS + 1), ("0-4294967295", 2**32),
                         ("7," + ",".join(["1-9999"] * 2), 19999)):
        monkeypatch.setenv("UIOFMU_SEEDS", value)
        tracemalloc.start()
        try:
            with pytest.raises(ValueError, match=rf"{count} seeds, more than 10000 \(each costs every test taking "
                                                 r"uiofmu_seed a run and about 5 KB of pytest's memory\)"):
                seeds_from_environment()
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert peak < 100_000, (value, peak)
    monkeypatch.setenv("UIOFMU_SEEDS", ",".join(["1"] * (MAX_SEEDS + 1)))
    with pytest.raises(ValueError, match=r"10001 items, more than 10000 seeds"):
        seeds_from_environment()


def test_a_seed_list_that_names_no_seed_fails_the_run_instead_of_skipping_it(tmp_path):
    """An inverted range used to parametrise with no seed: pytest skipped the (failing) test and exited 0. The
    fixture parametrised (indirectly) with 1.5 used to give seed 1."""
    (tmp_path / "test_env.py").write_text('pytest_plugins = ["uiofmu.testing"]\n\n'
                                          "def test_fails(uiofmu_seed):\n    assert False\n")
    (tmp_path / "test_given.py").write_text('import pytest\npytest_plugins = ["uiofmu.testing"]\n\n'
                                            '@pytest.mark.parametrize("uiofmu_seed", [1.5, -1, True], indirect=True)\n'
                                            "def test_given(uiofmu_seed):\n    pass\n")
    env = {k: v for k, v in os.environ.items() if k != "UIOFMU_SEEDS"}
    command = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider"]
    proc = subprocess.run([*command, "test_env.py"], capture_output=True, text=True, cwd=tmp_path,
                          env={**env, "UIOFMU_SEEDS": "5-1"})
    assert proc.returncode == 2, proc.stdout
    assert "ValueError: UIOFMU_SEEDS='5-1': the range 5-1 names no seed (it runs backwards)" in proc.stdout
    assert "skipped" not in proc.stdout and "1 error" in proc.stdout, proc.stdout
    proc = subprocess.run([*command, "test_given.py"], capture_output=True, text=True, cwd=tmp_path, env=env)
    assert proc.returncode == 1 and "3 errors" in proc.stdout and "passed" not in proc.stdout, proc.stdout
    for value in ("1.5", "-1", "True"):
        assert f"ValueError: uiofmu_seed: expected an integer from 0 to 4294967295, found {value}" in proc.stdout


@pytest.mark.parametrize("kwargs, message", [
    ({"steps": 0}, r"steps: expected a step SPEC such as 'fixed:0\.1', or a 1-D sequence of at least one step "
                   r"length > 0; found the number 0"),
    ({"steps": -5}, r"steps: expected a step SPEC .*; found the number -5"),
    ({"steps": []}, r"steps: expected a step SPEC .*; found an array of shape \(0,\)"),
    ({"steps": [[0.1]]}, r"steps: expected a step SPEC .*; found an array of shape \(1, 1\)"),
    ({"steps": [0.1, float("nan")]}, r"steps: every step length must be finite and > 0; step 1 is nan \(1 of 2"),
    ({"steps": [0.1, -0.1, 0.0]}, r"steps: every step length must be finite and > 0; step 1 is -0\.1 \(2 of 3"),
    ({"steps": "fixed:-1"}, r"steps='fixed:-1' \(t_end 69\.5 s\): --steps: fixed:H must be > 0"),
    ({"steps": [0.1] * 5, "t_end": 1.0}, r"t_end: applies to a step SPEC only; found t_end=1\.0 with the step "
                                         r"lengths given"),
    ({"t_end": 0.0}, r"t_end: expected a finite number > 0, found 0\.0"),
    ({"t_end": -1}, r"t_end: expected a finite number > 0, found -1"),
    ({"t_end": float("nan")}, r"t_end: expected a finite number > 0, found nan"),
    ({"t_end": float("inf")}, r"t_end: expected a finite number > 0, found inf"),
    ({"xhat0_error": float("nan")}, r"xhat0_error: expected a finite number >= 0, found nan"),
    ({"xhat0_error": -0.5}, r"xhat0_error: expected a finite number >= 0, found -0\.5"),
    ({"seed": -1}, r"seed: expected an integer from 0 to 4294967295, found -1"),
    ({"seed": 1.5}, r"seed: expected an integer from 0 to 4294967295, found 1\.5"),
    ({"seed": 2**40}, r"seed: expected an integer from 0 to 4294967295, found 1099511627776"),
])
def test_steps_and_times_that_make_no_run_are_errors(right, kwargs, message):
    for helper in (assert_converges, assert_bound_respected):
        with pytest.raises(ValueError, match="^" + message):
            helper(right.observer, right.plant, **kwargs)


def test_assert_matches_runtime_refuses_a_validation_of_no_steps(right):
    """steps=0 compared the initial point only, steps=-5 nothing, and rtol=inf anything: each passed."""
    for kwargs, message in (({"steps": 0}, "steps: expected an integer >= 1, found 0"),
                            ({"steps": -5}, "steps: expected an integer >= 1, found -5"),
                            ({"steps": 2.5}, "steps: expected an integer >= 1, found 2.5"),
                            ({"rtol": float("inf")}, "rtol: expected a finite number > 0, found inf"),
                            ({"rtol": float("nan")}, "rtol: expected a finite number > 0, found nan"),
                            ({"rtol": 0.0}, "rtol: expected a finite number > 0, found 0.0"),
                            ({"seed": -1}, "seed: expected an integer from 0 to 4294967295, found -1")):
        with pytest.raises(ValueError, match="^" + message.replace(".", r"\.") + "$"):
            assert_matches_runtime(right.observer, **kwargs)
    assert_matches_runtime(right.observer, steps=1)


def test_a_window_longer_than_the_run_is_an_error(right, stale, deadbeat):
    """within=10000 on a run of 695 steps checked no point: the diverging stale observer passed."""
    with pytest.raises(ValueError, match=r"^within: 10000 steps, more than the 695 steps of the run \(fixed:0\.1\), so "
                                         r"no point would be checked; give at most 695 steps"):
        assert_converges(stale, right.plant, within=10_000)
    with pytest.raises(ValueError, match=r"^within: 6 steps, more than the 5 steps of the run \(given\)"):
        assert_converges(right.observer, right.plant, steps=[0.1] * 5, within=6)
    with pytest.raises(AssertionError, match=r"^stale\.fmu does not converge within 695 of 695 steps"):
        assert_converges(stale, right.plant, within=695)              # the last point is still checked
    # a run of 2 steps ends before the first full window of 4 samples (step 3)
    with pytest.raises(ValueError, match=r"^steps: the run has 2 steps \(fixed:1\.0, to t = 2 s\), but the first full "
                                         r"window of 4 samples is at step 3, so no point would be checked"):
        assert_exact_functional(deadbeat.observer, deadbeat.plant, t_end=2.0)
    run = assert_exact_functional(deadbeat.observer, deadbeat.plant, t_end=3.0)
    assert len(run.steps) == 3 and run.result.functional["valid"][3] == 1.0


def test_tolerances_that_are_not_finite_and_positive_are_errors(right, stale, deadbeat):
    """tol=inf let the diverging stale observer converge; max_ratio=nan dropped the margin check."""
    for tol in (float("inf"), float("nan"), 0.0, -0.01):
        with pytest.raises(ValueError, match=rf"^tol: expected a finite number > 0, found {tol!r}$"):
            assert_converges(stale, right.plant, within=0.75, tol=tol)
    for ratio in (float("nan"), float("inf"), 0.0, -1.0, 1.5):
        with pytest.raises(ValueError, match=rf"^max_ratio: expected a finite number > 0 and <= 1, found {ratio!r}$"):
            assert_bound_respected(right.observer, right.plant, max_ratio=ratio)
    for rtol in (float("inf"), float("nan"), 0.0):
        with pytest.raises(ValueError, match=rf"^rtol: expected a finite number > 0, found {rtol!r}$"):
            assert_exact_functional(deadbeat.observer, deadbeat.plant, t_end=12.0, rtol=rtol)
    for within in (0, -1, float("nan"), 0.0, 1.5, True):
        with pytest.raises(ValueError, match=r"^within: "):
            assert_converges(right.observer, right.plant, within=within)
    with pytest.raises(ValueError, match=r"^xhat0_error: seed003-example_observer\.fmu is a functional observer \("
                                         r"kernel window\), which has no initial estimate to offset"):
        assert_converges(deadbeat.observer, deadbeat.plant, t_end=12.0, xhat0_error=0.5)


def test_an_error_that_is_not_finite_fails(right):
    """An initial error of 1e300 overflows to an infinite error norm and bound: both assertions passed (inf <= inf,
    and the master's NaN ratio compares False with max_ratio)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)          # numpy's overflow in the norms and metrics
        with pytest.raises(AssertionError) as info:
            assert_converges(right.observer, right.plant, within=0.75, xhat0_error=1e300)
        text = str(info.value)
        assert text.startswith("seed000-example1_observer.fmu: expected a finite estimation error at every point; "
                               "it is not finite from step 0 (t = 0 s) on: ||x - xhat|| = inf (x = [ 1. -1.], xhat "
                               "= ["), text
        assert "696 such point(s) [695 steps fixed:0.1, seed 0" in text
        with pytest.raises(AssertionError) as info:
            assert_bound_respected(right.observer, right.plant, xhat0_error=1e300)
        text = str(info.value)
        assert text.startswith("seed000-example1_observer.fmu: expected ||x - xhat|| inside the certified bound"), text
        assert "the error or the bound is not finite from step 0 (t = 0 s) on: ||x - xhat|| = inf, bound = inf" in text


@pytest.fixture(scope="session")
def at_rest(tmp_path_factory):
    """Example 1 from x0 = 0 with no signals, and a stale (diverging) observer of it: both run with an estimation
    error of exactly 0 at every point unless xhat0_error offsets the initial estimate."""
    folder = tmp_path_factory.mktemp("at_rest")
    text = (EXAMPLES / "seed000_example1.toml").read_text().split("[signals]")[0]
    text = text.replace("x0 = [1.0, -1.0]", "x0 = [0.0, 0.0]").replace('"seed000-example1"', '"at-rest"')
    (folder / "at_rest.toml").write_text(text)
    fmus = build_fmus(folder / "at_rest.toml", folder, backend=BACKEND)
    card = card_from_data(_perturbed(fmus.card, [[1.2], [0.0]], False, "stale_at_rest"))
    return fmus, build_observer(card, folder / "stale_at_rest.fmu", backend=BACKEND)


def test_a_run_whose_error_is_zero_throughout_cannot_pass(at_rest):
    """With the observer started at the plant's state and nothing driving the error, a diverging observer passed
    assert_converges and any observer assert_bound_respected."""
    fmus, stale_at_rest = at_rest
    message = (r"^xhat0_error: the estimation error \|\|x - xhat\|\| is 0 at every one of the 696 points \(the "
               r"observer starts at the plant's state and nothing drives the error\), so the run cannot show ")
    with pytest.raises(ValueError, match=message + "convergence; give xhat0_error > 0"):
        assert_converges(stale_at_rest, fmus.plant, within=0.75)
    with pytest.raises(ValueError, match=message + "that the error stays inside a bound; give xhat0_error > 0"):
        assert_bound_respected(fmus.observer, fmus.plant)
    with pytest.raises(AssertionError, match=r"^stale_at_rest\.fmu does not converge within 522 of 695 steps"):
        assert_converges(stale_at_rest, fmus.plant, within=0.75, xhat0_error=0.5)
    assert_converges(fmus.observer, fmus.plant, within=0.75, xhat0_error=0.5)
    assert_bound_respected(fmus.observer, fmus.plant, xhat0_error=0.5)
