"""Least-noise designs of the sampled-data and switched families: ``observer.noise = "min"`` never raises the
certified ``gain_y`` at the decay asked for and lowers it where the default design leans on a weak output;
``observer.noise_gain`` gives the fastest decay within the gain; ``uiofmu tradeoff`` draws both families; ltv-auid
refuses the keys with its reason. Every card is re-checked from its JSON (the gain by the bounded real lemma at
the stored matrices). Both families certify ``gain_dhat_y`` where the card has dhat: the runtime's dhat under noise
on random interval and mode sequences stays within it, and a lowered gain fails ``uiofmu verify``."""

from __future__ import annotations

import copy
import csv
import json
import math

import numpy as np
import pytest

import uiofmu
from uiofmu.noise import NOISE_GAIN_RESOLUTION, NOISE_GAIN_SLOWEST
from uiofmu.problem import problem_from_data
from uiofmu.runtime.card import card_from_data
from uiofmu.runtime.observer import Runtime
from uiofmu.synthesis import recheck

#: A weak first output (entries near 1e-2) beside a strong one, one unknown input: the default designs read the
#: weak output with large gains.
WEAK_C = [[0.01, 0.0, 0.02, 0.01], [1.0, 0.5, -0.5, 1.0]]

#: A continuous plant for the sampled-data family (intervals 0.1 s and 0.2 s).
SAMPLED = {"time": "continuous", "C": WEAK_C, "E": [[1.0], [0.0], [0.2], [0.5]], "x0": [0.0] * 4,
           "A": [[-1.0, 0.5, 0.2, 0.0], [0.0, -0.5, 1.0, 0.3], [0.2, 0.0, -2.0, 0.5], [0.1, 0.3, 0.0, -1.5]]}

#: A two-mode switched plant with a weak output.
SWITCHED = {"time": "discrete", "dt": 0.1, "E": [[1.457], [-0.053], [-0.054], [0.512]], "x0": [0.0] * 4,
            "C": [[-0.021, -0.011, 0.021, 0.014], [-1.159, 0.833, -0.59, -1.056]],
            "modes": [{"A": [[-0.401, -0.5, 0.236, -0.336], [-0.202, -0.139, 0.213, -0.162],
                             [0.111, -0.071, -0.338, -0.128], [-0.38, 0.003, -0.45, -0.437]]},
                      {"A": [[-0.301, -0.5, 0.236, -0.336], [-0.202, -0.239, 0.213, -0.162],
                             [0.111, -0.071, -0.238, -0.128], [-0.38, 0.103, -0.45, -0.437]]}],
            "switching": {"rule": "random", "seed": 1}}


def _sampled(**observer):
    return uiofmu.design(problem_from_data({"name": "sampled", "plant": copy.deepcopy(SAMPLED), "observer": {
        "family": "sampled-data", "intervals": [0.1, 0.2], **observer}}))


def _switched(**observer):
    return uiofmu.design(problem_from_data({"name": "switched", "plant": copy.deepcopy(SWITCHED), "observer": {
        "family": "switched", "method": "lmi", **observer}}))


def _at(family, decay: float, **observer):
    """A card of ``family`` at ``decay`` (the sampled-data family asks for it as ``alpha = 1 - decay^2``)."""
    return _sampled(alpha=1.0 - decay * decay, **observer) if family is _sampled else family(decay=decay, **observer)


def _rechecked(card):
    """The card read back from its JSON and re-checked (raises where a check fails)."""
    back = card_from_data(json.loads(card.to_json()))
    recheck(back)
    return back


@pytest.mark.parametrize("family, decays", [(_sampled, (0.95, 0.9, 0.8366600265340756)),
                                            (_switched, (0.9, 0.6, 0.4))])
def test_noise_min_never_raises_the_gain_at_the_same_decay(family, decays):
    for decay in decays:
        default, least = _at(family, decay), _at(family, decay, noise="min")
        assert least.data["decay_bound"] == default.data["decay_bound"]
        assert least.data["noise"]["gain_y"] <= default.data["noise"]["gain_y"], decay
        assert least.data["noise_design"]["default_gain_y"] == default.data["noise"]["gain_y"]
        _rechecked(least)


