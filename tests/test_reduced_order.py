"""The reduced-order unknown-input observer (``observer.order = "reduced"``, :mod:`uiofmu.reduced_order`): exact
decoupling, contraction and a certificate that ``verify`` re-checks, on plants nobody wrote, and FMUs of both
backends that co-simulate within the certified bound with a state of n - p entries."""

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
from uiofmu.problem import problem_from_data, to_toml  # noqa: E402
from uiofmu.runtime.card import read_card  # noqa: E402
from uiofmu.runtime.errors import ProblemError  # noqa: E402
from uiofmu.runtime.observer import Runtime  # noqa: E402
from tests.conftest import EXAMPLES, built_with_both_backends, run_cli  # noqa: E402

EXAMPLE = EXAMPLES / "reduced_order.toml"
#: The example's period.
H = 0.05


def random_plant(seed: int, n: int, p: int, q: int) -> dict:
    """A seeded discrete plant with rank(CE) = rank(E) = q < p (no invariant zeros, generically)."""
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((n, n))
    A *= 0.95 / np.abs(np.linalg.eigvals(A)).max() * rng.uniform(0.7, 1.3)
    return {"name": f"reduced-random-{seed}",
            "plant": {"time": "discrete", "dt": 0.1, "A": A.tolist(), "B": rng.standard_normal((n, 1)).tolist(),
                      "E": rng.standard_normal((n, q)).tolist(), "C": rng.standard_normal((p, n)).tolist(),
                      "x0": rng.standard_normal(n).tolist()},
            "observer": {"family": "lti-uio", "order": "reduced", "decay": 0.9}}


PLANTS = [(11, 4, 2, 1), (12, 5, 3, 1), (13, 6, 3, 2), (14, 5, 2, 1)]


@pytest.fixture(scope="module", params=PLANTS, ids=lambda s: f"seed{s[0]}-n{s[1]}p{s[2]}q{s[3]}")
def random_card(request):
    data = random_plant(*request.param)
    return data, uiofmu.design(problem_from_data(data))


def test_decoupled_contracting_and_verified(random_card):
    data, card = random_card
    m = card.matrices
    n, p = np.shape(data["plant"]["C"])[1], np.shape(data["plant"]["C"])[0]
    assert card.data["dims"]["nz"] == n - p and card.data["order"] == "reduced"
    A, E, C = (np.asarray(data["plant"][k]) for k in ("A", "E", "C"))
    Zx, N, L, Xz, Xy = (m[k] for k in ("Zx", "N", "L", "Xz", "Xy"))
    scale = max(1.0, np.linalg.norm(Zx, 2)) * max(1.0, np.linalg.norm(A, 2))
    assert np.linalg.norm(Zx @ E) <= 1e-12 * scale * np.linalg.norm(E, 2)          # d is decoupled exactly
    assert np.linalg.norm(Zx @ A - N @ Zx - L @ C) <= 1e-12 * scale * max(1.0, np.linalg.norm(L, 2))
    assert np.linalg.norm(Xz @ Zx + Xy @ C - np.eye(n)) <= 1e-12 * scale * max(1.0, np.linalg.norm(Xy, 2))
    assert np.abs(np.linalg.eigvals(N)).max() < card.data["decay_bound"] <= 0.9
    assert all(c.holds for c in uiofmu.verify(card))


