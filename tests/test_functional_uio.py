"""Functional unknown-input observers (:mod:`uiofmu.functional_uio`) on seeded random plants: the decoupling and
matching identities at rounding level, the decay certified and re-checked, ``zhat - L x`` within the certified
bound whatever the unknown input, the least order found below ``n`` where one exists, and bad functionals refused;
their cards (``observer.functional``: ``order``, ``Lf``, ``zhat``) designed, re-checked by ``verify`` (an edited one
fails), built on both backends and co-simulated within the certified bound; and where no observer of the whole state
exists (``rank(CE) < rank(E)``, or an undetectable decoupled mode the functional does not see), the functional
observer checked, designed, verified and co-simulated, and a plant with neither refused with its numbers."""

from __future__ import annotations

import json
import sys
import tomllib
import zipfile
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

import uiofmu  # noqa: E402
from cfmu import NEEDS_CC, check_sanitized, equal_to_the_runtime, random_calls, script_main  # noqa: E402
from tests.conftest import EXAMPLES, built_with_both_backends, run_cli  # noqa: E402
from uiofmu import functional_uio as fu  # noqa: E402
from uiofmu.cosim.fmi import Fmu  # noqa: E402
from uiofmu.problem import problem_from_data, to_toml  # noqa: E402
from uiofmu.runtime.card import read_card  # noqa: E402
from uiofmu.runtime.errors import ProblemError  # noqa: E402
from uiofmu.runtime.observer import Runtime  # noqa: E402


def _plant(seed, n, p, q, r):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    A /= 1.2 * np.max(np.abs(np.linalg.eigvals(A)))
    return (A, rng.normal(size=(n, 1)), rng.normal(size=(p, n)), rng.normal(size=(n, q)), rng.normal(size=(r, n)))


def _simulate(design, A, B, C, E, L, seed, steps=80):
    """Largest ``||zhat_k - L x_k|| - bound_k`` over a run with a large unknown input (rounding excepted)."""
    rng = np.random.default_rng(seed + 1000)
    x, z = 3.0 * rng.normal(size=A.shape[0]), np.zeros(design.order)
    e0 = float(np.linalg.norm(z - design.T @ x))
    worst, last = -np.inf, None
    for k in range(steps):
        u, d = rng.normal(size=B.shape[1]), 10.0 * np.sin(0.3 * k) + rng.normal(size=E.shape[1])
        y = C @ x
        err = float(np.linalg.norm(design.R @ z + design.Q @ y - L @ x))
        slack = 1e-9 * max(1.0, float(np.linalg.norm(x)))
        worst = max(worst, err - float(design.bound(e0, k)) - slack)
        last = err
        z = design.N @ z + design.J @ y + design.H @ u
        x = A @ x + B @ u + E @ d
    return worst, last


SHAPES = [(5, 3, 1, 1), (5, 2, 1, 1), (4, 2, 1, 1), (4, 2, 1, 2), (5, 3, 2, 2)]


@pytest.mark.parametrize("shape", SHAPES)
def test_random_plants_decouple_decay_and_converge(shape):
    designed = 0
    for seed in range(6):
        A, B, C, E, L = _plant(seed, *shape)
        try:
            design = fu.design(A, B, C, E, L, 0.6)
        except ProblemError as err:
            assert "no functional unknown-input observer" in str(err)
            continue
        designed += 1
        checks = fu.checks(design, A, B, C, E, L)
        assert all(c.holds for c in checks), [c.explain() for c in checks if not c.holds]
        assert np.max(np.abs(design.T @ E)) < 1e-12 * max(1.0, np.linalg.norm(design.T) * np.linalg.norm(E))
        assert np.max(np.abs(np.linalg.eigvals(design.N))) < design.rho
        assert shape[3] <= design.order <= shape[0]
        worst, last = _simulate(design, A, B, C, E, L, seed)
        assert worst <= 0.0 and last < 1e-8
    assert designed >= 3


def test_least_order_below_n():
    A, B, C, E, L = _plant(0, 5, 2, 1, 1)
    design = fu.design(A, B, C, E, L, 0.5)
    assert design.order < 5
    failed = [c for c in design.conditions if not c.holds]
    assert failed and "rank [LPA; LP; Pi C A; C] = 5 > rank [LP; Pi C A; C] = 4" in failed[0].message
    A, B, C, E, L = _plant(0, 5, 3, 1, 1)
    assert fu.design(A, B, C, E, L, 0.5).order == 1


