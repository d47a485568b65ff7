"""The co-simulation master, from the command line, with real FMUs."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from uiofmu.runtime.errors import ProblemError
from uiofmu.cosim.metrics import settling_index
from uiofmu.cosim.steps import step_sequence


@pytest.fixture(scope="module")
def built(example1_card, example1_path, tmp_path_factory, ):
    from tests.conftest import run_cli

    card, card_path = example1_card
    d = tmp_path_factory.mktemp("cosim")
    assert run_cli("build", card_path, "-o", d / "obs.fmu").code == 0
    assert run_cli("plant", example1_path, "-o", d / "plant.fmu").code == 0
    return card, d


def read_results(path):
    with open(path) as f:
        rows = list(csv.DictReader(f))
    return rows


def test_cosim_converges_as_the_runtime_predicts(built, cli):
    card, d = built
    res = cli("cosim", "--plant", d / "plant.fmu", "--observer", d / "obs.fmu", "--steps", "fixed:0.1",
              "--t-end", "60", "--out", d / "run")
    assert res.code == 0, res.err
    metrics = json.loads((d / "run" / "metrics.json").read_text())
    for key in ("steps", "initial_error_norm", "final_error_norm", "rms_error", "steps_to_1pct",
                "certified_decay", "certified_overshoot", "bound_respected"):
        assert key in metrics
    assert metrics["steps"] == 600
    assert metrics["bound_respected"] is True
    # the error follows e_k = N^k e_0 exactly (d is decoupled), so the runtime predicts every number
    N = card.matrices["N"]
    x0 = np.array(card.data["problem"]["plant"]["x0"])
    e = [x0 - np.array(card.data["initial"]["xhat0"])]
    for _ in range(600):
        e.append(N @ e[-1])
    norms = np.linalg.norm(e, axis=1)
    assert metrics["final_error_norm"] == pytest.approx(norms[-1], rel=1e-9)
    assert metrics["steps_to_1pct"] == settling_index(norms, 0.01)
    rows = read_results(d / "run" / "results.csv")
    assert len(rows) == 601
    np.testing.assert_allclose([float(r["error_norm"]) for r in rows], norms, rtol=1e-9, atol=1e-13)
    assert (d / "run" / "report.png").stat().st_size > 10_000
    assert "bound respected      yes" in res.out


def test_cosim_with_csv_inputs(built, cli, tmp_path):
    _, d = built
    table = tmp_path / "in.csv"
    table.write_text("time,u[1],d[1]\n0,1.0,0.0\n1.0,-1.0,2.0\n2.5,0.0,-3.0\n")
    res = cli("cosim", "--plant", d / "plant.fmu", "--observer", d / "obs.fmu", "--inputs", table,
              "--t-end", "4", "--out", tmp_path / "run")
    assert res.code == 0, res.err
    rows = read_results(tmp_path / "run" / "results.csv")
    by_t = {round(float(r["time"]), 6): r for r in rows}
    assert float(by_t[0.5]["u[1]"]) == 1.0 and float(by_t[1.0]["d[1]"]) == 2.0
    assert float(by_t[2.4]["d[1]"]) == 2.0 and float(by_t[2.5]["d[1]"]) == -3.0
    assert json.loads((tmp_path / "run" / "metrics.json").read_text())["bound_respected"] is True


@pytest.mark.parametrize("args,fragment", [
    (["--steps", "fixed:0.2"], "refused step 0 (t = 0 s, h = 0.2 s)"),
    (["--steps", "sometimes:3"], "--steps: unknown kind 'sometimes'"),
    (["--steps", "fixed:-1"], "fixed:H must be > 0"),
    (["--steps", "uniform:2:1"], "HMIN = 2 > HMAX = 1"),
    (["--t-end", "-3"], "--t-end: expected a finite time > 0"),
])
def test_cosim_bad_arguments_exit_2(built, cli, tmp_path, args, fragment):
    _, d = built
    res = cli("cosim", "--plant", d / "plant.fmu", "--observer", d / "obs.fmu", *args, "--out", tmp_path / "r")
    assert res.code == 2, res
    assert fragment in res.err and "Traceback" not in res.err


def test_bad_csv_exits_2(built, cli, tmp_path):
    _, d = built
    table = tmp_path / "in.csv"
    table.write_text("time,u[1],d[7]\n0,1,2\n")
    res = cli("cosim", "--plant", d / "plant.fmu", "--observer", d / "obs.fmu", "--inputs", table,
              "--out", tmp_path / "r")
    assert res.code == 2 and "column d[7] but the plant has 1 d channel(s)" in res.err


def test_step_sequences(tmp_path):
    assert step_sequence("fixed:0.5", 2.0).tolist() == [0.5] * 4
    a = step_sequence("choice:0.1,0.3", 10.0, seed=4)
    assert set(a.tolist()) == {0.1, 0.3} and a.sum() >= 10.0 - 1e-9
    assert np.array_equal(a, step_sequence("choice:0.1,0.3", 10.0, seed=4))
    assert not np.array_equal(a, step_sequence("choice:0.1,0.3", 10.0, seed=5))
    u = step_sequence("uniform:0.1:0.2", 50.0, seed=1)
    assert u.min() >= 0.1 and u.max() <= 0.2 and len(set(u.tolist())) == len(u)
    f = tmp_path / "steps.txt"
    f.write_text("# steps\n0.1\n0.2\n\n0.3\n")
    assert step_sequence(f"file:{f}", 0.25).tolist() == [0.1, 0.2]
    with pytest.raises(ProblemError, match="line 2 of"):
        f.write_text("0.1\nabc\n")
        step_sequence(f"file:{f}", 1.0)


def _one_draw_a_step(spec: str, t_end: float, seed: int) -> list:
    """The definition of the random kinds: one step drawn at a time until ``t_end`` is reached."""
    rng = np.random.default_rng(seed)
    kind, _, rest = spec.partition(":")
    parts = rest.split(":")
    if kind == "choice":
        options = [float(v) for v in rest.split(",")]
        draw = lambda: options[int(rng.integers(len(options)))]          # noqa: E731
    elif kind == "uniform":
        draw = lambda: float(rng.uniform(float(parts[0]), float(parts[1])))  # noqa: E731
    else:
        nominal, prob, most = float(parts[0]), float(parts[1]), int(parts[2])

        def draw():
            lost = 0
            while lost < most and rng.random() < prob:
                lost += 1
            return nominal * (1 + lost)
    out, t = [], 0.0
    while t < t_end * (1 - 1e-12):
        out.append(draw())
        t += out[-1]
    return out


@pytest.mark.parametrize("spec", ["choice:0.1,0.3", "choice:0.2", "choice:0.1,0.2,0.3,0.4,0.5,0.6,0.7",
                                  "uniform:0.01:0.5", "uniform:0.3:0.3", "dropout:0.1:0.3:2", "dropout:0.1:0.9:7",
                                  "dropout:0.1:0.5:0", "dropout:0.1:0:3", "dropout:0.1:0.99:1000",
                                  "dropout:0.1:0.5:" + "9" * 30])
def test_drawn_at_once_the_steps_are_those_drawn_one_at_a_time(spec):
    for seed in range(12):
        for t_end in (0.05, 1.0, 7.3, 400.0):
            assert step_sequence(spec, t_end, seed=seed).tolist() == _one_draw_a_step(spec, t_end, seed), \
                (spec, seed, t_end)


def test_too_many_steps_are_refused():
    with pytest.raises(ProblemError, match="needs more than 10000000 steps"):
        step_sequence("uniform:1e-6:2e-6", 1e3, seed=1)
    with pytest.raises(ProblemError, match=r"needs more than 33554432 random draws \(a sample arrives too rarely\)"):
        step_sequence("dropout:0.1:0.99999999:" + "9" * 30, 1e3, seed=1)


def test_continuous_plant_lti_observer_end_to_end(tmp_path, cli):
    problem = tmp_path / "osc.toml"
    problem.write_text("""name = "osc"
