"""Refusals that say what would help: every suggestion, applied to the problem, makes the check pass.

An extra measured state (a unit row added to C), another sampling period or set of intervals, a slower
decay (lti-uio ``decay``, sampled-data ``alpha``, ltv-auid ``eta``), more delays (delayed-uio): each is
re-checked here with the suggestion applied, and a suggestion that none of the candidates helps is
checked against every candidate. The dead-beat refusal names a product of the Phat_i that never vanishes.
"""

from __future__ import annotations

import copy
import itertools
import re

import numpy as np
import pytest

from uiofmu.decoupling import MAX_ROW_PAIRS, PERIOD_FACTORS, short_above, short_below
from uiofmu.families.deadbeat_functional import lasting_product, nilpotency_class
from uiofmu.problem import problem_from_data
from uiofmu.synthesis import check

#: A chain of three tanks: a leak into tank 1, the level of tank 3 measured (relative degree 3: sampled
#: zeros -1.80 and -0.12 at dt = 1 s, -0.896 and -0.055 at 2 s).
TANKS = {"time": "continuous", "A": [[-1.0, 0.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, -1.0]],
         "B": [[1.0], [0.0], [0.0]], "E": [[1.0], [0.0], [0.0]], "C": [[0.0, 0.0, 1.0]]}
#: The same chain sampled at 1 s, with the leak into the last tank and the first tank measured: rank(CE) = 0.
TANKS_UPSTREAM = {"time": "discrete", "dt": 1.0, "A": [[0.6, 0.0, 0.0], [0.3, 0.6, 0.0], [0.0, 0.3, 0.6]],
                  "E": [[0.0], [0.0], [0.5]], "C": [[1.0, 0.0, 0.0]]}
#: A cart-pole linearised upright (cart 1 kg, pole 0.1 kg, 0.5 m), states x, x', theta, theta', a force
#: disturbance on the cart, position and angle measured: a sampled zero at -1 at every period.
CART_POLE = {"time": "continuous",
             "A": [[0.0, 1.0, 0.0, 0.0], [0.0, 0.0, -0.981, 0.0], [0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 21.582, 0.0]],
             "B": [[0.0], [1.0], [0.0], [-2.0]], "E": [[0.0], [1.0], [0.0], [-2.0]],
             "C": [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]]}


def analysed(plant: dict, observer: dict, **rest):
    """The existence report of a problem document."""
    return check(problem_from_data({"name": "hint", "plant": plant, "observer": observer, **rest}))


def hinted(report):
    """The first failing required condition (it carries the hint)."""
    failing = report.failures
    assert failing, "the problem was expected to be refused"
    assert failing[0].hint
    return failing[0]


def states(hint: str) -> list[int]:
    """The 0-based states of ``measuring x[i] and x[j] (adding ...`` (the first suggestion)."""
    named = re.match(r"measuring (.*?) \(adding", hint[hint.index("measuring"):]).group(1)
    return [int(i) - 1 for i in re.findall(r"x\[(\d+)\]", named)]


def measuring(plant: dict, rows) -> dict:
    """``plant`` with the unit rows of ``rows`` added to its C."""
    n = len(plant["A"])
    return {**plant, "C": plant["C"] + [np.eye(n)[i].tolist() for i in rows]}


def number(hint: str, key: str) -> float:
    return float(re.search(rf"{key} = ([0-9.e+-]+)", hint).group(1))


def test_rank_refusal_names_the_state_to_measure_and_it_decouples(cli, tmp_path):
    report = analysed(TANKS_UPSTREAM, {"family": "lti-uio", "decay": "max"})
    cond = hinted(report)
    assert cond.name == "rank(CE) = rank(E)" and "rank(CE) = 0 < rank(E) = 1" in cond.message
    assert states(cond.hint) == [2]
    assert "rank(CE) = 1 = rank(E)" in cond.hint
    fixed = analysed(measuring(TANKS_UPSTREAM, [2]), {"family": "lti-uio", "decay": "max"})
    assert fixed.exists
    # the command line prints it under the failing line, and the refusal repeats it
    from uiofmu.problem import to_toml

    path = tmp_path / "tanks.toml"
    path.write_text(to_toml({"name": "tanks", "plant": TANKS_UPSTREAM,
                             "observer": {"family": "lti-uio", "decay": "max"}}), encoding="utf-8")
    result = cli("check", path)
    assert result.code == 2
    lines = result.out.splitlines()
    at = next(i for i, line in enumerate(lines) if "[FAIL] rank(CE) = 0" in line)
    assert lines[at + 1].strip().startswith("would help: measuring x[3] (adding the row e_3' to C)")
    assert "would help: measuring x[3]" in result.err