def test_order_n_when_the_functionals_span_the_state():
    A, B, C, E, L = _plant(3, 4, 2, 1, 4)
    design = fu.design(A, B, C, E, L, 0.6)
    assert design.order == 4
    assert all(c.holds for c in fu.checks(design, A, B, C, E, L))
    assert _simulate(design, A, B, C, E, L, 3)[0] <= 0.0


def test_hand_edited_design_fails_the_recheck():
    A, B, C, E, L = _plant(1, 5, 2, 1, 1)
    design = fu.design(A, B, C, E, L, 0.6)
    edited = fu.FunctionalDesign(**{**design.__dict__, "J": design.J + 1e-3})
    assert not all(c.holds for c in fu.checks(edited, A, B, C, E, L))
    slow = fu.FunctionalDesign(**{**design.__dict__, "N": design.N * 2.0})
    names = [c.name for c in fu.checks(slow, A, B, C, E, L) if not c.holds]
    assert "eig_min(rho^2 X - N'XN)" in names


def test_no_observer_is_refused_with_its_numbers():
    for seed in range(20):
        A, B, C, E, L = _plant(seed, 3, 1, 1, 1)
        try:
            fu.design(A, B, C, E, L, 0.5)
        except ProblemError as err:
            assert "order 1:" in str(err) and "fixed mode" in str(err)
            return
    pytest.fail("no refused plant among the seeds")


@pytest.mark.parametrize("raw, needle", [
    ([[1.0, 2.0]], "expected a row of 3 numbers"),
    ([[1.0, float("nan"), 0.0]], "non-finite"),
    ([[0.0, 0.0, 0.0]], "a row of zeros"),
    ([], "expected a list"),
    ("x", "expected a list"),
    ([[1.0, True, 0.0]], "must be a number"),
])
def test_bad_functionals_are_refused(raw, needle):
    with pytest.raises(ProblemError, match=needle):
        fu.parse_functional(raw, 3)


def test_good_functional_is_read():
    assert fu.parse_functional([[1, 0, 0], [0, 1.5, 2]], 3).shape == (2, 3)


FUNCTIONAL = EXAMPLES / "functional_uio.toml"


def test_example_check_reports_order_three(cli):
    res = cli("check", FUNCTIONAL)
    assert res.code == 0, res.err
    for line in ("order 1: rank [LPA; LP; Pi C A; C] = 5 > rank [LP; Pi C A; C] = 4",
                 "order 2: largest fixed mode of the functional error |0.933354| >= decay 0.6",
                 "functional observer of order 3 (searched 1..5)"):
        assert line in res.out
    doc = tomllib.loads(FUNCTIONAL.read_text(encoding="utf-8"))
    p = doc["plant"]
    A, B, C, E = (np.array(p[k], dtype=float) for k in "ABCE")
    L = np.array(doc["observer"]["functional"], dtype=float)
    design = fu.design(A, B, C, E, L, doc["observer"]["decay"])
    assert design.order == 3 and all(c.holds for c in fu.checks(design, A, B, C, E, L))


@pytest.mark.parametrize("edit, needle", [
    ({"observer": {"poles": [0.1, 0.2]}}, "observer.poles"),
    ({"observer": {"noise": "min"}}, "observer.noise"),
    ({"observer": {"functional": [[1.0, 2.0]]}}, "expected a row of 5 numbers"),
    ({"observer": {"functional": [[0, 0, 0, 0, 0]]}}, "a row of zeros"),
    ({"plant": {"F": [[1.0], [0.0]]}}, "plant.F"),
])
def test_unsupported_options_are_refused(cli, tmp_path, edit, needle):
    doc = tomllib.loads(FUNCTIONAL.read_text(encoding="utf-8"))
    for table, values in edit.items():
        doc[table].update(values)
    path = tmp_path / "p.toml"
    path.write_text(to_toml(doc), encoding="utf-8")
    res = cli("check", path)
    assert res.code == 2 and needle in res.err, res.err


# -- cards -------------------------------------------------------------------------------------
def random_problem(seed: int, n: int, p: int, q: int, r: int) -> dict:
    """A seeded discrete plant (spectral radius 1 / 1.2) with ``r`` random functionals to estimate."""
    A, B, C, E, L = _plant(seed, n, p, q, r)
    x0 = np.random.default_rng(seed + 1000).normal(size=n)
    return {"name": f"functional-random-{seed}",
            "plant": {"time": "discrete", "dt": 0.1, "A": A.tolist(), "B": B.tolist(), "E": E.tolist(),
                      "C": C.tolist(), "x0": x0.tolist()},
            "observer": {"family": "lti-uio", "decay": 0.7, "functional": L.tolist()}}


