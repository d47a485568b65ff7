"""The LMI coordinate changes as reductions (uiofmu.reductions): each variable declares how it maps
back; a point mapped to the reduced coordinates and back is the point; a certificate of the reduced
LMIs, solved by CLARABEL, maps back to a certificate of the original LMIs, both evaluated with numpy."""

from __future__ import annotations

import numpy as np
import pytest

from uiofmu.families import lti_uio
from uiofmu.families import sampled_data as sd
from uiofmu.families.random_plants import random_problem
from uiofmu.lmi import eig_min
from uiofmu.problem import problem_from_data
from uiofmu.reductions import (
    LYAPUNOV,
    PRODUCT,
    UNCHANGED,
    UPPER_BOUND,
    CongruenceData,
    DiagonalCongruence,
    congruent,
    mean_root,
    reduced_values,
    role_of,
    roles,
    scalar,
    symmetric,
)
from uiofmu.scaling import PlantLmis, StateScaling, state_scaling


def _random_point(rng, variables: dict) -> dict:
    """Random values of every variable: symmetric positive definite Lyapunov matrices, any matrices,
    positive scalars."""
    out = {}
    for name, spec in variables.items():
        if spec[0] == "symmetric":
            R = rng.standard_normal((spec[1], spec[1]))
            out[name] = R @ R.T + np.eye(spec[1])
        elif spec[0] == "matrix":
            out[name] = rng.standard_normal(spec[1])
        else:
            out[name] = np.asarray(1.0 + rng.random())
    return out


def _stable(rng, n: int, radius: float) -> np.ndarray:
    A = rng.standard_normal((n, n))
    return A * (radius / np.abs(np.linalg.eigvals(A)).max())


# -- the declarations ---------------------------------------------------------------------------

def test_every_variable_of_the_transformed_lmis_declares_how_it_maps_back():
    plant = problem_from_data(random_problem("sampled-data", 5)).plant
    full = roles(sd._lmis([plant.sampled(h) for h in (0.1, 0.2)], plant.C, gain_cap=10.0).variables)
    assert full["mu"] == UPPER_BOUND and full["s"] == UNCHANGED
    assert {full[k] for k in full if k.startswith("Pl")} == {LYAPUNOV}
    assert {full[k] for k in full if k[0] in "SQ"} == {PRODUCT}
    one = roles(lti_uio._lmis(np.eye(2), np.ones((1, 2))).variables)
    assert one == {"X": LYAPUNOV, "W": PRODUCT, "t": UPPER_BOUND}


def test_a_matrix_without_a_role_and_an_unknown_role_are_refused():
    assert role_of(("scalar",)) == UNCHANGED
    with pytest.raises(ValueError, match="declares no role"):
        role_of(("symmetric", 3))
    with pytest.raises(ValueError, match="unknown role"):
        symmetric(3, "transpose")
    with pytest.raises(ValueError, match="unknown role"):
        scalar("congruence")


# -- apply then invert ----------------------------------------------------------------------------

def _variables(n: int, p: int) -> dict:
    return {"X": symmetric(n), "W": ("matrix", (n, p), PRODUCT), "mu": scalar(UPPER_BOUND), "g": scalar()}