def test_error_follows_the_reduced_dynamics_whatever_d(random_card):
    """The reference runtime on the plant itself: e_k = Xz N^k Zx e_0 with any unknown input, within the bound."""
    data, card = random_card
    A, B, E, C = (np.asarray(data["plant"][k]) for k in ("A", "B", "E", "C"))
    rng = np.random.default_rng(7)
    x = np.asarray(data["plant"]["x0"], dtype=float)
    obs = Runtime(card)
    e0 = x - obs.xhat0
    m, bound = card.matrices, []
    eps = m["Zx"] @ e0
    for k in range(60):
        y = C @ x
        obs.set_y(y)
        obs.set_u(np.array([np.sin(0.3 * k)]))
        e = x - obs.xhat()
        expected = e0 if k == 0 else m["Xz"] @ eps
        assert np.linalg.norm(e - expected) <= 1e-9 * (1 + np.linalg.norm(e0))
        bound.append(card.data["overshoot_bound"] * card.data["decay_bound"] ** k * np.linalg.norm(e0))
        assert np.linalg.norm(e) <= bound[-1] * (1 + 1e-9)
        d = 5.0 * rng.standard_normal(E.shape[1])
        obs.step(0.1)
        eps = m["N"] @ eps                            # z_0 = Zx xhat0: eps_0 = Zx e_0, eps_(k+1) = N eps_k
        x = A @ x + B @ np.array([np.sin(0.3 * k)]) + E @ d


def test_an_edited_card_fails_verify(random_card, tmp_path):
    data, card = random_card
    path = tmp_path / "card.json"
    card.write(path)
    raw = json.loads(path.read_text())
    raw["matrices"]["N"][0][0] += 1e-3
    path.write_text(json.dumps(raw))
    assert run_cli("verify", path).code != 0
    raw = json.loads((card.write(path), path.read_text())[1])
    raw["overshoot_bound"] = 1.0
    path.write_text(json.dumps(raw))
    assert run_cli("verify", path).code != 0
    for edit in ("order", "problem"):                    # a reduced card that says it is a full-order one
        raw = json.loads((card.write(path), path.read_text())[1])
        if edit == "order":
            del raw["order"]
        else:
            raw["problem"]["observer"]["order"] = "full"
        path.write_text(json.dumps(raw))
        assert run_cli("verify", path).code != 0, edit
    card.write(path)
    assert run_cli("verify", path).code == 0


@pytest.mark.parametrize("extra, key", [({"noise": "min"}, "observer.noise"), ({"poles": [0.1, 0.2]}, "observer.poles"),
                                        ({"noise_gain": 3.0}, "observer.noise_gain")])
def test_unsupported_options_are_refused(extra, key):
    data = random_plant(*PLANTS[0])
    data["observer"].update(extra)
    with pytest.raises(ProblemError, match=f'order = "reduced" does not support {key}'):
        problem_from_data(data)


def test_feedthrough_is_refused(tmp_path):
    data = random_plant(*PLANTS[0])
    data["plant"]["D"] = [[0.0], [1.0]]
    path = tmp_path / "p.toml"
    path.write_text(to_toml(data))
    res = run_cli("check", path)
    assert res.code == 2 and "plant.D" in res.err


def test_full_order_is_the_default():
    data = random_plant(*PLANTS[0])
    del data["observer"]["order"]
    card = uiofmu.design(problem_from_data(data))
    assert card.data["dims"]["nz"] == card.data["dims"]["n"] and "Zx" not in card.matrices
    assert "order" not in card.data


@pytest.fixture(scope="module")
def example_fmus(tmp_path_factory):
    return built_with_both_backends(EXAMPLE, tmp_path_factory.mktemp("reduced"))


@pytest.mark.parametrize("backend", ["c", "python"])
def test_fmu_cosimulates_within_the_bound(example_fmus, backend):
    d = example_fmus
    card = read_card(d / "card.json")
    problem = tomllib.loads(EXAMPLE.read_text())
    n, p = len(problem["plant"]["A"]), len(problem["plant"]["C"])
    assert card.data["dims"]["nz"] == n - p == 2
    res = run_cli("cosim", "--plant", d / "plant.fmu", "--observer", d / f"obs_{backend}.fmu", "--t-end", "10",
                  "--out", d / f"run_{backend}", "--no-report")
    assert res.code == 0, res.err
    metrics = json.loads((d / f"run_{backend}" / "metrics.json").read_text())
    assert metrics["bound_respected"] is True
    assert metrics["final_error_norm"] < 1e-3 * metrics["initial_error_norm"]


