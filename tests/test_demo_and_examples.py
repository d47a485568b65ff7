"""The main job and the example scripts run end to end (real design, FMUs, co-simulation)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from tests.conftest import EXAMPLES


def test_demo(cli, tmp_path):
    res = cli("demo", "--out", tmp_path / "demo")
    assert res.code == 0, res.err
    for line in ("initial error", "final error", "steps to 1 %", "certified bound", "bound respected      yes"):
        assert line in res.out
    m = json.loads((tmp_path / "demo" / "metrics.json").read_text())
    assert m["bound_respected"] is True and m["t_end"] >= 86400 and m["step_max"] > 600
    for name in ("design.json", "observer.fmu", "plant.fmu", "results.csv", "report.png"):
        assert (tmp_path / "demo" / name).stat().st_size > 0


def _functional_end_to_end(cli, path, tmp_path, order: int) -> str:
    """check, design, verify, plant, build (C) and cosim of a functional problem file: the card of ``order``, the C
    FMU's zhat against Lf x of the plant's state within the certified bound and down by 1e-6; ``check``'s output."""
    checked = cli("check", path)
    assert checked.code == 0, checked.err
    assert cli("design", path, "-o", tmp_path / "card.json").code == 0
    card = json.loads((tmp_path / "card.json").read_text())
    assert card["order"] == card["dims"]["nz"] == order and card["dims"]["nf"] == 1
    assert cli("verify", tmp_path / "card.json").code == 0
    assert cli("plant", path, "-o", tmp_path / "plant.fmu").code == 0
    assert cli("build", tmp_path / "card.json", "-o", tmp_path / "obs.fmu").code == 0
    res = cli("cosim", "--plant", tmp_path / "plant.fmu", "--observer", tmp_path / "obs.fmu", "--out", tmp_path / "run",
              "--no-report")
    assert res.code == 0, res.err
    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert m["bound_respected"] is True and m["final_error_norm"] < 1e-6 * m["initial_error_norm"]
    return checked.out


def test_functional_uio_example(cli, tmp_path):
    """examples/functional_uio.toml end to end: check finds order 3, design writes it, the C FMU's zhat meets Lf x
    of the plant's state within the certified bound."""
    out = _functional_end_to_end(cli, EXAMPLES / "functional_uio.toml", tmp_path, 3)
    assert "functional observer of order 3 (searched 1..5)" in out


def test_functional_without_full_uio_example(cli, tmp_path):
    """examples/functional_without_full_uio.toml end to end: rank(CE) < rank(E) told as not required, check finds
    order 1, design writes it, the C FMU's zhat meets Lf x of the plant's state within the certified bound."""
    out = _functional_end_to_end(cli, EXAMPLES / "functional_without_full_uio.toml", tmp_path, 1)
    assert "functional observer of order 1 (searched 1..4)" in out
    assert "rank(CE) = 1 < rank(E) = 2" in out and "not required for a functional observer" in out