CARD_PLANTS = [(21, 5, 2, 1, 1), (22, 6, 3, 1, 2), (23, 5, 3, 2, 1), (24, 4, 2, 1, 2), (3, 4, 2, 1, 4)]


@pytest.fixture(scope="module", params=CARD_PLANTS, ids=lambda s: "seed{}-n{}p{}q{}r{}".format(*s))
def random_card(request):
    data = random_problem(*request.param)
    return data, uiofmu.design(problem_from_data(data))


def test_cards_decouple_contract_and_verify(random_card):
    """The card's identities to 1e-10 relative, N inside the decay, order = nz, and verify re-checks it all."""
    data, card = random_card
    m, dims = card.matrices, card.data["dims"]
    A, E, C, B = (np.asarray(data["plant"][k]) for k in ("A", "E", "C", "B"))
    Lf = np.asarray(data["observer"]["functional"])
    T, N, J, R, Q = (m[k] for k in ("Zx", "N", "L", "Xz", "Xy"))
    assert dims["nf"] == len(Lf) and card.data["order"] == dims["nz"] <= dims["n"]
    np.testing.assert_array_equal(m["Lf"], Lf)
    size = max(1.0, np.linalg.norm(T, 2)) * max(1.0, np.linalg.norm(A, 2), np.linalg.norm(N, 2))
    assert np.linalg.norm(T @ E) <= 1e-10 * size * np.linalg.norm(E, 2)
    assert np.linalg.norm(T @ A - N @ T - J @ C) <= 1e-10 * size * max(1.0, np.linalg.norm(J, 2))
    assert np.linalg.norm(m["G"] - T @ B) <= 1e-10 * size * np.linalg.norm(B, 2)
    read = np.eye(dims["n"]) if dims["nz"] == dims["n"] else Lf       # order n: the state, zhat = Lf xhat
    assert np.linalg.norm(R @ T + Q @ C - read) <= 1e-10 * max(1.0, np.linalg.norm(R, 2) * size,
                                                              np.linalg.norm(Q, 2) * np.linalg.norm(C, 2))
    assert np.abs(np.linalg.eigvals(N)).max() < card.data["decay_bound"] == 0.7
    assert card.data["certificate"]["verified"] is True
    assert all(c.holds for c in uiofmu.verify(card))
    outputs = [p["name"] for p in card.data["ports"] if p["causality"] == "output"]
    assert outputs == (["xhat", "r", "zhat"] if dims["nz"] == dims["n"] else ["zhat"])


def test_zhat_follows_lf_x_whatever_d(random_card):
    """The reference runtime on the plant itself, with a large unknown input: ``||zhat_k - Lf x_k||`` within the
    card's ``overshoot_bound decay^k ||x_0 - xhat0||`` and down to rounding after 80 steps."""
    data, card = random_card
    A, B, E, C = (np.asarray(data["plant"][k]) for k in ("A", "B", "E", "C"))
    Lf = card.matrices["Lf"]
    rng = np.random.default_rng(5)
    x = np.asarray(data["plant"]["x0"], dtype=float)
    obs = Runtime(card, xhat0=rng.normal(size=len(x)))
    e0 = float(np.linalg.norm(x - obs.xhat0))
    for k in range(80):
        obs.set_y(C @ x)
        u = np.array([np.sin(0.3 * k)])
        obs.set_u(u)
        err = float(np.linalg.norm(obs.zhat() - Lf @ x))
        assert err <= card.data["overshoot_bound"] * card.data["decay_bound"] ** k * e0 * (1 + 1e-9) + 1e-12
        obs.step(0.1)
        x = A @ x + B @ u + E @ (10.0 * rng.normal(size=E.shape[1]))
    assert err <= 1e-9 * (1.0 + e0) * card.data["overshoot_bound"]