def _random_rank_deficient(rng, n: int, p: int, q: int) -> dict:
    """A discrete plant whose unknown inputs the outputs do not see at once (CE = 0), some of its modes
    outside the unit circle, some of its entries zero."""
    A = rng.normal(size=(n, n))
    A *= rng.uniform(0.5, 1.6) / max(abs(np.linalg.eigvals(A)))
    A[np.abs(A) < rng.uniform(0.0, 0.5)] = 0.0
    E = rng.normal(size=(n, q))
    C = rng.normal(size=(p, n))
    C -= C @ E @ np.linalg.solve(E.T @ E, E.T)
    return {"time": "discrete", "dt": 1.0, "A": A.tolist(), "E": E.tolist(), "C": C.tolist()}


def test_extra_measurement_hints_on_random_plants():
    """Whatever the hint claims is what the check finds with the row(s) applied, and "none" is exhaustive."""
    rng = np.random.default_rng(28)
    seen = {"every": 0, "none": 0}
    observer = {"family": "lti-uio", "decay": "max"}
    for _ in range(40):
        n = int(rng.integers(3, 6))
        plant = _random_rank_deficient(rng, n, int(rng.integers(1, n - 1)), int(rng.integers(1, 4)))
        report = analysed(plant, observer)
        cond = hinted(report)
        assert cond.name == "rank(CE) = rank(E)"
        if cond.hint.startswith("no added measurement"):
            seen["none"] += 1
            for rows in itertools.chain(itertools.combinations(range(n), 1),
                                        itertools.islice(itertools.combinations(range(n), 2), MAX_ROW_PAIRS)):
                assert not analysed(measuring(plant, rows), observer).holds("rank(CE) = rank(E)")
            continue
        after = analysed(measuring(plant, states(cond.hint)), observer)
        assert after.holds("rank(CE) = rank(E)")
        if "every condition of exact decoupling holds" in cond.hint:
            seen["every"] += 1
            assert after.exists
        else:
            assert not after.exists
    assert seen["every"] >= 10 and seen["none"] >= 3               # both kinds of answer are exercised


def test_a_measurement_that_only_decouples_says_so():
    """Two unstable modes nothing sees: measuring x[1] decouples d, and no pair of measured states also
    makes both modes detectable."""
    A = np.diag([0.5, 0.5, 0.5, 1.5, 1.4])
    A[1, 0] = A[2, 1] = 0.3
    plant = {"time": "discrete", "dt": 1.0, "A": A.tolist(), "E": np.eye(5)[:, :1].tolist(),
             "C": [np.eye(5)[2].tolist()]}
    observer = {"family": "lti-uio", "decay": "max"}
    cond = hinted(analysed(plant, observer))
    assert "but other conditions of exact decoupling still fail" in cond.hint
    after = analysed(measuring(plant, states(cond.hint)), observer)
    assert after.holds("rank(CE) = rank(E)") and not after.exists
    for rows in itertools.chain(itertools.combinations(range(5), 1), itertools.combinations(range(5), 2)):
        assert not analysed(measuring(plant, rows), observer).exists


def test_sampled_zero_hint_lists_the_periods_that_work():
    observer = {"family": "lti-uio", "dt": 1.0, "decay": "max"}
    cond = hinted(analysed(TANKS, observer))
    assert cond.name == "stable invariant zeros"
    listed = [float(v) for v in re.search(r"observer\.dt = ([0-9. or]+) s", cond.hint).group(1).split(" or ")]
    assert listed == [2.0, 4.0]
    for factor in PERIOD_FACTORS:                  # exactly the listed ones pass
        assert analysed(TANKS, {**observer, "dt": factor}).exists == (factor in listed)
    # and a measured state removes the zeros at the given period
    assert analysed(measuring(TANKS, states(cond.hint)), observer).exists