@pytest.mark.slow
@pytest.mark.parametrize("script,outputs", [
    ("seed000_example1.py", ["figure1_classical.png", "report.png", "metrics.json"]),
    ("two_room_building.py", ["figure1.png", "figure2.png", "report.png", "metrics.json"]),
    ("noise_building.py", ["report.png", "metrics.json", "results.csv"]),
    ("noise_tradeoff.py", ["tradeoff.png", "tradeoff.csv", "plant.fmu"]),
    ("ssp_libcosim.py", ["loop.ssp", "loop_held.ssp", "held_inputs.csv"]),
    pytest.param("quarter_car.py", ["dhat_vs_d.png", "quarter-car/report.png", "quarter-car-ltv/metrics.json"],
                 marks=pytest.mark.mujoco),
    ("seed000_ltv_vs_classical.py", ["fig1_x2_estimates.png", "fig2_eigenvalues.png", "fig6_alpha.png",
                                     "ltv/metrics.json", "example1_comparison.json"]),
    ("card_from_someone_else.py", ["observer.fmu", "hostile.fmu"]),
    ("seed001_delayed.py", ["errors_and_margin.png", "summary.json", "premise_input/h0.001/report.png",
                            "outside_the_premise/h0.001/metrics.json"]),
    ("seed002_switched.py", ["fig2_threshold.png", "fig2_random.png", "three_modes.png", "summary.json",
                             "setup2_threshold/metrics.json", "three_modes/report.png"]),
    ("seed003_deadbeat.py", ["example_functional.png", "needs_theta_functional.png", "summary.json",
                             "example/metrics.json", "example/report.png", "needs_theta/results.csv"]),
])
def test_example_scripts(script, outputs, tmp_path):
    """Each script runs in a temporary folder and writes there (UIOFMU_EXAMPLES_OUT), not into examples/out."""
    env = {**os.environ, "UIOFMU_EXAMPLES_OUT": str(tmp_path / "out")}
    proc = subprocess.run([sys.executable, str(EXAMPLES / script)], capture_output=True, text=True, cwd=tmp_path,
                          env=env)
    assert proc.returncode == 0, proc.stderr
    if script == "card_from_someone_else.py":
        assert "payload in the C sources: False" in proc.stdout
        assert "unchanged after the refused builds: True" in proc.stdout
        assert "PWNED exists: False" in proc.stdout and proc.stdout.count("exit 2") == 2
        assert not (tmp_path / "PWNED").exists()
    if script == "ssp_libcosim.py":
        assert "plant state, libcosim against our master: largest difference 0\n" in proc.stdout
        held = float(proc.stdout.split("with held inputs: first ")[1].split("last ")[1])
        assert held < 1e-2, proc.stdout
    if script == "noise_tradeoff.py":
        assert proc.stdout.count("(respected: True)") == 2 and "noise_gain = 1.5: decay" in proc.stdout
    if script == "seed001_delayed.py":
        runs = json.loads((tmp_path / "out" / "seed001_delayed" / "summary.json").read_text())["runs"]
        fine, coarse, outside = runs.values()
        assert fine["theta_error_after_1.5s_when_valid"] < 1e-2 < coarse["theta_error_after_1.5s_when_valid"]
        assert fine["invalid_stretches"] == 0 < outside["invalid_stretches"]
    if script == "seed002_switched.py":
        summary = json.loads((tmp_path / "out" / "seed002_switched" / "summary.json").read_text())
        assert not summary["setup1"]["exists"]
        assert max(summary["setup2"]["largest_gap_to_paper"].values()) < 1e-3
        assert summary["setup2_threshold"]["largest_relative_error_after_one_step"] < 1e-9
        assert summary["three_modes"]["bound_respected"]
    if script == "seed003_deadbeat.py":
        summary = json.loads((tmp_path / "out" / "seed003_deadbeat" / "summary.json").read_text())
        ex = summary["example"]
        assert ex["exists"] and ex["r"] == 2 and ex["t"] == 2 and ex["K"] == 1
        assert ex["P_1_lower_left"] == pytest.approx(-18.0, abs=1e-9) and ex["paper_prints"] == -14.0
        assert np.allclose(ex["P_1"], [[-4, 1, 0], [-16, 4, 0], [-18, 4, -1]], rtol=0, atol=1e-9)
        assert np.allclose(ex["P_2"], [[0, 0, 0], [0, 0, 0], [-1, 0, 0]], rtol=0, atol=1e-9)
        assert ex["invariant_is_span_e3"] and ex["Phat_2_is_zero"]
        assert np.allclose(ex["Phat_1"], [[-4, 1], [-16, 4]], rtol=0, atol=1e-9)
        assert ex["coefficients"] == pytest.approx({"y_k-2": 0, "y_k-1": 0, "y_k": 11, "y_k+1": 2}, abs=1e-9)
        assert ex["card"]["formula"] == "(G x)_1 at k = 11·y_k + 2·y_k+1" and not ex["uses_theta"]
        assert not summary["G_identity"]["exists"]
        assert any("nilpotent" in r and "Phat_1: -1" in r for r in summary["G_identity"]["reasons"])
        assert summary["G_prop6"]["K"] == 0 and summary["G_prop6"]["formula"] == "(G x)_1 at k = 1·y_k+1"
        for key, steps in (("example_cosim", 12), ("needs_theta_cosim", 400)):
            run = summary[key]
            assert run["steps"] == steps and run["exact_from_first_full_window"] and run["steps_to_exact"] == 3
        assert summary["example_cosim"]["max_relative_error_vs_3x1_2x2"] < 1e-13
        assert summary["example_cosim"]["pythonfmu_observer_max_difference"] <= 1e-12
        assert summary["needs_theta_cosim"]["uses_theta"]
        assert summary["needs_theta_cosim"]["max_relative_error_vs_window"] < 1e-13
        assert summary["needs_theta_cosim"]["median_relative_error_with_theta_zero"] > 1e-2
    folder = tmp_path / "out" / {"seed000_ltv_vs_classical.py": "seed000_ltv"}.get(script, script.removesuffix(".py"))
    for name in outputs:
        assert (folder / name).stat().st_size > 0
    for metrics in folder.glob("**/metrics.json"):
        assert json.loads(metrics.read_text())["final_error_norm"] < json.loads(metrics.read_text())["max_error_norm"]
