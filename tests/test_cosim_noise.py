"""Co-simulation with sensor noise (``cosim --noise``) and the bound check's round-off floor, with real FMUs on
both backends driven by fmpy."""

from __future__ import annotations

import csv
import io
import json

import numpy as np
import pytest

from tests.conftest import DC_MOTOR_LOAD_TORQUE as DC_MOTOR
from tests.conftest import run_cli
from uiofmu.cosim.master import cosimulate, default_steps, plant_is_design_model
from uiofmu.cosim.metrics import error_metrics
from uiofmu.cosim.noise import Noise, noise_metrics, parse_noise
from uiofmu.cosim.steps import step_sequence
from uiofmu.cosim.summary import print_summary
from uiofmu.fmu.export import build_observer
from uiofmu.runtime.card import card_from_data
from uiofmu.runtime.errors import ProblemError



def with_noise_gain(card, gain: float):
    """The card claiming ``gain`` without the certificate to prove it (schema-valid, refused by the re-check)."""
    data = dict(card.data)
    data["noise"] = {"norm": "l2", "gain_y": gain, "gain_w": None, "gain_dhat_y": None, "reason": None}
    return card_from_data(data)


def without_noise(card):
    """The card without its noise section: one designed before noise gains were certified (it claims none)."""
    data = {k: v for k, v in card.data.items() if k != "noise"}
    return card_from_data(data)


def hinf_gain(card) -> float:
    """The l2 gain of an lti card's estimate from the noise on y: the largest singular value of
    ``Xy + Xz (zI - N)^-1 L`` on the unit circle (a dense grid: the sup to a part in 1e4 here)."""
    m = card.matrices
    N, L, Xz, Xy = (np.asarray(m[k], dtype=float) for k in ("N", "L", "Xz", "Xy"))
    eye = np.eye(N.shape[0])
    return max(float(np.linalg.norm(Xy + Xz @ np.linalg.solve(np.exp(1j * w) * eye - N, L), 2))
               for w in np.linspace(0.0, np.pi, 20001))


@pytest.fixture(scope="module")
def dc_motor(tmp_path_factory):
    d = tmp_path_factory.mktemp("dc_motor")
    (d / "problem.toml").write_text(DC_MOTOR)
    assert run_cli("design", d / "problem.toml", "-o", d / "card.json").code == 0
    return d


@pytest.mark.parametrize("backend", ["c", "python"])
def test_dc_motor_bound_is_respected_with_the_round_off_floor_stated(dc_motor, backend, cli):
    """Gains of 4e6 leak about 1e-9 per step where the bound falls to 1e-49: the leaks, carried by the certified
    decay, are the floor, and the run on the design's own plant never blames a mismatch."""
    from uiofmu.runtime.card import read_card

    d = dc_motor
    assert run_cli("build", d / "card.json", "-o", d / f"obs-{backend}.fmu", "--backend", backend).code == 0
    assert run_cli("plant", d / "problem.toml", "-o", d / f"plant-{backend}.fmu", "--backend", backend).code == 0
    card = read_card(d / "card.json")
    steps = step_sequence(default_steps(card), 5.0, seed=0)
    plant, obs = d / f"plant-{backend}.fmu", d / f"obs-{backend}.fmu"
    result = cosimulate(plant, obs, steps, plant_x0=[1.0, 1.0, 1.0], xhat0=[1.001, 1.0, 1.0])
    m = result.metrics
    assert "plant" not in m                              # asked only of a run that violates its bound
    assert plant_is_design_model(plant, card) is True
    leaks = m["roundoff_floor"]
    assert leaks["roundoff"] and 0 < leaks["worst_leak"] <= leaks["leak_eps"] and leaks["carried"] > 0
    assert m["bound_respected"] is True and m["points_on_floor"] > 0
    assert m["bound_floor"] == pytest.approx(1e-9 * m["initial_error_norm"] + (1 + 1e-9) * leaks["carried"])
    # without the carried leaks, the fixed floor alone calls this correct observer a violation
    bare = error_metrics(result.times, result.h, result.x, result.xhat, result.bound, m["certified_decay"],
                         m["certified_overshoot"])
    assert bare["bound_respected"] is False
    said = io.StringIO()
    print_summary(m, file=said)
    assert "bound respected      yes" in said.getvalue()
    assert f"carried by the certified decay, {leaks['carried']:.3g}" in said.getvalue(), said.getvalue()
    res = cli("cosim", "--plant", plant, "--observer", obs, "--t-end", "5", "--out", d / f"run-{backend}",
              "--no-report")
    assert res.code == 0, res.err
    assert "bound respected      yes" in res.out and "mismatch" not in res.out


