"""The rules that keep designs honest and free of spurious failures.

A decay bound of 1 or more never certifies; equalities and non-strict LMIs at the solver's
point are judged relative to its size while strict LMIs and the stored-matrix re-check stay
absolute; homogeneous LMIs are repaired by scaling; searches stay inside their range and walk
toward the easy end; a value on the feasible side of a certified best one always designs.
"""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

import uiofmu
from uiofmu.runtime.card import card_from_data
from uiofmu.certificate import certificate, decay_check
from uiofmu.runtime.errors import CardError, InfeasibleError
from uiofmu.lmi import Lmi, LmiSystem, accepted, eig_min, point_scale, search, tune
from uiofmu.problem import problem_from_data

from same_answers import DC_MOTOR, NEAR_UNIT_FIXED_MODE, badly_scaled as _badly_scaled


def _problem(plant, **observer):
    return problem_from_data({"name": "p", "plant": plant, "observer": observer})


def _toy(homogeneous=False):
    """``X >= 1`` and ``(1 - s) X > 0``: feasible for s < 1, homogeneous apart from the normalisation."""
    def build(v, prm, ops):
        return [Lmi("X >= 1", v["X"] - ops.eye(1), strict=False),
                Lmi("(1 - s) X > 0", (1.0 - prm["s"]) * v["X"] + 0.0 * ops.eye(1))]
    return LmiSystem("toy", {"X": ("symmetric", 1)}, {"s": 0.0}, build, homogeneous=homogeneous)


# -- a bound that does not contract never certifies ----------------------------------------------

def test_a_fixed_mode_next_to_the_unit_circle_certifies_a_decay_below_one():
    """The reproducer that used to write a verified card with decay bound 1.00009."""
    card = uiofmu.design(_problem(NEAR_UNIT_FIXED_MODE, family="lti-uio", decay="max"))
    assert 0.99999 < card.data["decay_bound"] < 1.0
    assert card.data["certificate"]["verified"] and all(c.holds for c in uiofmu.verify(card))
    assert card.data["certificate"]["checks"]["decay bound < 1"]["holds"]


def test_a_bound_of_one_fails_the_certificate_and_the_schema(example1_card):
    assert not decay_check(1.0).holds and not decay_check(1.00009).holds and decay_check(0.999999).holds
    data = json.loads(example1_card[0].to_json())
    data["decay_bound"] = 1.0
    with pytest.raises(CardError, match="a bound of 1 or more certifies no convergence"):
        card_from_data(data)


def test_the_first_search_point_stays_inside_a_narrow_bracket():
    """The bracket (0.99999, 0.999995) is narrower than the tolerance: the first point tried is inside it."""
    found = search(_toy(), "s", 0.4, 0.99999 ** 0, tol=1e-4, transform=lambda x: x)
    assert found.value < 1.0
    narrow = search(_toy(), "s", 0.999995, 1.0, tol=1e-4)
    assert 0.999995 <= narrow.value < 1.0


# -- relative acceptance, absolute strictness -----------------------------------------------------

def _equality_system():
    def build(v, prm, ops):
        return [Lmi("x = y", v["x"] - v["y"], equality=True), Lmi("x > 0", v["x"] + 0.0 * ops.eye(1))]
    return build


def test_equalities_are_judged_relative_to_the_size_of_the_point():
    build = _equality_system()
    from uiofmu.lmi import NUMPY_OPS

    def verdict(x, y):
        values = {"x": np.array([[x]]), "y": np.array([[y]])}
        lmis = build(values, {}, NUMPY_OPS)
        return accepted(eig_min(lmis), lmis, scale=point_scale(values))

    assert verdict(6e7, 6e7 + 3.6e-6)          # 6e-14 relative: as exact as double precision allows
    assert not verdict(1.0, 1.0 + 3.6e-6)      # the same residual on a point of size 1 is a violation
    assert not verdict(6e7, 6e7 * (1 + 1e-6))  # a residual of 1e-6 relative is not round-off
    assert not verdict(-1e-9, -1e-9)           # strict LMIs keep the absolute margin at any scale


def test_the_dc_motor_designs_at_a_fixed_alpha():
    """Spuriously rejected before: residuals of 9e-13 relative to |S|, |Q| of 6e7 failed an absolute rule."""
    card = uiofmu.design(_problem(DC_MOTOR, family="sampled-data", intervals=[0.01, 0.02, 0.03, 0.04, 0.05],
                                  alpha=0.9))
    assert card.data["alpha"] == 0.9 and card.data["certificate"]["verified"]
    assert all(c.holds for c in uiofmu.verify(card))