def test_an_edited_card_fails_verify(random_card, tmp_path):
    data, card = random_card
    path = tmp_path / "card.json"
    edits = {"N": lambda raw: raw["matrices"]["N"][0].__setitem__(0, raw["matrices"]["N"][0][0] + 1e-3),
             "Lf": lambda raw: raw["matrices"]["Lf"][0].__setitem__(0, raw["matrices"]["Lf"][0][0] * 1.01 + 1e-3),
             "Xy": lambda raw: raw["matrices"]["Xy"][0].__setitem__(0, raw["matrices"]["Xy"][0][0] + 1e-3),
             "overshoot_bound": lambda raw: raw.__setitem__("overshoot_bound", 0.5),
             "order": lambda raw: raw.__setitem__("order", raw["order"] + 1),
             "functional": lambda raw: raw["problem"]["observer"]["functional"][0].__setitem__(0, 9.0)}
    for name, edit in edits.items():
        card.write(path)
        raw = json.loads(path.read_text())
        edit(raw)
        path.write_text(json.dumps(raw))
        res = run_cli("verify", path)
        assert res.code != 0, name
    card.write(path)
    assert run_cli("verify", path).code == 0


FUNCTIONAL_H = 0.1


@pytest.fixture(scope="module")
def example_fmus(tmp_path_factory):
    return built_with_both_backends(FUNCTIONAL, tmp_path_factory.mktemp("functional"))


def test_example_card_records_order_three(example_fmus):
    card = read_card(example_fmus / "card.json")
    assert card.data["order"] == card.data["dims"]["nz"] == 3 and card.data["dims"]["nf"] == 1
    assert all(c.holds for c in uiofmu.verify(card))


def _cosimulates_within_the_bound(d, backend: str) -> None:
    """``uiofmu cosim`` of ``d/plant.fmu`` and ``d/obs_BACKEND.fmu`` over 6 s: zhat within the card's bound on Lf x
    at every step, from an error above 0.1 down by 1e-6."""
    res = run_cli("cosim", "--plant", d / "plant.fmu", "--observer", d / f"obs_{backend}.fmu", "--t-end", "6",
                  "--steps", "uniform:0.1:0.1", "--out", d / f"run_{backend}", "--no-report")
    assert res.code == 0, res.err
    metrics = json.loads((d / f"run_{backend}" / "metrics.json").read_text())
    assert metrics["bound_respected"] is True
    assert metrics["initial_error_norm"] > 0.1
    assert metrics["final_error_norm"] < 1e-6 * metrics["initial_error_norm"]


@pytest.mark.parametrize("backend", ["c", "python"])
def test_fmu_cosimulates_within_the_bound(example_fmus, backend):
    """fmpy runs the plant and the observer FMU: ``zhat`` against ``Lf x`` of the plant's state, within the card's
    bound at every step, down by 1e-6 over the run."""
    d = example_fmus
    _cosimulates_within_the_bound(d, backend)
    header = (d / f"run_{backend}" / "results.csv").read_text().splitlines()[0].split(",")
    assert "zhat[1]" in header and "zhat_true[1]" in header and not any(h.startswith("xhat[") for h in header)


def test_noise_gain_of_zhat_is_respected(example_fmus):
    """Sensor noise on y: the measured l2 gain from the noise to the error of zhat stays under the card's certified
    gain_y (the bounded real lemma at the stored matrices, which verify re-checks)."""
    d = example_fmus
    card = read_card(d / "card.json")
    assert card.data["noise"]["gain_y"] > 0 and card.data["noise"].get("gain_dhat_y") is None
    res = run_cli("cosim", "--plant", d / "plant.fmu", "--observer", d / "obs_c.fmu", "--t-end", "10",
                  "--noise", "y=0.01,4", "--out", d / "run_noise", "--no-report")
    assert res.code == 0, res.err
    metrics = json.loads((d / "run_noise" / "metrics.json").read_text())
    assert metrics["noise_gain_respected"] is True and metrics["bound_respected"] is True
    assert 0 < metrics["noise_gain_measured"] <= card.data["noise"]["gain_y"]
    header = (d / "run_noise" / "results.csv").read_text().splitlines()[0].split(",")
    assert "zhat_noisy[1]" in header


@pytest.mark.parametrize("noise", [None, "y=0.01,4"])
def test_report_draws_a_functional_run_again_from_its_files(example_fmus, tmp_path, noise):
    """``uiofmu report DIR`` of a functional run (``zhat_true[i]``, ``zhat[i]``, with noise ``zhat_noisy[i]``) draws
    the very figure ``cosim`` drew."""
    d, out = example_fmus, tmp_path / "run"
    res = run_cli("cosim", "--plant", d / "plant.fmu", "--observer", d / "obs_c.fmu", "--t-end", "3", "--out", out,
                  *(["--noise", noise] if noise else []))
    assert res.code == 0, res.err
    drawn = (out / "report.png").read_bytes()
    (out / "report.png").unlink()
    res = run_cli("report", out)
    assert res.code == 0, res.err
    assert (out / "report.png").read_bytes() == drawn