def test_a_plant_other_than_the_design_model_is_told_apart(dc_motor, tmp_path):
    from uiofmu.runtime.card import read_card

    card = read_card(dc_motor / "card.json")
    other = tmp_path / "other.toml"
    other.write_text(DC_MOTOR.replace("[0.0, -10.0, 1.0]", "[0.0, -10.5, 1.0]"))
    assert run_cli("plant", other, "-o", tmp_path / "other.fmu", "--backend", "c").code == 0
    assert plant_is_design_model(tmp_path / "other.fmu", card) is False
    assert run_cli("build", dc_motor / "card.json", "-o", tmp_path / "obs.fmu", "--backend", "c").code == 0
    steps = step_sequence(default_steps(card), 3.0, seed=1)
    m = cosimulate(tmp_path / "other.fmu", tmp_path / "obs.fmu", steps, plant_x0=[1.0, 1.0, 1.0],
                  xhat0=[1.1, 1.0, 1.0]).metrics
    assert m["plant"]["is_design_model"] is False
    assert m["roundoff_floor"]["roundoff"] is False          # the mismatch leaks far above round-off


@pytest.fixture(scope="module")
def example1(example1_card, example1_path, tmp_path_factory):
    d = tmp_path_factory.mktemp("noise")
    card = example1_card[0]
    for backend in ("c", "python"):
        assert run_cli("plant", example1_path, "-o", d / f"plant-{backend}.fmu", "--backend", backend).code == 0
    return card, d, hinf_gain(card)


@pytest.mark.parametrize("backend", ["c", "python"])
def test_noise_splits_exactly_and_respects_a_true_gain(example1, backend, cli):
    card, d, gain = example1
    assert card.data["noise"]["gain_y"] >= gain                     # the certified gain bounds the true one
    obs = build_observer(card, d / f"obs-true-{backend}.fmu", backend=backend)
    run = d / f"run-true-{backend}"
    res = cli("cosim", "--plant", d / f"plant-{backend}.fmu", "--observer", obs, "--steps", "fixed:0.1",
              "--t-end", "60", "--noise", "y=0.05,3", "--out", run)
    assert res.code == 0, res.err
    m = json.loads((run / "metrics.json").read_text())
    assert m["noise_gain_certified"] == card.data["noise"]["gain_y"]
    assert 0 < m["noise_gain_measured"] <= m["noise_gain_certified"] and m["noise_gain_respected"] is True
    assert m["noise"]["std"] == [0.05] and m["noise"]["seed"] == 3
    assert m["bound_respected"] is True                              # the twin is the noise-free run
    assert "noise gain           measured" in res.out and "respected" in res.out
    with open(run / "results.csv") as f:
        rows = list(csv.DictReader(f))
    v = np.array([[float(r["v[1]"])] for r in rows])
    # v[i] is what the observer received beyond y: the seeded samples, to the round-off of y + v - y
    np.testing.assert_allclose(v, Noise("y", (0.05,), 3).samples(len(rows), 1), rtol=0, atol=1e-15)
    diff = np.array([[float(r[f"xhat_noisy[{i}]"]) - float(r[f"xhat[{i}]"]) for i in (1, 2)] for r in rows])
    # the noise's part by the card's own recursion: z_0 takes -Xy v_0, xhat_0 is xhat0 for both observers
    mats = card.matrices
    dz = -mats["Xy"] @ v[0]
    expected = [np.zeros(2)]
    for k in range(1, len(rows)):
        dz = mats["N"] @ dz + mats["L"] @ v[k - 1]
        expected.append(mats["Xz"] @ dz + mats["Xy"] @ v[k])
    np.testing.assert_allclose(diff, np.array(expected), rtol=1e-9, atol=1e-12)
    assert m["noise_gain_measured"] == pytest.approx(np.linalg.norm(diff) / np.linalg.norm(v), rel=1e-12)
    assert (run / "report.png").stat().st_size > 10_000
    assert run_cli("report", run).code == 0