def test_relative_acceptance_never_replaces_the_stored_matrix_check(building_card):
    """A point the solver-side rule accepts still has to pass the checks at the matrices the runtime uses."""
    from uiofmu.families.sampled_data import checks

    card = building_card[0]
    mats = {k: np.array(v) for k, v in card.data["matrices"].items()}
    sol = type("S", (), {"status": "optimal", "parameters": {}, "margin": 1e-6, "eig_min": {}, "verified": True,
                         "solve_time": 0.0})()
    certificate(sol, checks(mats, card.data["decay_bound"]), "building")           # the stored matrices pass
    mats["N"] = mats["N"] * 1.05                                                    # a gain the point did not give
    with pytest.raises(InfeasibleError, match="does not survive the re-check at the stored matrices"):
        certificate(sol, checks(mats, card.data["decay_bound"]), "building")


# -- homogeneous repair ----------------------------------------------------------------------------

def test_a_point_that_misses_a_normalisation_by_round_off_is_scaled_not_rejected():
    point = {"X": np.array([[1.0 - 1e-6]])}
    assert not _toy().recheck(point, {"s": 0.5}).verified
    repaired = _toy(homogeneous=True).recheck(point, {"s": 0.5})
    assert repaired.verified and repaired.values["X"][0, 0] >= 1.0
    assert not _toy(homogeneous=True).recheck({"X": np.array([[-1.0]])}, {"s": 0.5}).verified   # no scale helps


# -- searches and monotone answers -----------------------------------------------------------------

def test_a_search_walks_toward_the_easy_end_when_its_first_guess_fails():
    """Feasible for s < 1 only: from the guess 1.5 the search walks toward the safe end 0 and certifies."""
    found = search(_toy(), "s", 1.5, 2.0, tol=1e-3, safe_end=0.0)
    assert found.solution.verified and 1.0 - 2e-3 < found.value < 1.0
    with pytest.raises(InfeasibleError):
        search(_toy(), "s", 1.5, 2.0, tol=1e-3)        # without a safe end there is nowhere to go


def test_a_value_on_the_feasible_side_of_the_best_reuses_its_certificate():
    tuned = tune(_toy(), "s", 0.3, feasible_end=0.5, infeasible_end=2.0, safe_end=0.0, tol=1e-3)
    assert tuned.value == 0.3 and tuned.solution.verified
    with pytest.raises(InfeasibleError):
        tune(_toy(), "s", 1.2, feasible_end=0.5, infeasible_end=2.0, safe_end=0.0, tol=1e-3)


@pytest.mark.parametrize("path,key,side", [
    ("examples/seed000_example1.toml", "decay", +1),
    ("examples/seed000_example1_ltv.toml", "mu", -1),
    ("plants/two_room_building/problem.toml", "alpha", -1),
])
def test_values_on_the_feasible_side_of_max_design(path, key, side):
    from tests.conftest import ROOT

    doc = __import__("tomllib").loads((ROOT / path).read_text())
    doc["observer"][key] = "max"
    best = uiofmu.design(problem_from_data(doc)).data[key]
    for frac in (0.999, 0.9, 0.5):
        value = 1 - (1 - best) * frac if side > 0 else best * frac
        doc["observer"][key] = value
        card = uiofmu.design(problem_from_data(doc))
        assert card.data["certificate"]["verified"] and card.data["decay_bound"] < 1.0, (key, value)


# -- weak modes and the solver-free design ---------------------------------------------------------

def test_check_names_a_weakly_observable_mode():
    report = uiofmu.check(_problem(DC_MOTOR, family="lti-uio", dt=0.01, decay="max"))
    weak = next(c for c in report.conditions if c.name == "well observable modes")
    assert not weak.holds and not weak.required and report.exists
    assert abs(weak.values["weakest_margin"] - 1.65e-7) < 0.01e-7
    assert "gains of order 1/margin = 6.06e+06" in weak.message


def test_the_weak_mode_is_reached_by_the_fallback():
    """The DC motor sampled at 0.01 s: decay 0.7 needs gains of 3e6, beyond the LMI's precision; the
    solver-free fallback certifies it with margin over the re-check's rounding (and its overshoot
    bound says what such gains cost)."""
    card = uiofmu.design(_problem(DC_MOTOR, family="lti-uio", dt=0.01, decay=0.7))
    assert card.data["design_method"].startswith("riccati") and card.data["decay_bound"] == 0.7
    assert all(c.holds for c in uiofmu.verify(card)) and card.data["overshoot_bound"] > 1e6
    lyap = card.data["certificate"]["checks"]["eig_min(rho^2 X - N'XN)"]
    assert lyap["value"] >= 2 * lyap["rounding_floor"] > 1e-7      # the floor, not the margin, decides here