@pytest.mark.parametrize("backend", ["c", "python"])
def test_a_random_plant_cosimulates_within_its_bound(tmp_path, backend):
    """A seeded plant nobody wrote (6 states, 3 outputs, 2 functionals, process noise through W): designed, built,
    co-simulated with fmpy within the certified bound, and the measured gain from the process noise to the error
    of zhat under the card's gain_w."""
    data = random_problem(*CARD_PLANTS[1])
    data["plant"]["W"] = (0.2 * np.random.default_rng(9).normal(size=(6, 1))).tolist()
    path = tmp_path / "p.toml"
    path.write_text(to_toml(data), encoding="utf-8")
    assert run_cli("design", path, "-o", tmp_path / "card.json").code == 0
    card = read_card(tmp_path / "card.json")
    assert card.data["dims"]["nf"] == 2 and card.data["noise"]["gain_w"] > 0
    assert run_cli("plant", path, "-o", tmp_path / "plant.fmu", "--backend", backend).code == 0
    res = run_cli("build", tmp_path / "card.json", "-o", tmp_path / "obs.fmu", "--backend", backend)
    assert res.code == 0, res.err
    for noise, out in ((None, "run"), ("w=0.1,2", "run_w")):
        res = run_cli("cosim", "--plant", tmp_path / "plant.fmu", "--observer", tmp_path / "obs.fmu", "--t-end", "8",
                      "--out", tmp_path / out, "--no-report", *(("--noise", noise) if noise else ()))
        assert res.code == 0, res.err
        metrics = json.loads((tmp_path / out / "metrics.json").read_text())
        assert metrics["bound_respected"] is True
        if noise is None:
            assert metrics["final_error_norm"] < 1e-6 * metrics["initial_error_norm"]
        else:
            assert metrics["noise_gain_w_respected"] is True


@pytest.mark.parametrize("backend", ["c", "python"])
def test_order_n_outputs_the_state_and_lf_xhat(tmp_path, backend):
    """Four functionals of a 4-state plant: the observer has order n, so its FMU also outputs xhat and r, with
    zhat = Lf xhat, equal to the reference runtime, and xhat converges to x in co-simulation."""
    data = random_problem(3, 4, 2, 1, 4)
    path = tmp_path / "p.toml"
    path.write_text(to_toml(data), encoding="utf-8")
    assert run_cli("design", path, "-o", tmp_path / "card.json").code == 0
    card = read_card(tmp_path / "card.json")
    assert card.data["order"] == card.data["dims"]["nz"] == card.data["dims"]["n"] == 4
    assert run_cli("plant", path, "-o", tmp_path / "plant.fmu", "--backend", backend).code == 0
    assert run_cli("build", tmp_path / "card.json", "-o", tmp_path / "obs.fmu", "--backend", backend).code == 0
    rng = np.random.default_rng(8)
    ref = Runtime(card, xhat0=rng.normal(size=4))
    with Fmu(tmp_path / "obs.fmu", "observer") as fmu:
        assert set(fmu.ports("output")) == {"xhat", "r", "zhat"}
        fmu.initialize(0.0, {"xhat0": ref.xhat0})
        for k in range(15):
            y, u = rng.normal(size=2), rng.normal(size=1)
            for name, value in (("y", y), ("u", u)):
                fmu.set(name, value)
            ref.set_y(y)
            ref.set_u(u)
            got = np.concatenate([fmu.get("xhat"), fmu.get("r"), fmu.get("zhat")])
            np.testing.assert_allclose(got, np.concatenate([ref.xhat(), ref.residual(), ref.zhat()]),
                                       rtol=1e-11, atol=1e-11)
            np.testing.assert_allclose(fmu.get("zhat"), card.matrices["Lf"] @ np.asarray(fmu.get("xhat")),
                                       rtol=1e-11, atol=1e-11)
            fmu.step(k * 0.1, 0.1)
            ref.step(0.1)
    res = run_cli("cosim", "--plant", tmp_path / "plant.fmu", "--observer", tmp_path / "obs.fmu", "--t-end", "8",
                  "--out", tmp_path / "run", "--no-report")
    assert res.code == 0, res.err
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["bound_respected"] is True
    assert metrics["final_error_norm"] < 1e-6 * metrics["initial_error_norm"]
    import csv
    rows = list(csv.DictReader((tmp_path / "run" / "results.csv").open()))
    assert rows and "zhat[4]" in rows[0]


