"""A ``"max"`` search decided by optimal values: the largest margin of the LMIs at each value.

What the theory guarantees and these tests check: the largest-margin problem of a homogeneous system
is bounded and feasible at every value, its optimum is positive exactly where a certificate exists, its
point scaled to the normalisations satisfies every LMI with margin, and a search ends where that margin
crosses its threshold. The same search under other BLAS kernels is ``tests/test_same_answers.py``'s.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

import uiofmu
from uiofmu.certificate import FIGURE_DIGITS, UNDETERMINED, UNDETERMINED_NOTE, figure_text, overshoot_text
from uiofmu.cli import design_summary
from uiofmu.families import ltv_auid
from uiofmu.lmi import HELD, REPRODUCED, Lmi, LmiSystem, eig_min, search
from uiofmu.problem import problem_from_data
from uiofmu.runtime.tolerances import (MARGIN_DECISION_RTOL, SEARCH_MARGIN_CAP, SEARCH_MARGIN_FRACTION,
                                       SEARCH_RESOLUTION, SEARCH_TOL)

ROOT = Path(__file__).resolve().parents[1]


def _toy():
    """``X >= 1``, ``(1 - s) X > 0`` and ``(2 - s) X > 0``: largest margin ``min(1, 1 - s)`` with ``X = 1``."""
    def build(v, prm, ops):
        return [Lmi("X >= 1", v["X"] - ops.eye(1), strict=False),
                Lmi("(1 - s) X > 0", (1.0 - prm["s"]) * v["X"] + 0.0 * ops.eye(1)),
                Lmi("(2 - s) X > 0", (2.0 - prm["s"]) * v["X"] + 0.0 * ops.eye(1))]
    return LmiSystem("toy", {"X": ("symmetric", 1)}, {"s": 0.0}, build, homogeneous=True)


def _example2(**observer):
    doc = tomllib.loads((ROOT / "examples" / "seed000_example2_consistent.toml").read_text(encoding="utf-8"))
    doc["observer"].update(observer)
    return problem_from_data(doc)


def _theorem2(problem):
    """ltv-auid's Theorem 2 system of a problem, and the map from mu to its parameter."""
    s = problem.plant.sampled(problem.options.dt)
    _, A1, A2, S1 = ltv_auid._vertices(s, problem.plant.C, problem.options.alpha)
    eta = problem.options.eta
    return ltv_auid._lmis(A1, A2, S1, problem.plant.C, eta), (lambda mu: eta * (1.0 + mu))


def test_the_largest_margin_of_a_toy_is_its_closed_form():
    system = _toy()
    for s in (0.0, 0.3, 0.9):
        sol = system.largest_margin(s=s)
        assert sol.relative_margin == pytest.approx(min(1.0, 1.0 - s), abs=1e-8)
        assert sol.verified
        lmis = system.evaluate(sol.values, {"s": s})
        assert eig_min(lmis)["X >= 1"] >= -1e-9               # scaled back to its normalisation
    beyond = system.largest_margin(s=1.2)
    assert beyond.relative_margin == pytest.approx(-0.2, abs=1e-8) and not beyond.verified


def test_a_search_ends_where_the_margin_crosses_its_threshold():
    """The toy's margin is ``1 - s`` near 1: the value ``tol`` inside the limit (margin 1e-9) is not resolved,
    the easy end's margin 1 sets the threshold (capped at 1e-6), and the bracket narrows until its ends'
    margins differ by less than SEARCH_RESOLUTION thresholds."""
    found = search(_toy(), "s", 0.0, 1.0, tol=1e-9)
    threshold = SEARCH_MARGIN_CAP
    assert 1.0 - threshold - SEARCH_RESOLUTION * threshold <= found.value <= 1.0 - threshold
    good, bad = found.bracket
    assert (1.0 - good) - (1.0 - bad) < SEARCH_RESOLUTION * threshold and 1.0 - bad < threshold
    # settled: the least objective at half the threshold (the toy has no objective, so no figure to reproduce)
    assert found.solution.verified and found.solution.relative_margin == 0.5 * threshold
    assert HELD in found.solution.status and not found.solution.status.endswith(REPRODUCED)
    assert found.solution.held and not found.solution.reproduced


