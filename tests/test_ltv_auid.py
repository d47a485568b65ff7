"""Asymptotic-decoupling LTV observer (seed 000): what Theorem 2 and the construction guarantee."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

import uiofmu
from uiofmu.fmu.export import build_observer, build_plant
from uiofmu.problem import problem_from_data
from uiofmu.cosim.fmi import Fmu, FmuCallError
from uiofmu.runtime.observer import Runtime
from uiofmu.runtime.schedules import StepRejected
from uiofmu.cosim.validate import validate
from tests.conftest import EXAMPLES


def plant_of(card):
    d = card.data["problem"]["plant"]
    return uiofmu.Plant.create(d["A"], d["C"], d["E"], d["B"], dt=d["dt"], x0=d["x0"])


def test_certificate_and_identities(ltv_card):
    card, _ = ltv_card
    assert card.data["certificate"]["verified"] is True
    assert all(c.holds for c in uiofmu.verify(card))
    assert card.data["tau1"] == pytest.approx(0.01 * 91) and card.data["tau2"] == 0.01


@pytest.mark.parametrize("k", [0, 1, 3, 10, 50])
def test_conditions_1_to_3_at_step_k(ltv_card, k):
    """1) P_k = I + H_k C, 2) P_{k+1} A - N_k P_k - L_k C = 0, 3) P_{k+1} B - G_k = 0 with the
    matrices the runtime uses at step k."""
    card, _ = ltv_card
    plant = plant_of(card)
    M, C, A, B = np.array(card.data["matrices"]["M"]), plant.C, plant.A, plant.B
    sched = Runtime(card).schedule
    mats = sched.step_matrices(k, 0.1, 0.1)
    H_k = -mats["Xy"]                       # xhat = z - H_k y
    alpha = card.data["alpha"]
    np.testing.assert_allclose(H_k, (1 - alpha ** k) * M, atol=1e-15)
    P_k = np.eye(2) + H_k @ C
    P_next = np.eye(2) + (1 - alpha ** (k + 1)) * M @ C      # (10)-(11) with alpha^{k+1}
    assert np.linalg.norm(P_next @ A - mats["N"] @ P_k - mats["L"] @ C) < 1e-12
    assert np.linalg.norm(P_next @ B - mats["G"]) < 1e-12


def test_S_k_vanishes_as_alpha_to_the_k_plus_1(ltv_card):
    """Drive the runtime with e_k = 0 and an impulse d_k: e_{k+1} = S_k d_k, ||S_k|| = alpha^{k+1} ||MCE||."""
    card, _ = ltv_card
    plant = plant_of(card)
    alpha, nMCE = card.data["alpha"], card.data["norm_MCE"]
    for k in (0, 2, 5, 20, 60):
        rt = Runtime(card, xhat0=plant.x0)
        x = plant.x0.copy()
        for j in range(k + 1):
            d = np.array([1.0 if j == k else 0.0])
            u = np.array([np.sin(j)])
            rt.set_y(plant.C @ x)
            rt.set_u(u)
            assert np.linalg.norm(x - rt.xhat()) < 1e-12
            rt.step(0.1)
            x = plant.A @ x + plant.B @ u + plant.E @ d
        rt.set_y(plant.C @ x)
        S_k = np.linalg.norm(x - rt.xhat())
        assert S_k <= alpha ** (k + 1) * nMCE * (1 + 1e-9)
        assert S_k == pytest.approx(alpha ** (k + 1) * nMCE, rel=1e-9)
    assert alpha ** 61 * nMCE < 2e-3


def test_eigenvalue_at_k0_replaces_the_slow_zero(ltv_card):
    card, _ = ltv_card
    lam0 = max(abs(complex(*z)) for z in card.data["eigenvalues_N_k0"])
    lam_inf = max(abs(complex(*z)) for z in card.data["eigenvalues_N_inf"])
    assert lam0 < 0.3                        # the paper reports 0.14 with its own T_1
    assert lam_inf == pytest.approx(0.99, abs=1e-9)


def test_long_runs_do_not_drift(ltv_card):
    card, _ = ltv_card
    sched = Runtime(card).schedule
    far = {k: v.copy() for k, v in sched.step_matrices(10 ** 7, 0.1, 0.1).items()}
    assert sched.a(10 ** 7) == 0.0
    for name in ("N", "L", "G", "Xy"):
        np.testing.assert_array_equal(far[name], card.matrices[name][0])
    # alpha^k is computed afresh, not by repeated multiplication
    assert sched.a(1000) == 0.9 ** 1000


@pytest.fixture(scope="module", params=["python", "c"])
def fmus(request, ltv_card, example1_card, example1_path, tmp_path_factory):
    d = tmp_path_factory.mktemp("ltvfmu")
    problem = uiofmu.load_problem(example1_path)
    b = request.param
    return {"ltv": build_observer(ltv_card[0], d / "ltv.fmu", backend=b),
            "classical": build_observer(example1_card[0], d / "c.fmu", backend=b),
            "plant": build_plant(problem.plant, problem.name, d / "plant.fmu"), "dir": d, "backend": b}


def test_fmu_equals_runtime(fmus):
    report = validate(fmus["ltv"], steps=300, seed=5)
    assert report.ok and report.max_rel_diff <= 1e-12


def test_k_survives_save_and_restore(fmus):
    rng = np.random.default_rng(9)
    ys, us = rng.normal(size=(30, 1)), rng.normal(size=(30, 1))

    def drive(fmu, a, b, t):
        out = []
        for j in range(a, b):
            fmu.set("y", ys[j])
            fmu.set("u", us[j])
            out.append(fmu.get("xhat"))
            fmu.step(t, 0.1)
            t += 0.1
        return np.array(out)

    with Fmu(fmus["ltv"], "o") as fmu:
        fmu.initialize(0.0)
        drive(fmu, 0, 7, 0.0)
        blob = fmu.serialize(fmu.get_state())
        first = drive(fmu, 7, 30, 0.7)
    with Fmu(fmus["ltv"], "o2") as fmu:           # a fresh instance, restored from bytes
        fmu.initialize(0.0)
        fmu.set_state(fmu.deserialize(blob))
        second = drive(fmu, 7, 30, 0.7)
    assert first.tobytes() == second.tobytes()
    if fmus["backend"] == "python":
        assert json.loads(blob)["model"]["runtime"]["k"] == 7


def test_ltv_is_much_faster_than_classical_in_cosimulation(fmus, cli):
    d = fmus["dir"]
    res = {}
    for name in ("ltv", "classical"):
        r = cli("cosim", "--plant", fmus["plant"], "--observer", fmus[name], "--steps", "fixed:0.1", "--t-end", "60",
                "--out", d / name)
        assert r.code == 0, r.err
        res[name] = json.loads((d / name / "metrics.json").read_text())
    # measured: classical 424 steps to 1 %, LTV 25 (17x)
    assert res["classical"]["steps_to_1pct"] >= 8 * res["ltv"]["steps_to_1pct"]
    assert res["ltv"]["bound_respected"] is True and res["classical"]["bound_respected"] is True


def test_step_policies(ltv_card):
    card, _ = ltv_card
    rt = Runtime(card)
    with pytest.raises(StepRejected, match="designed for steps of dt = 0.1 s and received h = 0.3 s"):
        rt.step(0.3)
    data = json.loads(card.to_json())
    data["schedule"]["step_policy"] = "count"
    rt = Runtime(uiofmu.runtime.card.card_from_data(data))
    rt.set_y([1.0])
    rt.step(0.3)
    rt.step(0.05)
    assert rt.k == 2


def test_wrong_step_in_fmu_is_refused(fmus):
    with Fmu(fmus["ltv"], "o") as fmu:
        fmu.initialize(0.0)
        with pytest.raises(FmuCallError) as info:
            fmu.step(0.0, 0.2)
        assert any("received h = 0.2 s" in m for m in info.value.messages)


def test_example2_printed_data_has_an_unstable_zero(cli):
    res = cli("check", EXAMPLES / "seed000_example2_printed.toml")
    assert res.code == 2 and "largest modulus 1.00087" in res.err


def test_example2_consistent_data_is_within_rounding_and_gives_the_papers_zeros():
    printed = uiofmu.load_problem(EXAMPLES / "seed000_example2_printed.toml").plant
    consistent = uiofmu.load_problem(EXAMPLES / "seed000_example2_consistent.toml").plant
    assert np.abs(printed.A - consistent.A).max() < 5e-5 and np.abs(printed.C - consistent.C).max() < 5e-5
    zeros = np.sort(uiofmu.structure.invariant_zeros(consistent.A, consistent.E, consistent.C).real)
    np.testing.assert_allclose(zeros, [0.995, 0.999], atol=1e-6)


def test_example2_mu_max_is_close_to_the_papers(tmp_path):
    card = uiofmu.design(uiofmu.load_problem(EXAMPLES / "seed000_example2_consistent.toml"))
    assert 12 < card.data["mu"] < 16          # the paper finds 15; we find 14.08 with the normalisation X >= I
    assert all(c.holds for c in uiofmu.verify(card))


def test_mu_too_large_is_refused(cli, tmp_path):
    text = (EXAMPLES / "seed000_example1_ltv.toml").read_text().replace("mu = 90.0", "mu = 120.0")
    path = tmp_path / "p.toml"
    path.write_text(text)
    res = cli("check", path)
    assert res.code == 2 and "tau_1 = eta (1 + mu) = 0.01 * 121 = 1.21 must be < 1" in res.err


@pytest.mark.parametrize("seed", range(11_000_000, 11_000_006))
def test_near_limit_zeros_and_a_tiny_unknown_input_design(seed):
    """Campaign plants with a sampled zero next to the unit circle, with E as drawn and scaled to 1e-10, at
    mu = "max", 1 and 0.01: each designs (the Theorem 2 LMIs' (33) with S_1 of unit norm, the searches decided
    by largest margins), and a scaled E designs the same mu as the drawn one where both search. Before, 75
    of these 200 designs (40 seeds) were refused: "(33) needs slack 1e-06" or CLARABEL's numerical errors."""
    from uiofmu.families import random_plants as rp
    from uiofmu.runtime.errors import NoObserverError

    doc = rp.random_problem("ltv-auid", seed, plant_class="near-limit-zeros")
    found = {}
    for mu, scale in (("max", 1.0), ("max", 1e-10), (1.0, 1e-10), (0.01, 1.0), (0.01, 1e-10)):
        d = copy.deepcopy(doc)
        d["observer"]["mu"] = mu
        d["plant"]["E"] = (np.array(d["plant"]["E"]) * scale).tolist()
        try:
            card = uiofmu.design(problem_from_data(d))
        except NoObserverError:
            assert mu == "max" or found == {}, (mu, scale)
            return                                         # the drawn plant has no observer at all
        assert all(c.holds for c in uiofmu.verify(card))
        found[(mu, scale)] = card.data["mu"]
    limit = 1.0 / doc["observer"]["eta"] - 1.0
    assert abs(found[("max", 1.0)] - found[("max", 1e-10)]) <= 4 * 1e-4 * limit + 1e-9