def test_dependent_functionals_are_refused():
    with pytest.raises(ProblemError, match=r"the 2 rows are dependent \(rank 1\)"):
        fu.parse_functional([[1.0, 2.0, 0.0], [2.0, 4.0, 0.0]], 3)


def check_equal_to_the_runtime(path, card) -> None:
    """The observer FMU at ``path`` gives the reference runtime's ``zhat`` (to rounding) on random inputs, from a
    random ``xhat0``; a state saved after a few steps restores the same run."""
    with Fmu(path, "observer") as fmu:
        assert set(fmu.ports("output")) == {"zhat"}
    equal_to_the_runtime(path, card, FUNCTIONAL_H, lambda fmu: np.asarray(fmu.get("zhat")), lambda ref: ref.xhat())


def check_observer(path, card) -> None:
    """The checks of a C observer FMU that also run under the sanitizers."""
    check_equal_to_the_runtime(path, card)
    random_calls(path, FUNCTIONAL_H, 1)


@pytest.mark.parametrize("backend", ["c", "python"])
def test_both_backends_give_the_runtime_zhat(example_fmus, backend):
    d = example_fmus
    card = read_card(d / "card.json")
    check_equal_to_the_runtime(d / f"obs_{backend}.fmu", card)
    res = run_cli("validate", d / f"obs_{backend}.fmu")          # fmpy's validate_fmu, then random steps
    assert res.code == 0 and "validate_fmu         no problem" in res.out, res.out + res.err
    with zipfile.ZipFile(d / f"obs_{backend}.fmu") as z:
        described = z.read("modelDescription.xml").decode()
        assert 'name="zhat[1]"' in described and 'name="xhat[' not in described and 'name="r[' not in described
        if backend == "c":
            assert ".nf = 1," in z.read("sources/design_data.c").decode()


@NEEDS_CC
def test_c_observer_under_the_sanitizers(example_fmus, tmp_path):
    """The C observer of a functional card (zhat_0 = Lf xhat0, z_0 = Zx xhat0), compiled under ASan and UBSan: the
    same checks, and random FMI calls, with no sanitizer report."""
    card = read_card(example_fmus / "card.json")
    check_sanitized(__file__, {"functional": card}, {}, tmp_path)


@pytest.mark.parametrize("edit, words", [
    (lambda raw: raw["matrices"].pop("Lf"), "matrices.Lf: required by a functional observer"),
    (lambda raw: raw["dims"].pop("nf"), "matrices.Lf: the functionals of a functional observer need dims.nf"),
    (lambda raw: raw["matrices"].pop("Zx"), "matrices.Zx is missing"),
    (lambda raw: raw["dims"].__setitem__("nf", 2), "design card matrices.Xz"),
])
def test_a_malformed_functional_card_is_refused(example_fmus, tmp_path, edit, words):
    raw = json.loads((example_fmus / "card.json").read_text())
    edit(raw)
    path = tmp_path / "card.json"
    path.write_text(json.dumps(raw))
    res = run_cli("build", path, "-o", tmp_path / "obs.fmu")
    assert res.code == 2 and words in res.err, res.err


@pytest.mark.parametrize("edit, words", [
    ({"decay": "max"}, "observer.functional designs the functional observer at a given decay"),
    ({"order": "reduced"}, "observer.functional searches the order of the functional observer itself"),
    ({"plant_D": [[0.0], [1.0]]}, "this plant's known input feeds through (plant.D)"),
    ({"random": (30, 4, 1, 1, 1), "decay": 0.01}, "order 3: largest fixed mode of the functional error |0.538173| >= "
                                                   "decay 0.01"),
])
def test_design_refusals_name_the_condition(tmp_path, edit, words):
    """Exit 2 naming the key or the failed condition with its numbers (a plant whose functional error keeps an
    invariant zero 0.538 at every order: no order at decay 0.01)."""
    edit = dict(edit)
    doc = (random_problem(*edit.pop("random")) if "random" in edit
           else tomllib.loads(FUNCTIONAL.read_text(encoding="utf-8")))
    if "plant_D" in edit:
        doc["plant"]["D"] = edit.pop("plant_D")
    doc["observer"].update(edit)
    path = tmp_path / "p.toml"
    path.write_text(to_toml(doc), encoding="utf-8")
    res = run_cli("design", path, "-o", tmp_path / "card.json")
    assert res.code == 2 and words in res.err, res.err