def test_a_design_closer_to_the_edge_than_rounding_is_refused_with_the_reason():
    """Decay 0.3 needs cond(X) = 3.7e14 and gains of 4.8e6: the Lyapunov inequality's value (0.09 in
    exact arithmetic) is below the rounding floor of its own evaluation, so some BLAS kernels certified
    it and others refused it. Now every kernel refuses it, saying why and what helps."""
    match = r"Riccati design at decay 0.3: .* rounding floor .* a slower decay needs smaller gains"
    with pytest.raises(InfeasibleError, match=match):
        uiofmu.design(_problem(DC_MOTOR, family="lti-uio", dt=0.01, decay=0.3))


def test_the_rounding_floor_bounds_the_error_of_the_re_check():
    """``rho^2 X - N'XN`` in double precision against exact rational arithmetic at the same matrices,
    ill-conditioned X and large gains included: the error is below the floor, and the floor is not
    vacuous (at most 1e4 times the error seen) for matrices of ordinary size."""
    from fractions import Fraction

    from uiofmu.certificate import lyapunov_check

    rng = np.random.default_rng(5)
    ratios = []
    for trial in range(40):
        n = int(rng.integers(2, 6))
        V = np.linalg.qr(rng.standard_normal((n, n)))[0]
        X = V @ np.diag(10.0 ** rng.uniform(0, 3 * (trial % 5), n)) @ V.T
        X = 0.5 * (X + X.T)
        N = rng.standard_normal((n, n)) * 10.0 ** rng.uniform(-1, 3 * (trial % 3))
        rho = float(rng.uniform(0.5, 1.0))
        check = lyapunov_check("q", N, X, rho)
        F = [[Fraction(float(v)) for v in row] for row in X]
        G = [[Fraction(float(v)) for v in row] for row in N]
        r2 = Fraction(rho) ** 2
        exact = np.array([[float(r2 * F[i][j] - sum(G[a][i] * F[a][b] * G[b][j] for a in range(n) for b in range(n)))
                           for j in range(n)] for i in range(n)])
        err = abs(np.linalg.eigvalsh(0.5 * (exact + exact.T))[0] - check.value)
        assert err <= check.floor, (trial, err, check.floor)
        if err > 0:
            ratios.append(check.floor / err)
    assert ratios and np.median(ratios) < 1e4


def test_a_failed_design_names_the_weak_mode():
    match = r"fallback fails too: .*cond\(X\) = .*The mode 0.980199 .*PBH margin 1.65e-07"
    with pytest.raises(InfeasibleError, match=match):
        uiofmu.design(_problem(DC_MOTOR, family="lti-uio", dt=0.01, decay=0.1))


@pytest.mark.parametrize("plant,decay", [(DC_MOTOR, 0.9), (NEAR_UNIT_FIXED_MODE, 0.999995)])
def test_the_riccati_design_certifies_without_a_solver(plant, decay):
    options = {"dt": 0.01} if plant["time"] == "continuous" else {}
    card = uiofmu.design(_problem(plant, family="lti-uio", decay=decay, method="riccati", **options))
    assert card.data["design_method"] == "riccati" and card.data["certificate"]["solver"] == "none"
    assert card.data["timing"]["solves"] == 0
    assert all(c.holds for c in uiofmu.verify(card))
    N = np.array(card.data["matrices"]["N"])
    assert np.abs(np.linalg.eigvals(N)).max() < decay
    e = np.random.default_rng(3).normal(size=len(N))
    over, ratio = card.data["overshoot_bound"], []
    for k in range(200):                          # the error dynamics e+ = N e against the certified bound
        ratio.append(np.linalg.norm(np.linalg.matrix_power(N, k) @ e) / (over * decay ** k * np.linalg.norm(e)))
    assert max(ratio) <= 1 + 1e-9


def test_riccati_needs_a_number():
    from uiofmu.runtime.errors import ProblemError

    with pytest.raises(ProblemError, match='method = "riccati" needs a number'):
        _problem(DC_MOTOR, family="lti-uio", dt=0.01, method="riccati")


# -- state scaling: the same LMIs in balanced coordinates ------------------------------------------