@pytest.mark.parametrize("family, decay, factor", [(_sampled, 0.8366600265340756, 20), (_switched, 0.6, 20)])
def test_noise_min_lowers_a_gain_that_leans_on_a_weak_output(family, decay, factor):
    """Measured: sampled-data 2310 -> 84.5 at alpha = 0.3 (decay 0.837); switched 32.7 -> 0.827 at decay 0.6."""
    default, least = _at(family, decay), _at(family, decay, noise="min")
    assert least.data["noise"]["gain_y"] * factor < default.data["noise"]["gain_y"]
    assert least.data["noise_design"]["kept"] == "least noise"
    assert least.data["design_method"] == "lmi (least noise gain)" and least.data["certificate"]["verified"]
    assert _rechecked(least).data["noise"]["gain_y"] == least.data["noise"]["gain_y"]


@pytest.mark.parametrize("family, goal", [(_sampled, 5.0), (_switched, 1.0)])
def test_noise_gain_asks_for_the_fastest_decay_within_it(family, goal):
    """The card's certified gain is at most G, and the decay one step of the search faster has, by an
    independent least-noise design there, a larger certified gain (or none)."""
    fastest = family().data["decay_bound"]
    card = family(noise_gain=goal)
    rho, record = card.data["decay_bound"], card.data["noise_design"]
    assert card.data["noise"]["gain_y"] <= goal and record["noise_gain"] == goal
    assert fastest < rho < 1.0 and card.data["design_method"] == "lmi (least noise gain)"
    _rechecked(card)
    faster = max(d for d, _ in record["search"]["tried"] if d < rho)
    assert rho - faster <= (1.0 - fastest) * NOISE_GAIN_RESOLUTION * 1.0000001
    try:
        beyond = _at(family, faster, noise="min").data["noise"]["gain_y"]
    except uiofmu.InfeasibleError:
        beyond = math.inf
    assert beyond > goal, (faster, beyond)


def test_a_noise_gain_out_of_reach_or_with_a_decay_is_refused_with_its_numbers():
    with pytest.raises(uiofmu.InfeasibleError, match=r"noise_gain = 0.5: the slowest decay tried, 0\.99.*has "
                                                     r"certified gain_y ([0-9.]+) .*ask for noise_gain >= \1"):
        _sampled(noise_gain=0.5)
    assert 1.0 - NOISE_GAIN_SLOWEST > 0
    with pytest.raises(uiofmu.ProblemError, match=r"noise_gain = 2 asks for the fastest decay.*alpha"):
        _sampled(noise_gain=2.0, alpha=0.3)
    with pytest.raises(uiofmu.ProblemError, match=r"noise_gain = 2 asks for the fastest decay.*decay"):
        _switched(noise_gain=2.0, decay=0.5)
    with pytest.raises(uiofmu.ProblemError, match='observer.noise: the least noise gain is designed with the LMI'):
        _switched(noise="min", method="deadbeat")


def test_ltv_auid_refuses_a_least_noise_design_with_its_reason(example1_path):
    import tomllib

    data = tomllib.loads((example1_path.parent / "seed000_example1_ltv.toml").read_text())
    for key, value in (("noise", "min"), ("noise_gain", 2.0)):
        bad = copy.deepcopy(data)
        bad["observer"][key] = value
        with pytest.raises(uiofmu.ProblemError, match=f"observer.{key} = .*no least-noise form: its contraction is "
                                                      "set by eta and mu"):
            problem_from_data(bad)


@pytest.mark.parametrize("name, plant, observer", [
    ("sampled", SAMPLED, '[observer]\nfamily = "sampled-data"\nintervals = [0.1, 0.2]\nalpha = 0.3\n'),
    ("switched", SWITCHED, '[observer]\nfamily = "switched"\nmethod = "lmi"\ndecay = 0.6\n')])