def check_equal_to_the_runtime(path, card) -> None:
    """The observer FMU at ``path`` gives the reference runtime's outputs (to rounding) on random inputs, from a
    random ``xhat0``; a state saved after a few steps restores the same run."""
    z = equal_to_the_runtime(path, card, H,
                             lambda fmu: np.concatenate([fmu.get("xhat"), fmu.get("r"), fmu.get("dhat")]),
                             lambda ref: np.concatenate([ref.xhat(), ref.residual(), ref.dhat()]))
    assert z.shape == (card.data["dims"]["nz"],)


def check_observer(path, card) -> None:
    """The checks of a C observer FMU that also run under the sanitizers."""
    check_equal_to_the_runtime(path, card)
    random_calls(path, H, 1)


@pytest.mark.parametrize("backend", ["c", "python"])
def test_fmu_runs_a_state_of_n_minus_p(example_fmus, backend):
    """The FMU's z has n - p entries (the card's dims.nz, the design the native kernel runs) and the two backends
    step as the reference runtime does."""
    d = example_fmus
    card = read_card(d / "card.json")
    fmu_path = d / f"obs_{backend}.fmu"
    check_equal_to_the_runtime(fmu_path, card)
    with zipfile.ZipFile(fmu_path) as z:
        assert json.loads(z.read("resources/model.json"))["card"]["dims"]["nz"] == 2
        if backend == "c":                           # the design the native kernel runs
            assert ".nz = 2," in z.read("sources/design_data.c").decode()


@NEEDS_CC
def test_c_observer_under_the_sanitizers(example_fmus, tmp_path):
    """The C observer of a reduced-order card (z_0 = Zx (xhat0 - Xy y_0)), compiled under ASan and UBSan: the same
    checks, and random FMI calls, with no sanitizer report."""
    card = read_card(example_fmus / "card.json")
    check_sanitized(__file__, {"reduced": card}, {}, tmp_path)


if __name__ == "__main__":
    sys.exit(script_main(sys.argv[1:], check_observer, lambda fmu, data: None))


@pytest.mark.parametrize("seed", [31, 34, 36])
def test_the_fixed_modes_are_the_invariant_zeros(seed):
    """With as many outputs as unknown inputs (p = q) no output is left to correct the reduced state: its error
    dynamics is the plant's invariant zeros, the full-order observer's fixed modes, and the fastest decay sits
    just above them."""
    data = random_plant(seed, 4, 2, 2)
    data["observer"]["decay"] = "max"
    card = uiofmu.design(problem_from_data(data))
    fixed = np.sort_complex(np.array([complex(*z) for z in card.data["fixed_modes"]]))
    eig = np.sort_complex(np.linalg.eigvals(card.matrices["N"]))
    assert len(fixed) == card.data["dims"]["nz"] == 2
    np.testing.assert_allclose(eig, fixed, atol=1e-9)
    assert np.abs(fixed).max() < card.data["decay_bound"] < np.abs(fixed).max() + 1e-3
    assert all(c.holds for c in uiofmu.verify(card))


def test_a_card_without_zx_is_refused(example_fmus, tmp_path):
    """A card whose z is shorter than the state needs Zx for its first step: without it, or with a Zx of another
    shape, build refuses it (exit 2) naming the key."""
    raw = json.loads((example_fmus / "card.json").read_text())
    for edit, words in ((lambda m: m.pop("Zx"), "matrices.Zx is missing"),
                        (lambda m: m.update(Zx=m["Zx"][:1]), "matrices.Zx")):
        changed = json.loads(json.dumps(raw))
        edit(changed["matrices"])
        path = tmp_path / "card.json"
        path.write_text(json.dumps(changed))
        res = run_cli("build", path, "-o", tmp_path / "o.fmu", "--backend", "c")
        assert res.code == 2 and words in res.err, res.err