def test_scaling_maps_the_lmis_by_congruence():
    """An LMI point of the scaled coordinates, mapped back, gives the plant's LMI matrices
    ``D' F D`` with ``D = diag(T^-1, T^-1)``: feasibility is the same in both coordinates."""
    from uiofmu.families import sampled_data as sd
    from uiofmu.scaling import PlantLmis, StateScaling, state_scaling

    plant = problem_from_data({"name": "p", "plant": _badly_scaled(DC_MOTOR, [0, 3, -2]),
                               "observer": {"family": "sampled-data", "intervals": [0.01, 0.02]}}).plant
    samples = [plant.sampled(h) for h in (0.01, 0.02)]
    t = state_scaling(plant.A)
    assert np.all(t <= 1.0) and t.max() == 1.0 and np.all(np.log2(t) == np.round(np.log2(t)))
    assert t.min() < 1e-3                                        # the states 1e5 apart are brought together
    rng = np.random.default_rng(3)
    values = {"mu": np.array(5.0)}
    for i in range(2):
        values[f"Pl{i}"] = (lambda R: R @ R.T + np.eye(3))(rng.standard_normal((3, 3)))
        values[f"S{i}"] = rng.standard_normal((3, 2))
        for j in range(2):
            values[f"Q{i}_{j}"] = rng.standard_normal((3, 2))
    scaling = StateScaling(t)
    scaled, inverse = scaling.apply(PlantLmis(sd._lmis, samples, plant.C))
    plain = sd._lmis(samples, plant.C)
    prm = {"c": 0.9}
    Ti = np.diag(1.0 / t)
    for ms, mp in zip(scaled.evaluate(values, prm), plain.evaluate(scaling.invert(values, inverse), prm)):
        if ms.name.startswith("(15)"):
            D = np.kron(np.eye(2), Ti)
            np.testing.assert_allclose(np.asarray(mp.matrix), D.T @ np.asarray(ms.matrix) @ D,
                                       rtol=1e-9, atol=1e-9 * np.abs(mp.matrix).max())
        elif ms.name.startswith("(16)"):                       # E normalised in each: equal up to a factor
            a, b = np.asarray(mp.matrix), Ti.T @ np.asarray(ms.matrix)
            assert np.linalg.matrix_rank(np.column_stack([a.ravel(), b.ravel()]), tol=1e-9 * np.abs(a).max()) <= 1


@pytest.mark.parametrize("family,key,value", [("sampled-data", "alpha", 0.02), ("lti-uio", "decay", 0.99)])
def test_a_plant_in_other_units_designs_and_records_its_scaling(family, key, value):
    observer = {"family": family, key: value}
    observer.update({"intervals": [0.01, 0.02]} if family == "sampled-data" else {"dt": 0.05})
    card = uiofmu.design(_problem(_badly_scaled(DC_MOTOR, [0, 3, -2]), **observer))
    assert card.data["certificate"]["verified"] and all(c.holds for c in uiofmu.verify(card))
    scaling = card.data["scaling"]
    assert scaling["kind"] == "balance" and min(scaling["state"]) < 1e-3


def test_balanced_plants_design_as_without_scaling(building_card):
    assert building_card[0].data["scaling"]["state"] == [1.0, 1.0]
    data = json.loads(building_card[0].to_json())["problem"]
    data["observer"]["scaling"] = "none"
    plain = uiofmu.design(problem_from_data(data))
    assert plain.data["alpha"] == building_card[0].data["alpha"]
    assert plain.data["scaling"] == {**building_card[0].data["scaling"], "kind": "none"}


def test_a_badly_scaled_weak_mode_designs_in_balanced_coordinates():
    """A campaign plant (E entries 1e7, C rows 0.03 and 3, PBH margin 2e-9) whose "max" search
    failed in the plant's coordinates: balanced, it certifies."""
    from uiofmu.families.random_plants import random_problem

    problem = problem_from_data(random_problem("sampled-data", 7000022))
    card = uiofmu.design(problem)
    assert card.data["certificate"]["verified"] and all(c.holds for c in uiofmu.verify(card))
    assert 0 < card.data["alpha"] and card.data["decay_bound"] < 1