def test_sampled_data_hint_scales_the_intervals():
    observer = {"family": "sampled-data", "intervals": [1.0, 1.5], "alpha": "max"}
    cond = hinted(analysed(TANKS, observer))
    assert cond.name == "stable sampled invariant zeros"
    sets = re.findall(r"\[([0-9., ]+)\]", cond.hint.split("observer.intervals = ")[1].split(" s:")[0])
    listed = [[float(v) for v in s.split(", ")] for s in sets]
    assert listed == [[2.0, 3.0], [4.0, 6.0]]
    for intervals in listed:
        assert analysed(TANKS, {**observer, "intervals": intervals}).exists


@pytest.mark.parametrize("observer", [{"family": "lti-uio", "dt": 0.01, "decay": "max"},
                                      {"family": "sampled-data", "intervals": [0.01, 0.02], "alpha": "max"}])
def test_cart_pole_zero_at_minus_one_needs_a_velocity(observer):
    """No other sampling moves the zero at -1 (the hint says so, and each candidate is refused); measuring a
    velocity removes it."""
    cond = hinted(analysed(CART_POLE, observer))
    assert "-1" in cond.message
    assert "no sampling at 0.25, 0.5, 2, 4 times the given" in cond.hint
    key = "dt" if "dt" in observer else "intervals"
    for factor in PERIOD_FACTORS:
        scaled = factor * observer[key] if key == "dt" else [factor * h for h in observer[key]]
        assert not analysed(CART_POLE, {**observer, key: scaled}).exists
    rows = states(cond.hint)
    assert rows in ([1], [3])                     # x' or theta'
    assert analysed(measuring(CART_POLE, rows), observer).exists


def test_too_fast_decays_get_the_fastest_allowed():
    # lti-uio at dt = 2 s: fixed modes -0.896, -0.055
    lti = {"family": "lti-uio", "dt": 2.0, "decay": 0.5}
    cond = hinted(analysed(TANKS, lti))
    assert cond.name == "decay above fixed modes"
    decay = number(cond.hint, "decay")
    assert 0.895 < decay < 0.9
    assert analysed(TANKS, {**lti, "decay": decay}).exists
    # sampled-data on 2 and 3 s
    sd = {"family": "sampled-data", "intervals": [2.0, 3.0], "alpha": 0.9}
    cond = hinted(analysed(TANKS, sd))
    alpha = number(cond.hint, "alpha")
    assert 0.19 < alpha < 0.1976
    assert analysed(TANKS, {**sd, "alpha": alpha}).exists
    # ltv-auid's eta at dt = 2 s
    ltv = {"family": "ltv-auid", "dt": 2.0, "alpha": 0.5, "eta": 0.5}
    cond = hinted(analysed(TANKS, ltv))
    assert cond.name == "eta below the zero limit"
    eta = number(cond.hint, "eta")
    assert analysed(TANKS, {**ltv, "eta": eta}).holds("eta below the zero limit")
    # ltv-auid's mu: a mode at 0.8 that C does not see stays in the transient vertex (A_1, C)
    hidden = {"time": "discrete", "dt": 1.0, "A": [[0.5, 0.0], [0.0, 0.8]], "E": [[1.0], [0.0]], "C": [[1.0, 0.0]]}
    ltv = {"family": "ltv-auid", "alpha": 0.5, "eta": 0.1, "mu": 3.0}
    cond = hinted(analysed(hidden, ltv))
    assert cond.name == "transient vertex (A_1, C)"
    mu = number(cond.hint, "mu")
    assert mu == 2.59                              # the limit (1 - 0.8^2) / 0.1 - 1 = 2.6, on its safe side
    assert analysed(hidden, {**ltv, "mu": mu}).exists


def test_short_numbers_stay_on_their_side():
    for x in (0.197604, 0.8957655, 1e-5, 0.5, 123.456789):
        assert short_below(x) < x < short_above(x)
        assert abs(short_below(x) - x) <= 1e-2 * x and abs(short_above(x) - x) <= 1e-2 * x
        assert all(float(f"{v:.3g}") == v for v in (short_below(x), short_above(x)))


#: An LPV plant whose Phat_1 and Phat_2 are nilpotent (every eigenvalue 0) while Phat_2 Phat_1 is not.
MIXED = {"time": "discrete", "dt": 1.0, "A": [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]],
         "E": [[1.0], [0.0], [0.0]], "C": [[1.0, 0.0, 0.0]],
         "scheduling": [{"A": [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]]}], "theta": {"kind": "input"}}


