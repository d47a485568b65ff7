"""The classical UIO: what the theory guarantees, on the paper's example and random plants."""

from __future__ import annotations

import numpy as np
import pytest

import uiofmu
from uiofmu.runtime.errors import InfeasibleError, NoObserverError
from uiofmu.lmi import Lmi, LmiSystem, search
from uiofmu.synthesis import verify
from uiofmu.runtime.tolerances import SEARCH_TOL


def test_example1_properties(example1_card):
    card, _ = example1_card
    M = card.data["matrices"]
    P, E, N = np.array(M["P"]), np.array(M["E_sampled"]), np.array(M["N"])
    assert np.linalg.norm(P @ E) <= 1e-12                         # exact decoupling
    rho = card.data["decay_bound"]
    assert max(abs(np.linalg.eigvals(N))) <= rho                  # spectral radius under the bound
    # "max" reaches the invariant zero 0.99 of the paper, within the search tolerance
    assert 0.99 < rho <= 0.99 + 2 * SEARCH_TOL
    np.testing.assert_allclose(card.data["invariant_zeros"], [[0.99, 0.0]], atol=1e-12)
    assert card.data["certificate"]["verified"] is True
    assert all(c.holds for c in verify(card))


def test_tampered_card_fails_recheck(example1_card):
    card, _ = example1_card
    data = dict(card.data)
    mats = dict(data["matrices"])
    N = np.array(mats["N"])
    N[1, 1] += 0.02
    mats["N"] = N.tolist()
    data["matrices"] = mats
    eig = np.linalg.eigvals(N)                       # the figures the card lists of N, made to match
    data["eigenvalues_N"] = [[float(z.real), float(z.imag)] for z in eig]
    data["spectral_radius_N"] = float(np.abs(eig).max())
    bad = uiofmu.runtime.card.card_from_data(data)
    failed = {c.name for c in verify(bad) if not c.holds}
    assert "eig_min(rho^2 X - N'XN)" in failed and "||PA - NP - LC||" in failed


def test_kept_checks_are_the_checks_made_afresh(example1_card):
    """The certificate a design keeps from its search's re-check, with the identities that read nothing of the
    point checked once for the search's points, is the one the checks make afresh at the card's matrices."""
    from uiofmu.families.lti_uio import checks

    card, _ = example1_card
    m = {k: np.asarray(v, dtype=float) for k, v in card.data["matrices"].items()}
    rho = card.data["decay_bound"]
    afresh = [c.to_data() | {"name": c.name} for c in checks(m, rho)]
    assert [{**v, "name": k} for k, v in card.data["certificate"]["checks"].items()] == afresh
    kept: dict = {}
    other = checks({**m, "K": 1.5 * m["K"], "L": 1.5 * m["L"]}, rho, kept)      # another point first
    assert len(kept) == 1 and not all(c.holds for c in other)
    assert [c.to_data() | {"name": c.name} for c in checks(m, rho, kept)] == afresh


def test_requested_decay(tmp_path, example1_path):
    text = example1_path.read_text().replace('decay = "max"', "decay = 0.995")
    path = tmp_path / "p.toml"
    path.write_text(text)
    card = uiofmu.design(uiofmu.load_problem(path))
    assert card.data["decay_bound"] == 0.995
    assert max(abs(np.linalg.eigvals(np.array(card.data["matrices"]["N"])))) < 0.995


def test_continuous_plant_sampled_design():
    plant = uiofmu.Plant.create([[0.0, 1.0, 0.0], [-2.0, -0.5, 1.0], [0.0, 0.0, -1.0]],
                                [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], [[0.0], [1.0], [0.0]],
                                [[0.0], [0.0], [1.0]], time="continuous")
    problem = uiofmu.make_problem(plant, "lti-uio", dt=0.05, decay=0.995)
    card = uiofmu.design(problem)
    s = plant.sampled(0.05)
    P = np.array(card.data["matrices"]["P"])
    assert np.linalg.norm(P @ s.E) < 1e-12
    assert max(abs(np.linalg.eigvals(np.array(card.data["matrices"]["N"])))) < 0.995
    assert all(c.holds for c in verify(card))


@pytest.mark.parametrize("seed", range(8))
def test_random_plants_either_certified_or_refused(seed):
    rng = np.random.default_rng(seed)
    n, p = 4, 2
    A = rng.normal(size=(n, n))
    A *= 0.9 / max(abs(np.linalg.eigvals(A)))
    plant = uiofmu.Plant.create(A, rng.normal(size=(p, n)), rng.normal(size=(n, 1)), rng.normal(size=(n, 1)),
                                dt=1.0)
    problem = uiofmu.make_problem(plant, "lti-uio", decay="max")
    report = uiofmu.check(problem)
    if not report.exists:
        with pytest.raises(NoObserverError):
            uiofmu.design(problem)
        return
    card = uiofmu.design(problem)
    N = np.array(card.data["matrices"]["N"])
    P, E = np.array(card.data["matrices"]["P"]), plant.E
    assert np.linalg.norm(P @ E) < 1e-9 * max(1, np.linalg.norm(E))
    assert max(abs(np.linalg.eigvals(N))) <= card.data["decay_bound"]
    assert all(c.holds for c in verify(card))


def _toy(p0=0.0):
    def build(v, prm, ops):
        return [Lmi("X >= 1", v["X"] - ops.eye(1), strict=False),
                Lmi("(1 - s) X > 0", (1.0 - prm["s"]) * v["X"] + 0.0 * ops.eye(1))]
    return LmiSystem("toy", {"X": ("symmetric", 1)}, {"s": p0}, build)


def test_lmi_infeasible_names_the_lmi():
    with pytest.raises(InfeasibleError) as info:
        _toy().require(s=1.5)
    assert "toy LMIs are infeasible at s = 1.5" in str(info.value)
    assert "(1 - s) X > 0 needs slack" in str(info.value)


def test_lmi_search_finds_the_boundary():
    found = search(_toy(), "s", 0.0, 2.0, tol=1e-3)
    assert 1.0 - 2e-3 < found.value < 1.0
    assert found.solution.verified and found.solves >= 10


def test_make_problem_warns_of_an_initial_error_of_zero():
    """From Python (python-control) a plant's x0 defaults to 0, as the observer's xhat0: a
    co-simulation would show no convergence, and make_problem says so; any other x0 is quiet."""
    import warnings

    args = ([[0.5, 0.1], [0.0, 0.3]], [[1.0, 1.0]], [[1.0], [0.0]], [[1.0], [0.0]])
    with pytest.warns(UserWarning, match="estimation error starts at 0"):
        uiofmu.make_problem(uiofmu.Plant.create(*args, dt=1.0), "lti-uio", decay=0.6)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        uiofmu.make_problem(uiofmu.Plant.create(*args, dt=1.0, x0=[1.0, -1.0]), "lti-uio", decay=0.6)
        uiofmu.make_problem(uiofmu.Plant.create(*args, dt=1.0), "lti-uio", decay=0.6, xhat0=[0.5, 0.0])
