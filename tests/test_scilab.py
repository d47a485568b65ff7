"""uiofmu's lti-uio next to Scilab's ``ui_observer`` on the same seeded discrete plants (``tests/scilab_compare.py``).

Where Scilab's observer is valid (it decouples the unknown input exactly, to a tolerance relative to the norms
of the equations, and is stable), uiofmu's check holds and its design is certified, decoupling and stable below
its decay bound; where uiofmu's check fails, Scilab's observer is not valid or Scilab errors. Both observers are
judged by the same function, which trusts neither. The comparison skips, saying why, where ``scilab-cli`` is not
installed; the tests of the judge and of the script run everywhere.

Measured on the 24 plants (``python tests/scilab_compare.py``; ``docs/families/lti-uio.md``): 14 both valid;
where no observer exists Scilab returns one silently on 4 (unstable, or residual 0.11 to 0.7) and errors on 2;
where one exists Scilab errors on 4 (an internal dimension error, or no output matrices on each plant whose
unknown input feeds through). uiofmu is right in each of the 10 disagreements.
"""

from __future__ import annotations

import numpy as np
import pytest

import scilab_compare as sc


@pytest.fixture(scope="module")
def rows():
    """The comparison (one Scilab run for every plant); the tests that need it skip where Scilab is absent."""
    if not sc.available():
        pytest.skip(sc.NO_SCILAB)
    return sc.compare(sc.plants(sc.COUNT, sc.SEED))


def test_where_scilab_is_valid_uiofmu_certifies(rows):
    valid = [r for r in rows if r.scilab_valid]
    assert len(valid) >= sc.COUNT // 2
    for r in valid:
        assert r.exists, f"{r.plant.name}: Scilab's observer is valid, uiofmu's check says: {r.why_none}"
        assert r.certified, f"{r.plant.name}: not certified: {r.why_none}"
        assert r.ours.valid, f"{r.plant.name}: uiofmu's observer: {r.ours.why()}"
        assert r.ours.radius < r.decay_bound < 1.0


def test_where_no_observer_exists_scilab_has_none_valid(rows):
    none = [r for r in rows if not r.exists]
    assert {r.plant_class for r in none} >= {"rank-deficient", "unstable-zero"}
    for r in none:
        assert r.why_none
        assert not r.scilab_valid, f"{r.plant.name}: Scilab's observer decouples and is stable, uiofmu says: " \
                                   f"{r.why_none}"
        assert r.scilab_error or not r.scilab.valid


def test_every_observer_uiofmu_designs_is_valid(rows):
    for r in rows:
        if r.exists:
            assert r.certified and r.ours.valid, f"{r.plant.name}: {r.why_none or r.ours.why()}"


def test_the_disagreements_are_the_measured_ones(rows):
    """The counts of the docstring and of docs/families/lti-uio.md."""
    kinds = [r.outcome.split(" (")[0] for r in rows]
    assert {k: kinds.count(k) for k in set(kinds)} == {
        "both valid": 14, "no observer exists; Scilab returns one silently": 4,
        "no observer exists; Scilab errors": 2, "an observer exists; Scilab errors": 4}


def test_the_judge_tells_a_decoupling_observer_from_one_that_is_not():
    """The judge on a plant by hand: ``x1`` measured, ``d`` on ``x1``; the reduced observer of ``x2`` decouples,
    the same with the wrong sign on ``y`` does not; with ``Ao`` outside the unit circle it is unstable."""
    plant = sc.Plant("hand", np.array([[0.5, 0.2], [0.1, 0.3]]), np.zeros((2, 0)), np.array([[1.0], [0.0]]),
                     np.array([[1.0, 0.0]]), np.zeros((1, 0)), np.zeros((1, 1)))
    # xo = x2: xo+ = 0.3 xo + 0.1 y, xhat = [y; xo]
    good = sc.Observer(np.array([[0.3]]), np.zeros((1, 0)), np.array([[0.1]]), np.array([[0.0], [1.0]]),
                       np.zeros((2, 0)), np.array([[1.0], [0.0]]))
    verdict = sc.judge(good, plant)
    assert verdict.valid and verdict.residual < 1e-15 and verdict.radius == pytest.approx(0.3)
    bad = sc.Observer(good.Ao, good.Bu, -good.By, good.Co, good.Du, good.Dy)
    assert not sc.judge(bad, plant).decouples
    unstable = sc.Plant("hand-unstable", np.array([[0.5, 0.2], [0.1, 1.5]]), plant.B, plant.E, plant.C, plant.D,
                        plant.F)
    ao = sc.Observer(np.array([[1.5]]), good.Bu, good.By, good.Co, good.Du, good.Dy)
    v = sc.judge(ao, unstable)
    assert v.decouples and not v.stable and "spectral radius 1.5" in v.why()


def test_the_script_holds_only_numbers():
    plants = [sc.Plant.from_doc(doc) for doc, _ in sc.plants(3, sc.SEED)]
    text = sc.script(plants)
    assert "lti-uio" not in text and all(p.name not in text for p in plants)
    with pytest.raises(ValueError, match="non-finite"):
        sc.literal(np.array([[np.nan]]))