def test_a_gain_below_the_measured_one_is_a_false_certificate(example1, cli, tmp_path):
    """A card claiming half the gain its run measures never reaches a run (its noise certificate is re-checked
    first); the metrics of such a claim, had it one, say FALSE CERTIFICATE."""
    card, d, _ = example1
    plain = build_observer(card, d / "obs-plain-false.fmu", backend="c")
    run = cosimulate(d / "plant-c.fmu", plain, np.full(600, 0.1), noise="y=0.05,3")
    measured = run.metrics["noise_gain_measured"]
    forged = with_noise_gain(card, 0.5 * measured)
    (tmp_path / "forged.json").write_text(json.dumps(forged.data, default=lambda a: np.asarray(a).tolist()))
    res = cli("build", tmp_path / "forged.json", "-o", tmp_path / "obs-false.fmu")
    assert res.code == 2 and "noise" in res.err and not (tmp_path / "obs-false.fmu").exists()
    nz = run.noise
    m = noise_metrics(forged, nz["v"], nz["estimate"], run.xhat, run.x, noise=Noise("y", (0.05,), 3))
    assert m["noise_gain_respected"] is False and m["noise_gain_measured"] == pytest.approx(measured, rel=1e-12)
    out = io.StringIO()
    print_summary({**run.metrics, **m}, file=out)
    assert "FALSE CERTIFICATE" in out.getvalue()


def test_without_a_certified_gain_the_gain_is_measured_and_said_missing(example1):
    card, d, gain = example1
    obs = build_observer(without_noise(card), d / "obs-plain.fmu", backend="c")
    steps = np.full(300, 0.1)
    a = cosimulate(d / "plant-c.fmu", obs, steps, noise="y=0.1,9")
    b = cosimulate(d / "plant-c.fmu", obs, steps, noise=[Noise("y", (0.1,), 9)])
    assert a.metrics["noise_gain_certified"] is None and a.metrics["noise_gain_respected"] is None
    assert 0 < a.metrics["noise_gain_measured"] <= gain
    assert a.metrics["noise_gain_measured"] == b.metrics["noise_gain_measured"]     # the seed fixes the run
    plain = cosimulate(d / "plant-c.fmu", obs, steps)
    np.testing.assert_array_equal(plain.xhat, a.xhat)                                # the twin is the plain run
    assert "noise" not in plain.metrics


@pytest.mark.parametrize("text,fragment", [
    ("y=abc", "the standard deviation 'abc' is not a number"),
    ("y=-1", "must be a finite number >= 0"),
    ("y=nan", "is not a number"),
    ("q=1", "not q"),
    ("y=0", "every standard deviation is 0"),
    ("y=1,x", "the seed 'x' is not an integer"),
    ("y=[1,2]", "2 standard deviations for 1 element(s) of y"),
    ("y", "expected y=STD[,SEED]"),
    ("y=1," + "9" * 30, "is not an integer from 0 to 2**63 - 1"),
    ("w=0.1", "takes no process noise"),
])
def test_noise_text_is_untrusted_input(example1, cli, tmp_path, text, fragment):
    card, d, _ = example1
    obs = build_observer(card, tmp_path / "obs.fmu", backend="c")
    res = cli("cosim", "--plant", d / "plant-c.fmu", "--observer", obs, "--t-end", "1", "--noise", text,
              "--out", tmp_path / "run", "--no-report")
    assert res.code == 2
    assert fragment in res.err and len(res.err.strip().splitlines()) == 1, res.err