def test_the_threshold_is_a_fraction_of_the_problems_own_margin():
    """A system whose margin never exceeds 1e-4 (``X >= 1`` against ``1e-4 (1 - s) X > 0``) is searched
    against a tenth of its margin at the easy end, not against a fixed 1e-6 it would reach late."""
    def build(v, prm, ops):
        return [Lmi("X >= 1", v["X"] - ops.eye(1), strict=False),
                Lmi("1e-4 (1 - s) X > 0", 1e-4 * (1.0 - prm["s"]) * v["X"] + 0.0 * ops.eye(1))]
    system = LmiSystem("small", {"X": ("symmetric", 1)}, {"s": 0.0}, build, homogeneous=True)
    found = search(system, "s", 0.0, 1.0, tol=1e-9)
    threshold = min(max(SEARCH_MARGIN_FRACTION * 1e-4, MARGIN_DECISION_RTOL), SEARCH_MARGIN_CAP)
    margin = system.largest_margin(s=found.value).relative_margin
    assert threshold <= margin < (1.0 + SEARCH_RESOLUTION) * threshold


def test_a_system_without_normalisation_has_no_margin():
    def build(v, prm, ops):
        return [Lmi("X > 0", v["X"] + 0.0 * ops.eye(1))]
    with pytest.raises(ValueError, match="needs a normalisation"):
        LmiSystem("bare", {"X": ("symmetric", 1)}, {}, build, homogeneous=True).largest_margin()


def test_example_2s_margin_vanishes_at_the_papers_mu():
    """Theorem 2's LMIs of seed 000 Example 2 (consistent data): the largest margin changes sign
    between mu = 14.8 and 15.2; the paper's Example 2 reports mu = 15."""
    system, tau1 = _theorem2(_example2())
    inside, outside = system.largest_margin(tau1=tau1(14.8)), system.largest_margin(tau1=tau1(15.2))
    assert inside.status.startswith("optimal") and outside.status.startswith("optimal")
    assert inside.relative_margin > 0 > outside.relative_margin


def test_example_2s_search_stops_at_its_threshold():
    """Example 2's margin is capped near 2.5e-7 by the asymptotic vertex (34), which mu does not move: the
    search's threshold is then the least one, and mu ends below the paper's 15 with a bracket whose ends'
    margins differ by less than the search resolves."""
    card = uiofmu.design(_example2())
    mu, (good, bad) = card.data["mu"], card.data["search"]["bracket"]
    system, tau1 = _theorem2(_example2())
    limit = card.data["existence"]["conditions"][-1]["values"]["mu_limit"]
    easy = system.largest_margin(tau1=tau1(1e-4 * limit)).relative_margin
    threshold = min(max(SEARCH_MARGIN_FRACTION * easy, MARGIN_DECISION_RTOL), SEARCH_MARGIN_CAP)
    assert good == mu and 13.0 < mu < 15.0 < bad
    at_good, at_bad = (system.largest_margin(tau1=tau1(v)).relative_margin for v in (good, bad))
    assert at_good >= threshold > at_bad
    assert at_good - at_bad < SEARCH_RESOLUTION * threshold or abs(bad - good) <= SEARCH_TOL * limit + 1e-12
    assert all(c.holds for c in uiofmu.verify(card))


def test_a_value_whose_plain_solve_fails_designs_from_its_largest_margin():
    """At mu = 14.4 a plain solve of Theorem 2 ends without a certificate (CLARABEL stalls near the
    edge); its point of largest margin certifies, and the card is that design."""
    card = uiofmu.design(_example2(mu=14.4))
    assert card.data["mu"] == 14.4 and card.data["certificate"]["verified"]
    assert all(c.holds for c in uiofmu.verify(card))


def test_the_unknown_inputs_unit_does_not_change_an_ltv_design():
    """Scaling E scales S1; (33) with S1 / |S1| is the same LMI (a congruence), so E of 1e-10 designs the
    mu that E of 1 does (it used to need slack 1e-6 in (33))."""
    base = tomllib.loads((ROOT / "examples" / "seed000_example1_ltv.toml").read_text(encoding="utf-8"))
    base["observer"]["mu"] = "max"
    mus = []
    for scale in (1.0, 1e-10):
        doc = {**base, "plant": {**base["plant"], "E": (np.array(base["plant"]["E"]) * scale).tolist()}}
        card = uiofmu.design(problem_from_data(doc))
        assert all(c.holds for c in uiofmu.verify(card))
        mus.append(card.data["mu"])
    limit = 1.0 / 0.01 - 1.0
    assert abs(mus[0] - mus[1]) <= 2 * SEARCH_TOL * limit