def test_the_tradeoff_draws_certified_gains_for_both_families(tmp_path, cli, name, plant, observer):
    """``uiofmu tradeoff``: a png and a CSV whose every point is a certified design, the least-noise gain never
    above the default's."""
    problem = tmp_path / f"{name}.toml"
    problem.write_text(_toml(name, plant) + observer)
    res = cli("tradeoff", problem, "-o", tmp_path / "t.png", "--points", "3")
    assert res.code == 0, res.err
    assert (tmp_path / "t.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with open(tmp_path / "t.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 3
    for row in rows:
        default, least = float(row["gain_y_default"]), float(row["gain_y_least_noise"])
        assert 0 < least <= default, row


def _toml(name: str, plant: dict) -> str:
    """``plant`` as the TOML of a problem file (its ``[plant]`` and, for a switched plant, its modes)."""
    value = lambda v: ("[" + ", ".join(value(x) for x in v) + "]" if isinstance(v, list)      # noqa: E731
                       else f'"{v}"' if isinstance(v, str) else repr(v))
    text = f'name = "{name}"\n[plant]\n' + "".join(f"{k} = {value(v)}\n" for k, v in plant.items()
                                                   if k not in ("modes", "switching"))
    for mode in plant.get("modes", []):
        text += "[[plant.modes]]\n" + "".join(f"{k} = {value(v)}\n" for k, v in mode.items())
    if "switching" in plant:
        text += "[plant.switching]\n" + "".join(f"{k} = {value(v)}\n" for k, v in plant["switching"].items())
    return text


def test_the_sampled_data_example_designs_its_least_noise_gain(cli, tmp_path):
    """``examples/noise_sampled_data.toml``: noise = "min" at alpha = 0.3 keeps the least-noise design, its gain
    below a twentieth of the default's, and ``uiofmu verify`` re-checks the card against its problem."""
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "examples" / "noise_sampled_data.toml"
    card = uiofmu.design(uiofmu.load_problem(path))
    record = card.data["noise_design"]
    assert record["kept"] == "least noise" and card.data["noise"]["gain_y"] * 20 < record["default_gain_y"]
    (tmp_path / "card.json").write_text(card.to_json())
    res = cli("verify", tmp_path / "card.json")
    assert res.code == 0, res.err


@pytest.mark.parametrize("family", [_sampled, _switched])
def test_noise_min_at_the_fastest_decay_moves_it_and_certifies_there(family):
    """With the fastest decay asked for, the card's decay is 10 % of the way from it to 1 (the default point
    certifies there too, where no least-noise point is below it), its gain no more than the fastest design's."""
    fastest, least = family(), family(noise="min")
    rho = fastest.data["decay_bound"]
    assert least.data["decay_bound"] == pytest.approx(rho + 0.1 * (1 - rho), rel=1e-9)
    assert least.data["noise"]["gain_y"] <= fastest.data["noise"]["gain_y"]
    _rechecked(least)


# -- gain_dhat_y: the error of dhat from output noise, for every interval or switching sequence ---------------------
def _dhat_cards():
    """Cards with dhat: the module's sampled-data and switched plants (default designs) and seed 002's dead-beat
    switched observer."""
    from pathlib import Path

    setup2 = Path(__file__).resolve().parents[1] / "examples" / "seed002_setup2.toml"
    return {"sampled": _sampled(), "switched": _switched(), "deadbeat": uiofmu.design(uiofmu.load_problem(setup2))}


@pytest.fixture(scope="module")
def dhat_cards():
    return _dhat_cards()


def _frozen_peak(card) -> float:
    """The largest H-infinity norm of the dhat error system with the interval or mode held constant (a lower
    bound of the gain under every sequence)."""
    from uiofmu.noise import hinf_norm, pair_dhat_error_system

    A, B, C, D = pair_dhat_error_system(card.data["matrices"])
    return max(hinf_norm(A[i, i], B[i, i], C[i, i], D[i, i]) for i in range(len(A)))


def _dhat_runs(card, v: np.ndarray, sequence, seed: int) -> tuple:
    """``dhat`` of the runtime fed ``y + v`` and of its noise-free twin on one run of the card's plant (the plant
    sampled at the interval, or in the mode, of each step of ``sequence``; random known and unknown inputs)."""
    m = {k: np.asarray(val, dtype=float) for k, val in card.data["matrices"].items() if val is not None}
    interval = card.data["schedule"]["kind"] == "interval"
    A, B, E = (m[f"{k}_sampled"] if interval else m[f"{k}_modes"] for k in "ABE")
    w = np.zeros(A.shape[:2]) if interval else m["w_modes"]
    C, rng = m["C"], np.random.default_rng(seed)
    x = rng.normal(size=A.shape[-1])
    noisy, twin = Runtime(card), Runtime(card)
    out, ref = [], []
    for k, i in enumerate(sequence):
        u, d = rng.normal(size=B.shape[-1]), rng.normal(size=E.shape[-1])
        for rt, y in ((noisy, C @ x + v[k]), (twin, C @ x)):
            rt.set_y(y), rt.set_u(u)
            if not interval:
                rt.set_mode(int(i) + 1)
        out.append(noisy.dhat().copy()), ref.append(twin.dhat().copy())
        h = card.data["schedule"]["intervals"][int(i)] if interval else card.dt
        noisy.step(h), twin.step(h)
        x = A[i] @ x + B[i] @ u + E[i] @ d + w[i]
    return np.array(out), np.array(ref)


@pytest.mark.parametrize("name, steps", [("sampled", 1500), ("switched", 1500), ("deadbeat", 150)])
def test_the_dhat_gain_is_certified_for_every_sequence_and_bounds_the_runtime(dhat_cards, name, steps):
    """``gain_dhat_y`` (the poly-quadratic lemma of the dhat error system, state ``(eps, v_prev)``): finite, no less
    than any constant interval's or mode's peak, re-checked from the card's JSON; the runtime's dhat fed noise
    against its noise-free twin on the plant, on random interval or mode sequences, stays within it (with ``v_0``,
    the initial state ``(Xy_j0 v_0, v_0)`` of the error system adds ``initial_term`` times its norm). Seed 002's
    modes are unstable: its runs are short enough for the plant's state to leave the noise part its digits."""
    card = dhat_cards[name]
    noise = card.data["noise"]
    gain, cert = noise["gain_dhat_y"], noise["certificate_dhat_y"]
    assert gain is not None and math.isfinite(gain) and "gain_dhat_y" not in (noise["reason"] or "")
    peak = _frozen_peak(card)
    assert peak <= gain <= 10 * peak, (peak, gain)
    assert _rechecked(card).data["noise"]["gain_dhat_y"] == gain
    modes = len(card.data["matrices"]["N"])
    Xy = np.asarray(card.data["matrices"]["Xy"], dtype=float)
    rng = np.random.default_rng(3)
    p = card.dims["p"]
    for trial in range(4):
        sequence = rng.integers(0, modes, size=steps) if trial else np.zeros(steps, dtype=int)
        v = rng.normal(size=(steps, p)) * (1e-3 if trial % 2 else 1.0)
        if trial < 2:
            v[0] = 0.0                    # the error system starts at rest
        noisy, twin = _dhat_runs(card, v, sequence, seed=trial)
        measured = float(np.linalg.norm(noisy[1:] - twin[1:]))
        start = float(np.linalg.norm(np.concatenate([Xy[0] @ v[0], v[0]])))      # h_(-1), mode_prev0: index 0
        assert measured <= gain * float(np.linalg.norm(v)) + cert["initial_term"] * start, (trial, measured)
        assert measured > 0.0


@pytest.mark.parametrize("name", ["sampled", "switched"])
def test_a_lowered_dhat_gain_or_initial_term_fails_verify(dhat_cards, cli, tmp_path, name):
    """``uiofmu verify`` passes the card and refuses it with ``gain_dhat_y`` lowered below the peak of a constant
    interval or mode (no storage proves it), or its ``initial_term`` halved."""
    card = dhat_cards[name]
    (tmp_path / "card.json").write_text(card.to_json())
    assert cli("verify", tmp_path / "card.json").code == 0
    for key, where, factor in (("gain_dhat_y", None, 0.5 * _frozen_peak(card) / card.data["noise"]["gain_dhat_y"]),
                               ("initial_term", "certificate_dhat_y", 0.5)):
        doc = json.loads(card.to_json())
        section = doc["noise"] if where is None else doc["noise"][where]
        section[key] *= factor
        (tmp_path / "forged.json").write_text(json.dumps(doc))
        res = cli("verify", tmp_path / "forged.json")
        assert res.code != 0 and "gain_dhat_y" in res.out + res.err, (key, res.out, res.err)


def test_a_dhat_gain_without_dhat_is_refused(dhat_cards):
    """A switched card stripped of dhat's matrices that still claims ``gain_dhat_y`` fails its family's checks (and
    the card's problem, which determines those matrices)."""
    from uiofmu.families.switched import verify
    from uiofmu.runtime.kernels import DHAT

    doc = json.loads(dhat_cards["switched"].to_json())
    for key in DHAT:
        doc["matrices"].pop(key)
    doc["ports"] = [port for port in doc["ports"] if port["name"] != "dhat"]
    card = card_from_data(doc)
    assert any(not c.holds and "gain_dhat_y" in c.name for c in verify(card))
    with pytest.raises(uiofmu.CardError, match="matrices.Dy"):
        recheck(card)


#: The sampled-data plant with process noise ``[plant] W`` (held over the interval, sampled as E is).
SAMPLED_W = {**SAMPLED, "W": [[0.1], [0.0], [0.0], [0.2]], "x0": [1.0, -1.0, 0.5, 0.0]}


@pytest.fixture(scope="module")
def sampled_with_w(tmp_path_factory):
    """The sampled-data card of SAMPLED_W at alpha = 0.3, its plant FMU and its observer by each backend."""
    from uiofmu.fmu.export import build_observer, build_plant

    d = tmp_path_factory.mktemp("sampled_w")
    problem = problem_from_data({"name": "sampled-w", "plant": copy.deepcopy(SAMPLED_W), "observer": {
        "family": "sampled-data", "intervals": [0.1, 0.2], "alpha": 0.3}})
    card = uiofmu.design(problem)
    plant = build_plant(problem.plant, problem.name, d / "plant.fmu", step=problem.options.step, backend="c")
    return card, plant, {b: build_observer(card, d / f"obs-{b}.fmu", backend=b) for b in ("c", "python")}


def test_the_sampled_data_process_noise_gain_is_certified_for_every_sequence(sampled_with_w):
    """gain_w of a sampled-data card with [plant] W: at least each constant interval's peak, re-checked from the
    card alone, and a card with it lowered or without W_sampled is refused."""
    from uiofmu.noise import hinf_norm, pair_process_error_system

    card = sampled_with_w[0]
    noise = _rechecked(card).data["noise"]
    gain = noise["gain_w"]
    N, B, C, D = pair_process_error_system(card.data["matrices"])
    frozen = [hinf_norm(N[i, i], B[i, i], C[i], D[i]) for i in range(len(N))]
    assert max(frozen) <= gain <= 10 * max(frozen) and "gain_w" not in (noise["reason"] or "")
    for edit in (lambda d: d["noise"].update(gain_w=0.5 * max(frozen)),
                 lambda d: d["matrices"].pop("W_sampled")):
        forged = json.loads(card.to_json())
        edit(forged)
        with pytest.raises(Exception, match="gain_w|W_sampled"):
            recheck(card_from_data(forged))


@pytest.mark.parametrize("backend", ["c", "python"])
def test_the_sampled_data_process_noise_gain_holds_in_cosimulation(sampled_with_w, backend, cli, tmp_path):
    """cosim --noise w on aperiodic steps of both intervals: the noise part of the error (a noise-free twin loop)
    stays under the certified gain_w, and the twin respects the certified bound."""
    card, plant, observers = sampled_with_w
    res = cli("cosim", "--plant", plant, "--observer", observers[backend], "--steps", "choice:0.1,0.2", "--seed", "3",
              "--t-end", "60", "--noise", "w=0.5,2", "--out", tmp_path / "run", "--no-report")
    assert res.code == 0, res.err
    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert m["noise_gain_w_certified"] == card.data["noise"]["gain_w"]
    assert 0 < m["noise_gain_w_measured"] <= m["noise_gain_w_certified"] and m["noise_gain_w_respected"] is True
    assert m["bound_respected"] is True and m["step_min"] == 0.1 and m["step_max"] == 0.2