def test_parse_noise_reads_lists_and_refuses_long_texts():
    assert parse_noise("y=[0.1,2e-3],7") == Noise("y", (0.1, 0.002), 7)
    assert parse_noise("y=1e-6").seed == 0
    assert parse_noise(Noise("y", (0.1, 0.002), 7).text()) == Noise("y", (0.1, 0.002), 7)
    with pytest.raises(ProblemError, match="more than 2000"):
        parse_noise("y=[" + "1," * 2000 + "1]")


def test_a_violation_on_the_design_plant_never_blames_a_mismatch():
    metrics = {"steps": 10, "step_min": 0.1, "step_max": 0.1, "t_end": 1.0, "initial_error_norm": 1.0,
               "final_error_norm": 1e-3, "steps_to_1pct": None, "bound_formula": "b", "certified_decay": 0.5,
               "certified_overshoot": 1.0, "bound_respected": False, "first_bound_violation": 3,
               "error_at_first_violation": 0.2, "bound_at_first_violation": 0.125, "error_floor": 1e-3,
               "roundoff_floor": {"carried": 0.0, "worst_leak": 0.03, "leak_eps": 1e-12, "roundoff": False}}
    for design, said in ((True, "the plant FMU is the design's own model, so no model mismatch"),
                         (False, "a plant other than the design model has a mismatch floor")):
        out = io.StringIO()
        print_summary({**metrics, "plant": {"is_design_model": design}}, file=out)
        assert said in out.getvalue()
        assert ("has a mismatch floor" in out.getvalue()) is not design


def test_a_campaign_along_noise_y_measures_every_run_and_replays_the_worst(example1, tmp_path):
    """Sensor noise per row (one std for all outputs, three levels, one of them none), each row with its own
    seed: no run measures a gain above the true one certified, and the worst ratio's row replays bit for bit."""
    from uiofmu.cosim.campaign import read_table

    card, d, gain = example1
    obs = build_observer(card, tmp_path / "obs.fmu", backend="c")
    spec = tmp_path / "campaign.toml"
    spec.write_text(f'[campaign]\nobserver = "{obs}"\nplant = "{d / "plant-c.fmu"}"\nruns = 24\nseed = 3\n'
                    't_end = 20.0\n[axes]\nsteps = "fixed:0.1"\nxhat0_error = {kind = "normal", std = 1.0}\n'
                    "noise_y = [0.0, 0.01, 0.1]\n")
    out = tmp_path / "out"
    res = run_cli("campaign", spec, "--out", out, "--workers", "1")
    assert res.code == 0, res.err
    table = read_table(out / "campaign.csv")
    assert len(table) == 24 and all(r["status"] == "ok" for r in table)
    noisy = [r for r in table if float(r["noise_y[1]"]) > 0]
    assert noisy and len(noisy) < 24 and all(r["noise_gain_respected"] == "true" for r in noisy)
    assert len({r["noise_seed"] for r in table}) == 24
    assert all(r["noise_gain_measured"] == "" for r in table if float(r["noise_y[1]"]) == 0)
    summary = json.loads((out / "summary.json").read_text())
    worst = summary["worst_noise_gain_ratio"]
    ratios = [float(r["noise_gain_ratio"]) for r in noisy]
    assert worst["value"] == max(ratios) <= 1.0 and summary["noise_gain_violations"] == 0
    assert summary["quantiles"]["noise_rms_error"]["count"] == len(noisy)
    assert "rms_error" in summary["quantiles"]
    row = worst["row"]
    replay = run_cli("campaign", spec, "--out", out, "--replay", str(row))
    assert replay.code == 0, replay.err
    assert f"measured {float(table[row]['noise_gain_measured']):.4g}" in replay.out
    assert (out / "campaign.png").stat().st_size > 10_000