def test_the_overshoot_is_printed_to_the_digits_its_design_determines():
    accurate = uiofmu.design(problem_from_data(tomllib.loads(
        (ROOT / "examples" / "seed000_example1_ltv.toml").read_text(encoding="utf-8"))))
    assert accurate.data["overshoot_digits"] == FIGURE_DIGITS
    edge = uiofmu.design(_example2(mu=14.4))                # the point of largest margin
    assert edge.data["overshoot_digits"] == UNDETERMINED
    for card in (accurate, edge):
        text = overshoot_text(card.data)
        assert f"  overshoot_bound  {text}" in design_summary(card, timing=False)
        digits = card.data["overshoot_digits"] or 2
        assert float(text.split()[0]) == pytest.approx(card.data["overshoot_bound"], rel=10.0 ** (1 - digits))
    assert overshoot_text(edge.data).endswith(UNDETERMINED_NOTE)
    assert [figure_text(v, 2) for v in (292.79, 36.08, 0.00012345)] == ["290", "36", "0.00012"]
    assert figure_text(6.4517, 4) == "6.452" and figure_text(2.5e6, 2) == "2.5e+06"


def _scripted_held(figures):
    """A homogeneous system whose held solves return, in turn, points of these figures (None: no point)."""
    from dataclasses import replace as _replace

    from uiofmu.lmi import LmiSolution

    system = _toy()
    answers = iter(figures)
    calls = []

    def held_once(held, parameters):
        figure = next(answers)
        calls.append(held)
        if figure is None:
            return LmiSolution({}, {"s": 0.0}, "solver_error: CLARABEL answered InsufficientProgress", {}, False, 0, 0)
        sol = LmiSolution({"X": np.array([[figure]])}, {"s": 0.0}, "optimal_inaccurate", {}, True, 0, 0, figure)
        return _replace(sol, held=True, relative_margin=held)

    system._held_once = held_once
    return system, calls


def test_a_held_figure_counts_when_two_solves_agree_and_an_outlier_does_not_decide():
    """An answer CLARABEL stopped short at (58.94) agrees with no other; the two that agree decide, and the earlier
    of them is kept. Solves with no point are skipped."""
    system, calls = _scripted_held([58.94, None, 58.743, 58.735])
    sol = system.least_at_margin(5e-7)
    assert sol.reproduced and REPRODUCED in sol.status and sol.objective == 58.743
    assert len(calls) == 4 and calls[0] == 5e-7 and calls[2] < 5e-7 < calls[1]
    system, calls = _scripted_held([None, 12.0772, 12.0773])          # the first solve has no point
    sol = system.least_at_margin(5e-7)
    assert sol.reproduced and sol.objective == 12.0772 and len(calls) == 3
    system, calls = _scripted_held([58.94, 58.74, 57.0, 56.0, 55.0])   # no two agree: not the problem's figure
    sol = system.least_at_margin(5e-7)
    assert sol.verified and not sol.reproduced and sol.objective == 58.94 and len(calls) == 5


def test_a_held_problem_whose_first_two_solves_fail_is_not_solved_further():
    """Where neither of the first two solves gives a point that verifies, CLARABEL does not solve the held problem, and
    which later solves verify is the BLAS kernel's rounding (an lti-uio plant: the 3rd and 4th under SkylakeX, 9.7965,
    none under Prescott): no more are made, and no figure counts. A first solve that verifies keeps the probes going."""
    system, calls = _scripted_held([None, None, 9.79648, 9.79645, None])
    sol = system.least_at_margin(5e-7)
    assert not sol.verified and not sol.reproduced and len(calls) == 2
    system, calls = _scripted_held([9.79648, None, None, 9.79645])
    sol = system.least_at_margin(5e-7)
    assert sol.reproduced and sol.objective == 9.79648 and len(calls) == 4
    system, calls = _scripted_held([])                  # below the floor a held point never verifies: not solved
    sol = system.least_at_margin(0.5 * MARGIN_DECISION_RTOL)
    assert not sol.verified and sol.held and not calls