@pytest.mark.parametrize("seed", range(5))
def test_a_diagonal_congruence_of_powers_of_two_maps_there_and_back_exactly(seed):
    rng = np.random.default_rng(seed)
    n = 4
    data = CongruenceData(DiagonalCongruence(2.0 ** rng.integers(-30, 1, n).astype(float)), roles(_variables(n, 2)))
    values = _random_point(rng, _variables(n, 2))
    back = congruent(reduced_values(values, data), data)
    for k in ("X", "W", "g"):
        np.testing.assert_array_equal(back[k], values[k])
    d = data.congruence.d
    Xs = reduced_values(values, data)["X"]
    np.testing.assert_array_equal(Xs, values["X"] * np.outer(d, d))        # Xs = T' X T
    # a bound is mapped to one that holds: X <= mu I there, and the mapped X <= mapped mu here
    mu = np.linalg.eigvalsh(Xs)[-1]
    assert np.linalg.eigvalsh(congruent({"X": Xs, "mu": mu, "W": values["W"], "g": 1.0}, data)["X"])[-1] \
        <= float(congruent({"mu": mu}, data)["mu"]) * (1 + 1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_a_recentring_maps_there_and_back(seed):
    rng = np.random.default_rng(seed)
    variables = {"mu": scalar(UPPER_BOUND), "P0": symmetric(3), "P1": symmetric(3), "W": ("matrix", (3, 2), PRODUCT)}
    values = _random_point(rng, variables)
    root = mean_root(values, roles(variables))
    P0 = 0.5 * (values["P0"] + values["P1"])
    np.testing.assert_allclose(root.R @ root.R, P0 / np.linalg.eigvalsh(P0)[0], rtol=1e-10)
    np.testing.assert_allclose(root.R @ root.inverse, np.eye(3), atol=1e-10)
    data = CongruenceData(root, roles(variables))
    there = reduced_values(values, data)
    np.testing.assert_allclose(0.5 * (there["P0"] + there["P1"]), np.eye(3) * np.linalg.eigvalsh(P0)[0], rtol=1e-9,
                               atol=1e-9)                     # the mean Lyapunov matrix becomes a multiple of I
    back = congruent(there, data)
    for k in ("P0", "P1", "W"):
        np.testing.assert_allclose(back[k], values[k], rtol=1e-9, atol=1e-9 * np.abs(values[k]).max())


def test_a_mean_that_is_not_positive_definite_gives_no_recentring():
    variables = {"P0": symmetric(2)}
    assert mean_root({"P0": -np.eye(2)}, roles(variables)) is None


# -- certificates map back ------------------------------------------------------------------------

def _strict_and_equalities(lmis) -> tuple:
    eigs = eig_min(lmis)
    strict = [eigs[m.name] for m in lmis if m.strict and not m.equality]
    residuals = [np.abs(np.asarray(m.matrix)).max() for m in lmis if m.equality]
    return strict, residuals


def _loose(lmis) -> float:
    """The least eigenvalue of the non-strict LMIs (normalisations and bounds): what the solver left of them."""
    eigs = eig_min(lmis)
    return min(eigs[m.name] for m in lmis if not m.strict and not m.equality)


@pytest.mark.parametrize("seed", range(3))
def test_a_certificate_of_the_balanced_decay_lmi_is_one_of_the_plants(seed):
    """Solved for a plant whose states differ by 1e6 in scale, in its balanced coordinates; the point
    mapped back certifies the plant's own LMI (the congruence by ``T^-1 >= I`` only raises the margins)."""
    rng = np.random.default_rng(seed)
    D = np.diag([1.0, 1e3, 1e-3])
    A = D @ _stable(rng, 3, 0.6) @ np.linalg.inv(D)
    C = rng.standard_normal((1, 3)) @ np.linalg.inv(D)
    scaling = StateScaling(state_scaling(A))
    from uiofmu.plant import Sampled

    step = Sampled(A=A, B=np.zeros((3, 1)), E=np.zeros((3, 1)), w=np.zeros(3), h=1.0)
    system, inverse = scaling.apply(PlantLmis(lambda steps, Cs: lti_uio._lmis(steps[0].A, Cs), [step], C))
    sol = system.solve(rho2=0.81)
    assert sol.verified
    reduced_strict, _ = _strict_and_equalities(system.evaluate(sol.values, {"rho2": 0.81}))
    plain = lti_uio._lmis(A, C)
    mapped = scaling.invert(sol.values, inverse)
    strict, _ = _strict_and_equalities(plain.evaluate(mapped, {"rho2": 0.81}))
    assert min(reduced_strict) > 0 and min(strict) >= min(reduced_strict) * (1 - 1e-9)
    assert plain.recheck(mapped, {"rho2": 0.81}).verified


def test_a_certificate_of_the_balanced_sampled_data_lmis_is_one_of_the_plants():
    """A campaign plant with states 1e5 apart (seed 7000022): its Corollary 2 certificate in the balanced
    coordinates maps back to one of (15)-(16) in the plant's, normalisations and bound included."""
    problem = problem_from_data(random_problem("sampled-data", 7000022))
    analysis = sd.analyse(problem)
    samples, C = analysis.data["samples"], problem.plant.C
    t = state_scaling(problem.plant.A, "balance")
    assert t.min() < 1.0                                  # the balancing changes the coordinates
    scaling = StateScaling(t)
    system, inverse = scaling.apply(PlantLmis(sd._lmis, samples, C))
    c = 1.0 - 1e-3 * (1.0 - analysis.data["decay_floor"] ** 2)
    sol = system.largest_margin(c=c)
    assert sol.verified
    reduced = system.evaluate(sol.values, {"c": c})
    mapped = scaling.invert(sol.values, inverse)
    plain = sd._lmis(samples, C)
    lmis = plain.evaluate(mapped, {"c": c})
    strict, residuals = _strict_and_equalities(lmis)
    assert min(strict) >= min(_strict_and_equalities(reduced)[0]) * (1 - 1e-9) > 0     # by T^-1 >= I
    # Pl >= I and Pl <= mu I hold as well as the solver left them there (times |T^-1|^2 <= 1 / t_min^2)
    assert _loose(lmis) >= min(_loose(reduced), 0.0) / t.min() ** 2 - 1e-12
    scale = max(np.abs(mapped[f"Pl{i}"]).max() for i in range(len(samples)))
    assert max(residuals) <= 1e-6 * scale                                               # (16)


def test_a_certificate_on_ker_c_lifts_to_one_of_the_full_lmis():
    """p = q (seed 5): Corollary 2 on ker C, solved; its point lifted by KerC.invert satisfies (15)-(16)
    evaluated with numpy, and restricted to ker C again is the point itself."""
    problem = problem_from_data(random_problem("sampled-data", 5))
    assert problem.plant.p == problem.plant.q
    analysis = sd.analyse(problem)
    samples, C = analysis.data["samples"], problem.plant.C
    reduction = sd.KerC()
    system, inverse = reduction.apply((samples, C))
    c = 1.0 - 0.5 * (1.0 - analysis.data["decay_floor"] ** 2)
    sol = system.solve(c=c)
    assert sol.verified
    reduced = system.evaluate(sol.values, {"c": c})
    assert min(_strict_and_equalities(reduced)[0]) > 0
    full = reduction.invert(sol.values, inverse)
    lmis = sd._lmis(samples, C).evaluate(full, {"c": c})
    strict, residuals = _strict_and_equalities(lmis)
    assert min(strict) > 0
    assert _loose(lmis) >= min(_loose(reduced), 0.0) - 1e-12        # Pl_i >= I, Pl_i <= mu I as P_i's
    assert max(residuals) <= 1e-9 * max(np.abs(full[f"Pl{i}"]).max() for i in range(len(samples)))
    N = np.linalg.svd(C)[2][C.shape[0]:].T                                              # ker C
    for i in range(len(samples)):
        np.testing.assert_allclose(N.T @ full[f"Pl{i}"] @ N, sol.values[f"P{i}"], rtol=1e-10,
                                   atol=1e-10 * np.abs(sol.values[f"P{i}"]).max())


def test_a_certificate_of_recentred_ker_c_lmis_maps_back_to_one_of_the_original():
    """Seed 11000114 (p = q): the ker C LMIs in the coordinates centred on a refused point; their solved
    point, mapped back, passes the re-check of the original LMIs, and the margins of the recentred LMIs
    carry over (``P0 >= I``)."""
    problem = problem_from_data(random_problem("sampled-data", 11000114))
    analysis = sd.analyse(problem)
    F = sd.fixed_error_maps(analysis.data["samples"], problem.plant.C)
    c = 1.0 - 0.5 * (1.0 - analysis.data["decay_floor"] ** 2)
    original = sd._reduced_lmis(F, recentre=False)
    refused = original.solve(c=c)
    assert refused.values and not refused.verified
    reduction = sd._recentring(F, original.variables)
    system, inverse = reduction.apply(refused.values)
    sol = system.solve(c=c)
    assert sol.verified
    reduced_strict, _ = _strict_and_equalities(system.evaluate(sol.values, {"c": c}))
    mapped = reduction.invert(sol.values, inverse)
    strict, _ = _strict_and_equalities(original.evaluate(mapped, {"c": c}))
    assert min(strict) >= min(reduced_strict) * (1 - 1e-9) > 0
    assert original.recheck(mapped, {"c": c}).verified
