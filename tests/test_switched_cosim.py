"""Switched observers and plants as FMUs, end to end: the command line, both backends, the master.

Seed 002's setup 2 is dead-beat: from the FMUs the error is zero (to round-off relative to the
state) one step after the start, under 100 random switching sequences with a random unknown
input. The three-mode example respects its certified bound. A plant driven by the input rule
takes its mode from ``[signals] mode`` or from a CSV column.
"""

from __future__ import annotations

import copy
import csv
import json

import numpy as np
import pytest

from tests.conftest import EXAMPLES
from uiofmu.cosim.inputs import SignalInputs
from uiofmu.cosim.master import cosimulate
from uiofmu.cosim.steps import step_sequence
from uiofmu.problem import load_problem, problem_from_data, to_toml
from uiofmu.signals import parse_signals

BACKENDS = ["c", "python"]


@pytest.fixture(scope="module", params=BACKENDS)
def setup2(request, tmp_path_factory):
    """Setup 2's observer and a random-switching plant FMU (seed a parameter), one backend."""
    from tests.conftest import run_cli

    out = tmp_path_factory.mktemp(f"setup2-{request.param}")
    data = copy.deepcopy(load_problem(EXAMPLES / "seed002_setup2.toml").data)
    data["plant"]["switching"] = {"rule": "random", "probabilities": [0.5, 0.5], "seed": 1}
    path = out / "setup2_random.toml"
    path.write_text(to_toml(data))
    for argv in (("design", path, "-o", out / "card.json"),
                 ("build", out / "card.json", "-o", out / "observer.fmu", "--backend", request.param),
                 ("plant", path, "-o", out / "plant.fmu", "--backend", request.param)):
        res = run_cli(*map(str, argv))
        assert res.code == 0, res.err
    return out


def test_dead_beat_from_the_fmus_under_100_random_switching_sequences(setup2):
    rng = np.random.default_rng(0)
    steps = step_sequence("fixed:1.0", 25.0)
    switched = 0
    for seed in range(100):
        d = parse_signals([[{"kind": "random", "seed": seed, "std": 0.05, "hold": 1.0}]], "signals.d", 1)
        result = cosimulate(setup2 / "plant.fmu", setup2 / "observer.fmu", steps, SignalInputs((), d),
                            plant_x0=rng.normal(size=3), xhat0=rng.normal(size=3),
                            plant_parameters={"seed": [seed]}, show_progress=False)
        e = np.linalg.norm(result.x - result.xhat, axis=1)
        scale = np.maximum(1.0, np.linalg.norm(result.x, axis=1))
        assert e[0] > 0.1
        assert np.all(e[1:] <= 1e-9 * scale[1:]), (seed, e[1:].max())
        switched += result.metrics["modes"]["switches"] > 0
        assert set(result.mode[:-1]) <= {1.0, 2.0}
    assert switched == 100


def design_build_run(cli, problem, out, t_end: str) -> None:
    """``uiofmu design``, ``build``, ``plant`` and ``cosim --out out/run`` (default backends)."""
    for argv in (("design", problem, "-o", out / "card.json"),
                 ("build", out / "card.json", "-o", out / "observer.fmu"),
                 ("plant", problem, "-o", out / "plant.fmu"),
                 ("cosim", "--plant", out / "plant.fmu", "--observer", out / "observer.fmu", "--out", out / "run",
                  "--t-end", t_end)):
        res = cli(*map(str, argv))
        assert res.code == 0, res.err


def test_cosim_command_writes_the_mode_and_the_bound(tmp_path, cli):
    design_build_run(cli, EXAMPLES / "seed002_three_modes.toml", tmp_path, "20")
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["bound_respected"] is True
    assert metrics["modes"]["switches"] > 50 and set(metrics["modes"]["steps_in_mode"]) == {"1", "2", "3"}
    with open(tmp_path / "run" / "results.csv") as f:
        rows = list(csv.DictReader(f))
    assert {row["mode"] for row in rows[:-1]} == {"1.0", "2.0", "3.0"}
    drawn = (tmp_path / "run" / "report.png").read_bytes()
    assert len(drawn) > 10_000
    (tmp_path / "run" / "report.png").unlink()
    assert cli("report", tmp_path / "run").code == 0          # the same figure, from results.csv and metrics.json
    assert (tmp_path / "run" / "report.png").read_bytes() == drawn


def test_input_rule_takes_the_mode_from_signals_and_from_a_csv(tmp_path, cli):
    data = copy.deepcopy(load_problem(EXAMPLES / "seed002_three_modes.toml").data)
    data["plant"]["switching"] = {"rule": "input"}
    data["signals"]["mode"] = [[{"kind": "constant", "value": 1.0}, {"kind": "step", "time": 0.95, "value": 2.0}]]
    path = tmp_path / "input_rule.toml"
    path.write_text(to_toml(data))
    assert problem_from_data(copy.deepcopy(data)).mode
    design_build_run(cli, path, tmp_path, "2")
    with open(tmp_path / "run" / "results.csv") as f:
        modes = [float(row["mode"]) for row in csv.DictReader(f)][:-1]
    assert modes[:10] == [1.0] * 10 and modes[10:] == [3.0] * 10
    table = tmp_path / "inputs.csv"
    table.write_text("time,u[1],d[1],mode[1]\n0,0.5,0.1,2\n0.5,0.5,0.1,5\n")
    res = cli("cosim", "--plant", tmp_path / "plant.fmu", "--observer", tmp_path / "observer.fmu",
              "--out", tmp_path / "bad", "--t-end", "1", "--inputs", table)
    assert res.code == 2 and "mode = 5" in res.err and "1 to 3" in res.err, res.err