def test_a_held_overshoot_the_solver_does_not_reach_is_not_the_problems():
    """An lti-uio plant next to the edge (decay 0.9754) whose held problem CLARABEL gives up on (InsufficientProgress)
    under some kernels and ends AlmostSolved under others, at every margin up to its own largest: its overshoot is
    said not to be determined by the problem, where SkylakeX printed 9.8 and Prescott did not."""
    from uiofmu.families import random_plants as rpl

    doc = list(rpl.campaign("lti-uio", 3, 2026, n_max=5, intervals_max=4))[2]
    card = uiofmu.design(problem_from_data(doc))
    assert card.data["decay_bound"] == pytest.approx(0.975403, abs=1e-6)
    assert card.data["certificate"]["verified"] and all(c.holds for c in uiofmu.verify(card))
    assert card.data["overshoot_digits"] == UNDETERMINED
    assert overshoot_text(card.data).endswith(UNDETERMINED_NOTE)


def test_a_search_whose_margins_the_solver_does_not_resolve_refuses():
    """A badly scaled plant (gains of 1.6e6 needed) whose largest margins are CLARABEL's noise (-1.2e-6..9e-7 along
    the range, two solves 1e-9 apart of opposite signs, the first value's margin 1.5e-7 to 5.8e-7 by solve under
    Prescott): with the LMI alone the design is refused with that reason, and by default it falls back to the
    solver-free Riccati gain. Under Prescott, Haswell and SkylakeX that is what happens; under Sandybridge the
    first value's three solves happen to agree (4.4e-7 to 5.8e-7) and the LMIs design. So this asserts what holds
    under every kernel: the LMI's refusal gives that reason, the default design then is the Riccati gain, and
    either design re-checks (the rules themselves are tested on scripted margins below)."""
    from uiofmu.families import random_plants as rpl

    doc = list(rpl.campaign("lti-uio", 8, 2026, n_max=5, intervals_max=4))[7]
    assert doc["name"].startswith("lti-uio-seed2026000007-badly-scaled")
    card = uiofmu.design(problem_from_data(doc))
    assert card.data["certificate"]["verified"] and all(c.holds for c in uiofmu.verify(card))
    doc["observer"]["method"] = "lmi"
    try:
        lmi_card = uiofmu.design(problem_from_data(doc))
    except uiofmu.InfeasibleError as refusal:
        assert "the solver does not resolve these LMIs' margins" in str(refusal)
        assert card.data["design_method"] == "riccati (the LMI found no certificate)"
    else:
        assert card.data["design_method"].startswith("lmi") and lmi_card.data["decay_bound"] == card.data["decay_bound"]
        assert all(c.holds for c in uiofmu.verify(lmi_card))


def test_a_rounding_twin_solves_the_same_problem():
    """Within ``rounding_twin`` CLARABEL gets the variables in reversed order and the answer is put back in
    order: the toy's point (``X`` and ``t``, two variables swapped) and margin are its closed form, and Example 2's
    margin (8.7e-8, capped by a vertex mu does not move) comes out the same to its rounding (0.15 % apart)."""
    from uiofmu.conic import rounding_twin

    toy = _toy()
    with rounding_twin():
        sol = toy.largest_margin(s=0.3)
    assert sol.relative_margin == pytest.approx(0.7, abs=1e-8) and sol.verified
    assert sol.values["X"][0, 0] == pytest.approx(1.0 / 0.7, rel=1e-8)    # X = 1 at margin 0.7, scaled by it
    system, tau1 = _theorem2(_example2())
    own = system.largest_margin(tau1=tau1(10.0))
    with rounding_twin():
        twin = system.largest_margin(tau1=tau1(10.0))
    assert twin.verified and twin.relative_margin == pytest.approx(own.relative_margin, rel=1e-2)


def _scripted_margins(margins):
    """A ``decide`` answering the given (margin, certifies) in turn, and the calls it got: (value, twin)."""
    from uiofmu import conic
    from uiofmu.lmi import LmiSolution

    calls, answers = [], iter(margins)

    def decide(s):
        calls.append((s, conic._REVERSED.get()))
        margin, verified = next(answers)
        return LmiSolution({}, {"s": s}, "optimal", {}, verified, 0.0, 0.0, None, 1e-6, margin)
    return decide, calls