[plant]
time = "continuous"
A = [[0.0, 1.0, 0.0], [-2.0, -0.5, 1.0], [0.0, 0.0, -1.0]]
B = [[0.0], [0.0], [1.0]]
E = [[0.0], [1.0], [0.0]]
C = [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
x0 = [1.0, 0.5, -0.5]
[observer]
family = "lti-uio"
dt = 0.05
decay = "max"
[signals]
u = [[{kind = "sine", amplitude = 1.0, frequency_hz = 0.2}]]
d = [[{kind = "random", seed = 3, std = 1.0, hold = 0.05}]]
""")
    assert cli("design", problem, "-o", tmp_path / "osc.json").code == 0
    assert cli("build", tmp_path / "osc.json", "-o", tmp_path / "o.fmu").code == 0
    assert cli("plant", problem, "-o", tmp_path / "p.fmu").code == 0
    res = cli("cosim", "--plant", tmp_path / "p.fmu", "--observer", tmp_path / "o.fmu", "--out", tmp_path / "run")
    assert res.code == 0, res.err
    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    # d is random but held over each step, which the sampled design decouples exactly
    assert m["bound_respected"] is True
    # the default horizon runs until the certified bound reaches 1e-3 of the initial error
    assert m["final_error_norm"] <= 1e-3 * m["certified_overshoot"] * m["initial_error_norm"]
    assert m["steps_to_1pct"] is not None


@pytest.mark.parametrize("header,fragment", [
    ("time,u[1]", "missing column(s) d[1]"),
    ("time,u[1],d[1],mode[1]", "unknown column 'mode[1]' (the FMUs take u[1..1], d[1..1])"),
    ("time,u[1],d[1],y[1]", "unknown column 'y[1]'"),            # y comes from the plant, not the table
])
def test_every_csv_column_is_used_and_every_input_has_one(built, cli, tmp_path, header, fragment):
    _, d = built
    table = tmp_path / "in.csv"
    table.write_text(header + "\n" + ",".join(["0"] * len(header.split(","))) + "\n")
    res = cli("cosim", "--plant", d / "plant.fmu", "--observer", d / "obs.fmu", "--inputs", table,
              "--out", tmp_path / "r")
    assert res.code == 2 and fragment in res.err, res.err


def test_signals_are_routed_by_name(built):
    """The observer's y comes from the plant's y; u (both FMUs) and d (the plant) from the source;
    an input nothing gives is named."""
    from uiofmu.cosim.fmi import Fmu
    from uiofmu.cosim.master import routes
    from uiofmu.runtime.errors import FmuError

    _, d = built
    with Fmu(d / "plant.fmu", "plant") as plant, Fmu(d / "obs.fmu", "observer") as obs:
        assert routes(plant, obs, {"u": 1, "d": 1}) == (["y"], ["u"])
        with pytest.raises(FmuError, match=r"the plant FMU takes the input d\[1\.\.1\], which no plant output"):
            routes(plant, obs, {"u": 1})
        with pytest.raises(FmuError, match="the plant FMU takes 1 inputs u, the input source gives 2"):
            routes(plant, obs, {"u": 2, "d": 1})


def test_report_draws_a_cosim_run_again(built, cli):
    """`uiofmu report RUN_DIR` draws report.png again from the run's results.csv and metrics.json: the same figure."""
    _, d = built
    run = d / "redraw"
    assert cli("cosim", "--plant", d / "plant.fmu", "--observer", d / "obs.fmu", "--steps", "fixed:0.1",
               "--t-end", "20", "--out", run).code == 0
    drawn = (run / "report.png").read_bytes()
    (run / "report.png").unlink()
    res = cli("report", run)
    assert res.code == 0, res.err
    assert (run / "report.png").read_bytes() == drawn
    assert json.loads((run / "metrics.json").read_text())["title"].endswith("steps fixed:0.1")


@pytest.mark.parametrize("damage,fragment", [
    (lambda run: (run / "metrics.json").unlink(), "metrics.json: no such metrics file"),
    (lambda run: (run / "results.csv").write_text("time,h,x[1],xhat[1]\n0,0.1,1,0\n0.1,,abc,0\n"),
     "results.csv: line 3: a value is not a number"),
    (lambda run: (run / "metrics.json").write_text('{"certified_decay": "fast"}'),
     "certified_decay: expected a finite number, found fast"),
    (lambda run: (run / "results.csv").write_text("time,h,x[1],xhat[1]\n0,0.1,1," + "9" * 200_000 + "\n"),
     "results.csv: not a CSV table (field larger than field limit"),
    (lambda run: (run / "results.csv").write_text("time,h,x[1],xhat[1],xhat[2]\n0,0.1,1,0,0\n0.1,,1,0,0\n"),
     "results.csv: 1 columns x[i] but 2 columns xhat[i]"),
])
def test_report_of_a_damaged_run_exits_2(built, cli, tmp_path, damage, fragment):
    _, d = built
    run = tmp_path / "run"
    assert cli("cosim", "--plant", d / "plant.fmu", "--observer", d / "obs.fmu", "--steps", "fixed:0.1",
               "--t-end", "2", "--out", run).code == 0
    before = (run / "report.png").read_bytes()
    damage(run)
    res = cli("report", run)
    assert res.code == 2 and fragment in res.err, res
    assert len(res.err.strip().splitlines()) == 1 and "Traceback" not in res.err
    assert (run / "report.png").read_bytes() == before


def test_report_draws_a_binary_table_again(built, cli, tmp_path):
    """`cosim --format npz` then `uiofmu report`: the table metrics.json names is read, the same figure."""
    _, d = built
    run = tmp_path / "npz"
    assert cli("cosim", "--plant", d / "plant.fmu", "--observer", d / "obs.fmu", "--steps", "fixed:0.1",
               "--t-end", "5", "--out", run, "--format", "npz").code == 0
    assert json.loads((run / "metrics.json").read_text())["results_file"] == "results.npz"
    drawn = (run / "report.png").read_bytes()
    (run / "report.png").unlink()
    res = cli("report", run)
    assert res.code == 0, res.err
    assert (run / "report.png").read_bytes() == drawn
    (run / "results.npz").write_bytes(b"PK\x03\x04 not an archive")
    res = cli("report", run)
    assert res.code == 2 and "results.npz: not a results table" in res.err, res.err


@pytest.mark.parametrize("t_end,unit", [(5.0, "s"), (600.0, "s"), (601.0, "min"), (36000.0, "min"),
                                        (36001.0, "h"), (172800.0, "h"), (240 * 3600.0 + 1, "d")])
def test_time_axis_unit_follows_the_run_length(t_end, unit):
    from uiofmu.cosim.report import time_unit

    scale, name = time_unit(t_end)
    assert name == unit and scale == {"s": 1.0, "min": 60.0, "h": 3600.0, "d": 86400.0}[unit]


def _step_panel(h):
    from uiofmu.cosim.report import plot_steps, pyplot
    from uiofmu.cosim.master import communication_points

    plt, _ = pyplot()
    fig, ax = plt.subplots()
    plot_steps(ax, communication_points(h), h, "s")
    heights = [p.get_height() for p in ax.patches]
    lines = [line.get_xdata().size for line in ax.get_lines()]
    plt.close(fig)
    return heights, lines, ax.get_xlabel()


def test_step_panel_is_a_trace_up_to_the_limit_and_a_histogram_beyond():
    from uiofmu.cosim.report import STEP_TRACE_LIMIT

    drawn = step_sequence("choice:0.1,0.3", 400.0, seed=2)
    heights, lines, xlabel = _step_panel(drawn[:STEP_TRACE_LIMIT])
    assert heights == [] and lines == [STEP_TRACE_LIMIT] and xlabel == "time [s]"       # the step trace
    long = drawn[:STEP_TRACE_LIMIT + 1]
    heights, lines, xlabel = _step_panel(long)
    assert lines == [] and xlabel == "step length h [s]"
    assert heights == [np.count_nonzero(long == 0.1), np.count_nonzero(long == 0.3)]   # one bar per length
    spread = step_sequence("uniform:0.1:0.2", 1000.0, seed=2)[:5000]
    heights, lines, _ = _step_panel(spread)
    assert len(heights) == 50 and sum(heights) == 5000 and lines == []


def test_bound_check_allows_the_round_off_floor_and_says_where_it_used_it():
    from uiofmu.cosim.metrics import error_metrics

    steps = np.full(10, 0.1)
    times = np.concatenate([[0.0], np.cumsum(steps)])
    bound = np.concatenate([[1.0, 0.1, 0.01], np.zeros(8)])
    x, xhat = np.zeros((11, 1)), np.zeros((11, 1))
    x[:, 0] = np.concatenate([[1.0, 0.05, 0.005], np.full(8, 5e-10)])      # under the floor 1e-9 ||e_0||
    m = error_metrics(times, steps, x, xhat, bound, 0.1, 1.0)
    assert m["bound_respected"] and m["bound_floor"] == 1e-9 and m["points_on_floor"] == 8
    x[-1, 0] = 2e-9                                                          # above bound and floor
    m = error_metrics(times, steps, x, xhat, bound, 0.1, 1.0)
    assert not m["bound_respected"] and m["first_bound_violation"] == 10 and m["points_on_floor"] == 7


def test_the_bound_ratio_is_measured_from_k_1():
    """At k = 0 the bound is M ||e_0||: with M = 1 the ratio there is 1 by construction, not a property of the run."""
    from uiofmu.cosim.metrics import error_metrics

    norms = np.array([2.0, 1.2, 1.1, 0.3])
    bound = 2.0 * 0.8 ** np.arange(4)                  # M = 1, decay 0.8
    x = np.zeros((4, 2))
    xhat = np.column_stack([norms, np.zeros(4)])
    m = error_metrics(np.arange(4.0), np.ones(3), x, xhat, bound=bound, decay=0.8, overshoot=1.0)
    slack = bound * (1 + 1e-9) + 1e-9 * norms[0]
    assert norms[0] / slack[0] == pytest.approx(1.0, abs=1e-8)
    assert m["max_bound_ratio_step"] == 2 and m["max_bound_ratio"] == norms[2] / slack[2] < 0.86
    assert m["bound_respected"] is True
    one = error_metrics(np.zeros(1), np.zeros(0), x[:1], xhat[:1], bound=bound[:1], decay=0.8, overshoot=1.0)
    assert one["max_bound_ratio_step"] == 0        # a run without steps has only k = 0


def test_cosim_metrics_give_the_ratio_from_k_1(built, cli):
    card, d = built
    res = cli("cosim", "--plant", d / "plant.fmu", "--observer", d / "obs.fmu", "--t-end", "20", "--out", d / "k1")
    assert res.code == 0, res.err
    metrics = json.loads((d / "k1" / "metrics.json").read_text())
    rows = read_results(d / "k1" / "results.csv")
    norms = np.array([float(r["error_norm"]) for r in rows])
    M, delta = metrics["certified_overshoot"], metrics["certified_decay"]
    bound = M * delta ** np.arange(len(norms)) * norms[0]
    ratio = norms / (bound * (1 + 1e-9) + 1e-9 * norms[0])
    k = metrics["max_bound_ratio_step"]
    assert k == 1 + int(np.argmax(ratio[1:])) and metrics["max_bound_ratio"] == pytest.approx(ratio[k], rel=1e-12)


def test_results_in_binary_formats_hold_the_csv_columns(built, cli):
    card, d = built
    args = ["cosim", "--plant", d / "plant.fmu", "--observer", d / "obs.fmu", "--t-end", "5", "--no-report"]
    assert cli(*args, "--out", d / "csv").code == 0
    rows = read_results(d / "csv" / "results.csv")
    csv_cols = {k: np.array([float(r[k]) if r[k] else np.nan for r in rows]) for k in rows[0]}
    res = cli(*args, "--out", d / "npz", "--format", "npz")
    assert res.code == 0, res.err
    assert not (d / "npz" / "results.csv").exists() and "results.npz" in res.out
    with np.load(d / "npz" / "results.npz") as z:
        assert list(z.files) == list(csv_cols)
        for key, values in csv_cols.items():
            np.testing.assert_array_equal(z[key], values)      # the same doubles (NaN where the CSV is empty)
    res = cli(*args, "--out", d / "pq", "--format", "parquet")
    try:
        import pyarrow.parquet as pq
    except ImportError:
        assert res.code == 2 and "--format parquet: needs pyarrow" in res.err and res.err.count("\n") == 1
        assert not (d / "pq").exists() or not any((d / "pq").iterdir())
    else:
        assert res.code == 0, res.err
        table = pq.read_table(d / "pq" / "results.parquet")
        assert table.column_names == list(csv_cols)
        for key, values in csv_cols.items():
            np.testing.assert_array_equal(table.column(key).to_numpy(), values)
    bad = cli(*args, "--out", d / "x", "--format", "xlsx")
    assert bad.code == 2 and "--format 'xlsx': expected one of csv, npz, parquet" in bad.err


def test_a_long_spec_is_shortened_in_titles_and_messages():
    from uiofmu.cosim.steps import short_spec

    spec = "choice:" + ",".join(["0.1"] * 100_000)
    assert short_spec(spec) == spec[:80] + f"... ({len(spec)} characters)" and short_spec("fixed:0.1") == "fixed:0.1"