# -- where no observer of the whole state exists ---------------------------------------------------------------
def _rank_deficient(seed, n=4, p=2, q=2):
    """``rank(CE) = 1 < rank(E) = 2`` (one output sees ``E d``, the other reads a direction ``E`` does not reach),
    and ``L E`` in the span of ``CE``: no full-state UIO, the functional decoupling holds."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    A /= 1.2 * np.max(np.abs(np.linalg.eigvals(A)))
    B, E = rng.normal(size=(n, 1)), rng.normal(size=(n, q))
    unreached = np.linalg.svd(E.T)[2][q:]                  # rows w with w E = 0
    c1 = rng.normal(size=n)
    C = np.vstack([c1] + [rng.normal(size=n - q) @ unreached for _ in range(p - 1)])
    L = (rng.normal() * c1 + rng.normal(size=n - q) @ unreached)[None, :]
    return A, B, C, E, L


def _hidden_mode(seed, m=3, p=2, q=1, mode=1.1):
    """A mode (at 1.1) that no output sees, driven by the other states and driving none: the decoupled pair is not
    detectable, while the functional of the other states never sees that mode."""
    rng = np.random.default_rng(seed)
    A1 = rng.normal(size=(m, m))
    A1 /= 1.2 * np.max(np.abs(np.linalg.eigvals(A1)))
    A = np.block([[A1, np.zeros((m, 1))], [rng.normal(size=(1, m)), np.array([[mode]])]])
    B, E = rng.normal(size=(m + 1, 1)), np.vstack([rng.normal(size=(m, q)), np.zeros((1, q))])
    C = np.hstack([rng.normal(size=(p, m)), np.zeros((p, 1))])
    L = np.hstack([rng.normal(size=(1, m)), np.zeros((1, 1))])
    return A, B, C, E, L


#: Seeded plants with no full-state UIO and a functional one at decay 0.7: rank(CE) < rank(E), or an undetectable
#: decoupled mode the functional does not see.
NO_FULL_UIO = [(_rank_deficient, 3), (_rank_deficient, 5), (_rank_deficient, 8), (_hidden_mode, 0), (_hidden_mode, 4)]


def _problem(A, B, C, E, L, name="functional-no-full-uio", decay=0.7) -> dict:
    return {"name": name, "plant": {"time": "discrete", "dt": 0.1, "A": A.tolist(), "B": B.tolist(), "E": E.tolist(),
                                    "C": C.tolist(), "x0": np.linspace(1.0, -1.0, A.shape[0]).tolist()},
            "observer": {"family": "lti-uio", "decay": decay, "functional": L.tolist()}}


@pytest.mark.parametrize("make, seed", NO_FULL_UIO, ids=lambda v: getattr(v, "__name__", str(v)))
def test_functional_observer_where_no_full_uio_exists(make, seed):
    """The full-state conditions fail (rank(CE) < rank(E), or a fixed mode at 1.1), yet the analysis finds the
    functional observer, its design decouples (T E = 0, T A - N T = J C, R T + Q C = L) and decays inside 0.7,
    and ``zhat - L x`` stays within the certified bound under a large unknown input."""
    from uiofmu.decoupling import fixed_modes_condition, rank_condition

    A, B, C, E, L = make(seed)
    full = rank_condition(C, E)
    assert not full.holds or not fixed_modes_condition(A, E, C)[0].holds
    existence = uiofmu.check(problem_from_data(_problem(A, B, C, E, L)))
    assert existence.exists
    assert not any(c.required for c in existence.conditions if c.name != "functional observer order")
    design = fu.design(A, B, C, E, L, 0.7)
    assert design.order == existence.value("functional observer order", "order") < A.shape[0]
    assert all(c.holds for c in fu.checks(design, A, B, C, E, L))
    size = max(1.0, np.linalg.norm(design.T, 2)) * max(1.0, np.linalg.norm(A, 2), np.linalg.norm(design.N, 2))
    assert np.linalg.norm(design.T @ E) <= 1e-10 * size * np.linalg.norm(E, 2)
    assert np.linalg.norm(design.T @ A - design.N @ design.T - design.J @ C) <= 1e-10 * size * max(
        1.0, np.linalg.norm(design.J, 2))
    assert np.linalg.norm(design.R @ design.T + design.Q @ C - L) <= 1e-10 * size * max(1.0, np.linalg.norm(design.Q))
    assert np.abs(np.linalg.eigvals(design.N)).max() < 0.7
    worst, last = _simulate(design, A, B, C, E, L, seed)
    assert worst <= 0.0 and last < 1e-6


@pytest.mark.parametrize("make, seed", NO_FULL_UIO[::3], ids=lambda v: getattr(v, "__name__", str(v)))
def test_check_design_verify_without_full_uio(tmp_path, make, seed):
    """``check`` exits 0 with the functional order, the failed full-state condition told as not required; the
    card designed, marked verified and re-checked by ``verify``."""
    A, B, C, E, L = make(seed)
    path = tmp_path / "p.toml"
    path.write_text(to_toml(_problem(A, B, C, E, L)), encoding="utf-8")
    res = run_cli("check", path)
    assert res.code == 0 and "functional observer of order 1 (searched 1..4)" in res.out, res.err
    assert f"({fu.NOT_REQUIRED})" in res.out
    assert run_cli("design", path, "-o", tmp_path / "card.json").code == 0
    card = read_card(tmp_path / "card.json")
    assert card.data["order"] == card.data["dims"]["nz"] == 1 and card.data["certificate"]["verified"] is True
    assert card.data["spectral_radius_N"] < card.data["decay_bound"] == 0.7
    assert all(c.holds for c in uiofmu.verify(card))
    assert run_cli("verify", tmp_path / "card.json").code == 0


def test_functional_observer_faster_than_the_full_state_fixed_mode(tmp_path):
    """The hidden mode at 0.9: the full-state observer exists but cannot decay faster than 0.9; the functional
    observer, which never sees that mode, is checked, designed and verified at decay 0.7."""
    A, B, C, E, L = _hidden_mode(0, mode=0.9)
    path = tmp_path / "p.toml"
    path.write_text(to_toml(_problem(A, B, C, E, L)), encoding="utf-8")
    res = run_cli("check", path)
    assert res.code == 0 and "functional observer of order 1 (searched 1..4)" in res.out, res.err
    assert "requested decay 0.7 <= largest fixed mode modulus 0.9: " in res.out and fu.NOT_REQUIRED in res.out
    assert run_cli("design", path, "-o", tmp_path / "card.json").code == 0
    card = read_card(tmp_path / "card.json")
    assert card.data["spectral_radius_N"] < card.data["decay_bound"] == 0.7
    assert all(c.holds for c in uiofmu.verify(card))


def test_neither_observer_is_refused_with_its_numbers(tmp_path):
    """rank(CE) < rank(E) and the functional's own conditions failing: ``check`` and ``design`` exit 2,
    both naming the failed functional conditions with their numbers (order 1's fixed mode, the decoupling of the
    completions)."""
    A, B, C, E, L = _rank_deficient(0)
    path = tmp_path / "p.toml"
    path.write_text(to_toml(_problem(A, B, C, E, L)), encoding="utf-8")
    res = run_cli("check", path)
    assert res.code == 2, res.out + res.err
    assert "no functional observer of order 1..4 at decay 0.7" in res.out
    assert "order 1: largest fixed mode of the functional error |8.81538| >= decay 0.7" in res.out
    assert "order 2: rank [CE; LE] = 2 > rank CE = 1" in res.out
    res = run_cli("design", path, "-o", tmp_path / "card.json")
    assert res.code == 2 and "order 1: largest fixed mode of the functional error |8.81538| >= decay 0.7" in res.err
    assert not (tmp_path / "card.json").exists()


NO_FULL = EXAMPLES / "functional_without_full_uio.toml"


@pytest.fixture(scope="module")
def no_full_fmus(tmp_path_factory):
    return built_with_both_backends(NO_FULL, tmp_path_factory.mktemp("no_full_uio"))


@pytest.mark.parametrize("backend", ["c", "python"])
def test_no_full_uio_example_cosimulates_within_the_bound(no_full_fmus, backend):
    """The example with rank(CE) = 1 < rank(E) = 2: its order-1 card has no invariant zeros (no decoupled pair),
    and both FMUs, run by fmpy against the plant FMU, keep ``zhat`` within the card's bound on ``Lf x``, down by
    1e-6 over the run, with both unknown inputs acting."""
    d = no_full_fmus
    card = read_card(d / "card.json")
    assert card.data["order"] == 1 and "invariant_zeros" not in card.data
    _cosimulates_within_the_bound(d, backend)


if __name__ == "__main__":
    sys.exit(script_main(sys.argv[1:], check_observer, lambda fmu, data: None))