def test_a_value_near_its_threshold_counts_when_two_of_its_solves_agree():
    """Near the threshold a value is solved as its rounding twin, then 1e-9 away, until two certified margins agree:
    a lone outlier (the twin here) decides nothing; the margin kept is the smaller of those solved in the problem's
    own order. The first value that passes must agree with every probe."""
    from uiofmu.lmi import _judged
    from uiofmu.runtime.tolerances import MARGIN_PROBE

    decide, calls = _scripted_margins([(3e-8, True), (1e-10, True), (2.5e-8, True)])
    sol = _judged(decide, "s", 0.5, 2e-8)
    assert sol.verified and sol.relative_margin == 2.5e-8 and sol.unresolved is None
    assert calls == [(0.5, False), (0.5, True), (0.5 * (1.0 + MARGIN_PROBE), False)]
    decide, calls = _scripted_margins([(3e-8, True), (2.9e-8, True)])
    sol = _judged(decide, "s", 0.5, 2e-8)                  # the twin agrees: no third solve, the own margin kept
    assert sol.verified and sol.relative_margin == 3e-8 and len(calls) == 2
    decide, calls = _scripted_margins([(3e-8, True), (1e-10, True), (2.9e-8, False)])
    sol = _judged(decide, "s", 0.5, 2e-8)                  # the agreeing probe's point does not certify
    assert not sol.verified and sol.unresolved == (3e-8, 1e-10)
    decide, calls = _scripted_margins([(1e-6, True), (1e-10, True), (1e-6, True)])
    sol = _judged(decide, "s", 0.5, 2e-8, first=True)      # the first value: every probe must agree
    assert not sol.verified and sol.unresolved == (1e-6, 1e-10) and len(calls) == 2


def test_a_first_value_whose_margins_all_set_the_largest_threshold_counts_however_they_differ():
    """The first value's margin matters through the threshold it sets: where the first solve and every probe
    give margins of which 1 % is above the cap (2.4e-4 to 6.2e-4, as an ltv-auid plant's by kernel and probe), the
    threshold is the cap whatever their digits and the value counts, with the smallest own margin; a probe below
    that level (the cap then depends on which margin counts) must agree as before."""
    from uiofmu.lmi import _judged

    lowest = SEARCH_MARGIN_CAP / SEARCH_MARGIN_FRACTION
    decide, calls = _scripted_margins([(6.2e-4, True), (3.3e-4, True), (2.45e-4, True)])
    sol = _judged(decide, "s", 0.5, 2e-8, first=True)
    assert sol.verified and sol.relative_margin == 2.45e-4 and sol.unresolved is None and len(calls) == 3
    decide, calls = _scripted_margins([(6.2e-4, True), (0.9 * lowest, True), (6e-4, True)])
    sol = _judged(decide, "s", 0.5, 2e-8, first=True)
    assert not sol.verified and sol.unresolved == (6.2e-4, 0.9 * lowest) and len(calls) == 2


def test_a_plant_whose_first_margins_differ_above_the_cap_is_designed_under_every_kernel():
    """A badly scaled ltv-auid plant (||M C E|| 2.2e4) whose first value's margins came out 2.4e-4 to 6.2e-4 by
    BLAS kernel and probe: refused under three kernels and designed under the fourth while their disagreement
    decided; the threshold they set is the cap under all four, and the design is made and re-checks (where its
    search ends still moves with the kernel: docs/tolerances.md)."""
    from uiofmu.families import random_plants as rpl

    doc = list(rpl.campaign("ltv-auid", 8, 2031, n_max=5, intervals_max=4))[3]
    assert doc["name"].startswith("ltv-auid-seed2031000003-badly-scaled")
    card = uiofmu.design(problem_from_data(doc))
    assert card.data["certificate"]["verified"] and all(c.holds for c in uiofmu.verify(card))
    assert card.data["search"]["parameter"] == "mu" and card.data["mu"] > 0


def test_a_value_whose_solve_fails_is_decided_by_its_rounding_twin():
    """A solve CLARABEL gives up on (no margin) is made once more as its rounding twin, whose answer decides."""
    from uiofmu import conic
    from uiofmu.lmi import LmiSolution, _judged

    calls = []

    def decide(s):
        twin = conic._REVERSED.get()
        calls.append(twin)
        if not twin:
            return LmiSolution({}, {"s": s}, "solver_error: CLARABEL answered NumericalError", {}, False, 0.0, 0.0,
                               None, 1e-6)
        return LmiSolution({}, {"s": s}, "optimal", {}, True, 0.0, 0.0, None, 1e-6, 1e-3)
    sol = _judged(decide, "s", 0.5, 2e-8)
    assert sol.verified and sol.relative_margin == 1e-3 and calls == [False, True]