def test_an_interval_pair_without_a_certificate_is_found_and_named():
    """Two intervals that design alone but not together (a campaign plant, seed 11000116, p = q):
    check proves it on ker C, where Corollary 2 is exact (exit 2 before any design); the pair
    diagnosis of a failed design names the pair; either interval alone designs."""
    from uiofmu.families.random_plants import random_problem
    from uiofmu.families.sampled_data import _interval_diagnosis
    from uiofmu.runtime.errors import NoObserverError
    from uiofmu.scaling import state_scaling

    data = random_problem("sampled-data", 11000116)
    problem = problem_from_data(data)
    h1, h2 = data["observer"]["intervals"]
    with pytest.raises(NoObserverError, match="no observer of this family can be certified"):
        uiofmu.design(problem)
    samples = [problem.plant.sampled(h) for h in (h1, h2)]
    note = _interval_diagnosis(samples, problem.plant.C, state_scaling(problem.plant.A), (h1, h2), 1e-5)
    assert f"the pair(s) {h1:g} and {h2:g} s have none" in note and "drop one interval" in note
    for h in (h1, h2):
        alone = uiofmu.design(problem_from_data({**data, "observer": {**data["observer"], "intervals": [h]}}))
        assert alone.data["certificate"]["verified"] and all(c.holds for c in uiofmu.verify(alone))


@pytest.mark.slow
def test_with_p_equal_q_the_design_on_ker_c_certifies_where_the_full_lmis_fail():
    """A campaign plant (seed 11000091, p = q = 1, intervals of 24 to 96 s) whose full LMIs fail
    numerically: the same certificates on ker C design it, verified at the stored matrices."""
    from uiofmu.families.random_plants import random_problem

    card = uiofmu.design(problem_from_data(random_problem("sampled-data", 11000091)))
    assert card.data["design_method"] == "lmi on ker C (p = q)"
    assert card.data["certificate"]["verified"] and all(c.holds for c in uiofmu.verify(card))
    assert 0 < card.data["alpha"] < card.data["alpha_limit_from_zeros"]


@pytest.mark.parametrize("family", ["lti-uio", "ltv-auid", "sampled-data"])
def test_the_units_of_the_unknown_input_and_the_outputs_decide_no_existence_verdict(family):
    """The same plants with d in units 1e10 larger (E scaled by 1e-10) and outputs in units 1e8 larger (C by
    1e-8): every required verdict and every zero is the same (ranks, zeros and fixed modes are decided with C's
    rows and E's columns of unit norm; an E of 1e-10 was found of rank 0, 'rank(CE) = 1 < rank(E) = 0'). The
    note on weakly observable modes is not required and stays in the problem's units: gains of 1e8 times the
    size are what the solver then meets."""
    from uiofmu.families import random_plants as rp

    for doc in rp.campaign(family, 6, 11, plant_class="near-limit-zeros"):
        scaled = copy.deepcopy(doc)
        scaled["plant"]["E"] = (1e-10 * np.array(doc["plant"]["E"], dtype=float)).tolist()
        scaled["plant"]["C"] = (1e-8 * np.array(doc["plant"]["C"], dtype=float)).tolist()
        want, got = (uiofmu.check(problem_from_data(d)).to_data() for d in (doc, scaled))
        assert [(c["name"], c["holds"]) for c in got["conditions"] if c["required"]] == \
            [(c["name"], c["holds"]) for c in want["conditions"] if c["required"]], doc["name"]
        for a, b in zip(want["conditions"], got["conditions"]):
            if "zeros" in a["values"]:
                np.testing.assert_allclose(sorted(np.hypot(*np.array(b["values"]["zeros"]).T)),
                                           sorted(np.hypot(*np.array(a["values"]["zeros"]).T)), rtol=1e-6, atol=1e-9)


def test_balanced_lmis_find_the_plants_least_overshoot():
    """Normalised in the plant's coordinates, lti-uio's LMIs solved in balanced coordinates minimise the plant's
    overshoot bound: the same figure as the LMIs solved in the plant's own coordinates (to the solver's accuracy).
    Where the balance spreads the plant's identity by 1e6, the figure is said to be known to 2 digits only."""
    from uiofmu.certificate import FIGURE_DIGITS

    def card(exponents, scaling):
        return uiofmu.design(_problem(_badly_scaled(DC_MOTOR, exponents), family="lti-uio", scaling=scaling, dt=0.05,
                                      decay=0.99))

    balanced, plain = card([0, 2, -1], "balance"), card([0, 2, -1], "none")
    assert min(balanced.data["scaling"]["state"]) == 0.0625
    assert balanced.data["overshoot_digits"] == plain.data["overshoot_digits"] == FIGURE_DIGITS
    assert balanced.data["overshoot_bound"] == pytest.approx(plain.data["overshoot_bound"], rel=1e-5)
    far, plain = card([0, 3, -2], "balance"), card([0, 3, -2], "none")
    assert min(far.data["scaling"]["state"]) < 1e-3 and far.data["overshoot_digits"] < FIGURE_DIGITS
    assert far.data["overshoot_bound"] == pytest.approx(plain.data["overshoot_bound"], rel=1e-3)
    assert all(c.holds for c in uiofmu.verify(far))