def test_a_noise_axis_takes_standard_deviations_only(example1, tmp_path):
    card, d, _ = example1
    obs = build_observer(card, tmp_path / "obs.fmu", backend="c")
    for axis, message in (('{kind = "normal", std = 1.0}', "a normal draw is not always"),
                          ("[0.1, -0.1]", "axes.noise_y[1]: a standard deviation is >= 0, found -0.1"),
                          ("[[0.1, 0.2]]", "axes.noise_y[0]: expected 1 value(s)")):
        spec = tmp_path / "campaign.toml"
        spec.write_text(f'[campaign]\nobserver = "{obs}"\nplant = "{d / "plant-c.fmu"}"\nruns = 2\n'
                        f"[axes]\nnoise_y = {axis}\n")
        res = run_cli("campaign", spec, "--out", tmp_path / "out")
        assert res.code == 2 and message in res.err, res.err


def test_quantized_outputs_are_measured_like_noise(example1, tmp_path):
    """A quantum of 0.05 with no noise: the observer receives y rounded, the twin y; the gain is measured on the
    rounding error (at most Q/2 per output) and stays under the true gain; a campaign along quantization too."""
    from uiofmu.cosim.campaign import read_table

    card, d, gain = example1
    obs = build_observer(card, tmp_path / "obs.fmu", backend="c")
    result = cosimulate(d / "plant-c.fmu", obs, np.full(400, 0.1), quantization=0.05)
    m = result.metrics
    v = result.noise["v"]
    assert 0 < np.abs(v).max() <= 0.025 * (1 + 1e-12)
    assert m["noise"]["quantum"] == 0.05 and m["noise"]["text"] is None
    assert m["noise_std_norm"] == pytest.approx(0.05 / np.sqrt(12))
    assert 0 < m["noise_gain_measured"] <= m["noise_gain_certified"] and m["noise_gain_respected"] is True
    with pytest.raises(ProblemError, match="a finite number > 0"):
        cosimulate(d / "plant-c.fmu", obs, np.full(10, 0.1), quantization=-1.0)
    spec = tmp_path / "campaign.toml"
    spec.write_text(f'[campaign]\nobserver = "{obs}"\nplant = "{d / "plant-c.fmu"}"\nruns = 6\nseed = 1\n'
                    'grid = true\n'
                    't_end = 10.0\n[axes]\nsteps = "fixed:0.1"\nquantization = [0.0, 0.02, 0.2]\n')
    res = run_cli("campaign", spec, "--out", tmp_path / "out", "--workers", "1")
    assert res.code == 0, res.err
    table = read_table(tmp_path / "out" / "campaign.csv")
    assert {r["quantization"] for r in table} == {"0.0", "0.02", "0.2"} and "noise_seed" not in table[0]
    assert all((r["noise_gain_respected"] == "true") == (float(r["quantization"]) > 0) for r in table)
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["noise_gain_violations"] == 0 and summary["worst_noise_gain_ratio"]["value"] <= 1.0


def test_a_functional_observer_s_noise_part_is_its_window_formula(tmp_path, cli):
    """gx at point k is 11 y_(k-1) + 2 y_k (G x of one step back): its noise part is 11 v_(k-1) + 2 v_k exactly."""
    from tests.conftest import EXAMPLES

    problem = EXAMPLES / "seed003_example.toml"
    assert cli("design", problem, "-o", tmp_path / "card.json").code == 0
    assert cli("build", tmp_path / "card.json", "-o", tmp_path / "obs.fmu", "--backend", "c").code == 0
    assert cli("plant", problem, "-o", tmp_path / "plant.fmu", "--backend", "c").code == 0
    res = cli("cosim", "--plant", tmp_path / "plant.fmu", "--observer", tmp_path / "obs.fmu", "--noise", "y=0.01,2",
              "--out", tmp_path / "run", "--no-report")
    assert res.code == 0, res.err
    assert "noise gain           measured" in res.out and "respected" in res.out
    with open(tmp_path / "run" / "results.csv") as f:
        rows = list(csv.DictReader(f))
    v = np.array([float(r["v[1]"]) for r in rows])
    valid = np.array([float(r["gx_valid"]) for r in rows]) > 0.5
    diff = np.array([float(r["gx_noisy[1]"]) - float(r["gx[1]"]) for r in rows])
    k = np.flatnonzero(valid)
    assert k.size > 5
    np.testing.assert_allclose(diff[k], 11 * v[k - 1] + 2 * v[k], rtol=1e-12, atol=1e-14)