def test_deadbeat_refusal_shows_the_product_that_stays():
    report = analysed(MIXED, {"family": "deadbeat-functional", "G": "identity"})
    cond = report.failures[0]
    assert cond.name == "nilpotent semigroup"
    Phat = [np.array(P) for P in report.value("robust invariant subspace in ker G", "Phat")]
    assert all(np.allclose(np.linalg.eigvals(P), 0.0) for P in Phat)      # each one alone looks dead-beat
    product = np.eye(3)
    for i in cond.values["product"]:
        product = Phat[i - 1] @ product
    assert max(abs(np.linalg.eigvals(product))) == pytest.approx(1.0)   # its powers never vanish
    assert cond.values["product_norm"] == pytest.approx(np.linalg.norm(product, 2))
    assert "the product Phat_2·Phat_1 (norm 1, eigenvalues 0, 0, 1)" in cond.message


def test_lasting_product_on_random_semigroups():
    """Nilpotent one by one, not together: the product named has a non-zero eigenvalue."""
    rng = np.random.default_rng(3)
    for _ in range(30):
        h = int(rng.integers(2, 5))
        mats = []
        for _ in range(int(rng.integers(2, 4))):       # strictly triangular in a random basis each
            T = rng.normal(size=(h, h))
            mats.append(T @ np.triu(rng.normal(size=(h, h)), 1) @ np.linalg.inv(T))
        if nilpotency_class(mats) is not None:
            continue
        sequence, product, cycles = lasting_product(mats)
        assert cycles and max(abs(np.linalg.eigvals(product))) > 1e-6
        expected = np.eye(h)
        for i in sequence:
            expected = mats[i] @ expected
        np.testing.assert_allclose(product, expected)


#: A mass-spring-damper x'' = -k x - c x' + f with theta = (k, c, f) unknown, position and velocity measured:
#: rule (7) gives m = 1, but D(y) has rank 1, so each delayed copy adds one rank: m = 2 is needed.
MSD = {"time": "continuous", "A": [[0.0, 1.0], [0.0, 0.0]], "B": [[0.0], [1.0]], "C": [[1.0, 0.0], [0.0, 1.0]],
       "parameters": {"theta": [4.0, 0.5, 0.2], "D0": [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
                      "Dy": [{"output": 1, "D": [[0.0, 0.0, 0.0], [-1.0, 0.0, 0.0]]},
                             {"output": 2, "D": [[0.0, 0.0, 0.0], [0.0, -1.0, 0.0]]}]}}
MSD_OBSERVER = {"family": "delayed-uio", "delays": [0.5], "decay": 1.0, "dt": 0.001,
                "premise": {"signals": "u", "count": 3, "samples": 100, "seed": 1, "duration": 5.0}}
MSD_SIGNALS = {"u": [[{"kind": "sine", "amplitude": 2.0, "frequency_hz": 0.5},
                      {"kind": "sine", "amplitude": 1.0, "frequency_hz": 0.23}]]}


def test_delayed_rule_seven_too_few_delays_suggests_the_fewest_that_work():
    report = analysed(MSD, MSD_OBSERVER, signals=MSD_SIGNALS)
    assert report.holds("delays from rule (7)")
    cond = hinted(report)                               # refused before any premise point, not [ok] then inf
    assert cond.name == "rank C D_y at generic outputs"
    assert "rank C D_y = 2 < n_theta = 3" in cond.message
    assert not any(c.name == "P_y D_y = 0" for c in report.conditions)
    delays = [float(v) for v in re.search(r"e\.g\. \[([0-9., ]+)\]", cond.hint).group(1).split(", ")]
    assert "m = 2" in cond.hint and delays == [0.5, 1.0]
    after = analysed(MSD, {**MSD_OBSERVER, "delays": delays}, signals=MSD_SIGNALS)
    assert after.exists
    assert after.value("P_y D_y = 0", "residual") <= 1e-9


def test_delayed_without_enough_outputs_says_no_delays_help():
    plant = copy.deepcopy(MSD)
    plant["parameters"]["Dy"][1]["D"] = [[0.0, 0.0, 0.0], [-2.0, 0.0, 0.0]]     # k and c act alike
    cond = hinted(analysed(plant, MSD_OBSERVER, signals=MSD_SIGNALS))
    assert cond.hint.startswith("no number of delays")
    assert not analysed(plant, {**MSD_OBSERVER, "delays": [0.5, 1.0, 1.5]}, signals=MSD_SIGNALS).exists
