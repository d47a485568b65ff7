"""The main job and the example scripts run end to end (real design, FMUs, co-simulation)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

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


@pytest.mark.slow
@pytest.mark.parametrize("script,outputs", [
    ("seed000_example1.py", ["figure1_classical.png", "report.png", "metrics.json"]),
    ("two_room_building.py", ["figure1.png", "figure2.png", "report.png", "metrics.json"]),
    pytest.param("quarter_car.py", ["dhat_vs_d.png", "quarter-car/report.png", "quarter-car-ltv/metrics.json"],
                 marks=pytest.mark.mujoco),
    ("seed000_ltv_vs_classical.py", ["fig1_x2_estimates.png", "fig2_eigenvalues.png", "fig6_alpha.png",
                                     "ltv/metrics.json", "example1_comparison.json"]),
    ("card_from_someone_else.py", ["observer.fmu", "hostile.fmu"]),
    ("seed002_switched.py", ["fig2_threshold.png", "fig2_random.png", "three_modes.png", "summary.json",
                             "setup2_threshold/metrics.json", "three_modes/report.png"]),
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
    if script == "seed002_switched.py":
        summary = json.loads((tmp_path / "out" / "seed002_switched" / "summary.json").read_text())
        assert not summary["setup1"]["exists"]
        assert max(summary["setup2"]["largest_gap_to_paper"].values()) < 1e-3
        assert summary["setup2_threshold"]["largest_relative_error_after_one_step"] < 1e-9
        assert summary["three_modes"]["bound_respected"]
    folder = tmp_path / "out" / {"seed000_ltv_vs_classical.py": "seed000_ltv"}.get(script, script.removesuffix(".py"))
    for name in outputs:
        assert (folder / name).stat().st_size > 0
    for metrics in folder.glob("**/metrics.json"):
        assert json.loads(metrics.read_text())["final_error_norm"] < json.loads(metrics.read_text())["max_error_norm"]
