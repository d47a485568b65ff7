"""Work and range bounds: what a problem file can make uiofmu compute is bounded before it is spent.

1. The dead-beat functional family's exact polynomial arithmetic (:mod:`uiofmu.polynomials`) grows
   combinatorially with the window, the states and the scheduling components: LPV chains of 8, 16 and
   30 states with 8 components ran for minutes into gigabytes (or exited 1 on a MemoryError); they are
   refused with exit 2 within seconds and a bounded memory, naming the numbers, while the seed 003
   examples stay 10^4 times inside the limits.
2. Finite but extreme numbers of the plant parsers (a theta of 1e308, a period of 1e308, entries of
   1e300) exited 1 (ZeroDivisionError, OverflowError, a ValueError): they are refused with exit 2
   naming the key, the value and the range.
3. A plant runtime with internal substeps (the parametric plant's RK4) given h = 1e300 never returned:
   a step is bounded by ``MAX_SUBSTEPS``, a longer one refused at once (fmi2Discard and a log line
   naming h, the substep and the longest step), through the runtime and the real FMU.
"""

from __future__ import annotations

import copy
import math
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import run_cli

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"

#: Wall-clock budget of one refused chain plant: the work limit is about a second of arithmetic, the
#: rest is the interpreter's start-up; the budget leaves room for a loaded machine (the unbounded
#: computation ran for minutes).
REFUSAL_SECONDS = 25.0
#: Memory budget of one refused chain plant (peak resident set of the process, imports included:
#: about 60 MB); the unbounded computation grew past gigabytes.
REFUSAL_MB = 400


def _matrix(rows) -> str:
    return "[" + ", ".join("[" + ", ".join(repr(float(v)) for v in row) + "]" for row in rows) + "]"


def chain_problem(n: int, s: int, feedback: str = "first column", g: int = 0) -> str:
    """An LPV chain ``x_i+ = x_i+1``, ``x_n+ = d``, ``y = x_1``, with ``s`` scheduling components.

    ``feedback = "first column"``: component i feeds ``y = x_1`` back into every state with its own
    weights (``A_i = v_i e_1'``; the unknown input's path stays constant, so the inverse system exists
    and its matrices hold every product of the window). ``"last row"``: component i feeds the states
    into ``x_n`` (``A_i = e_n v_i'``). ``G = e_(g+1)'``.
    """
    A = [[1.0 if j == i + 1 else 0.0 for j in range(n)] for i in range(n)]
    lines = [f'name = "chain-{n}-{s}"', "[plant]", 'time = "discrete"', "dt = 1.0", f"A = {_matrix(A)}",
             f"E = {_matrix([[1.0 if i == n - 1 else 0.0] for i in range(n)])}",
             f"C = {_matrix([[1.0] + [0.0] * (n - 1)])}"]
    for i in range(s):
        if feedback == "first column":
            part = [[0.1 * (1 + (r * 7 + i * 3) % 5) if c == 0 else 0.0 for c in range(n)] for r in range(n)]
        else:
            part = [[0.1 * (1 + (c * 7 + i * 3) % 5) if r == n - 1 and c < n - 1 else 0.0 for c in range(n)]
                    for r in range(n)]
        lines += ["[[plant.scheduling]]", f"A = {_matrix(part)}"]
    lines += ["[plant.theta]", 'kind = "input"', "[observer]", 'family = "deadbeat-functional"',
              f"G = {_matrix([[1.0 if j == g else 0.0 for j in range(n)]])}"]
    return "\n".join(lines) + "\n"


#: ``python -c`` program that runs ``uiofmu ARGV`` and, at exit, writes its own peak resident set
#: (``VmHWM`` of /proc/self/status, in kB) to the file named by its first argument.
_MEASURED = """import atexit, runpy, sys
def peak(path=sys.argv[1]):
    with open("/proc/self/status") as f:
        kb = next(line.split()[1] for line in f if line.startswith("VmHWM:"))
    with open(path, "w") as f:
        f.write(kb)
atexit.register(peak)
sys.argv = ["uiofmu", *sys.argv[2:]]
runpy.run_module("uiofmu", run_name="__main__")
"""


def run_measured(tmp_path, *argv) -> tuple[subprocess.CompletedProcess, float, float]:
    """``python -m uiofmu ARGV`` in a child process: its result, wall-clock seconds and peak resident MB.

    The peak is the child's own (``VmHWM`` of the program it runs, read by the child as it exits), not
    ``wait4``'s ``ru_maxrss``: Linux keeps in that the size of the process the child was forked from (a
    pytest worker, hundreds of MB after the test files before) up to its ``exec``. The child's address
    space is capped at 3 GB so that an unbounded computation fails fast instead of taking the machine; a
    run past ``2 * REFUSAL_SECONDS`` is killed (exit code -9: the test fails).
    """
    import resource
    import threading

    def cap():
        resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))

    env = dict(os.environ, PYTHONPATH=str(ROOT))
    out, err, hwm = tmp_path / "stdout.txt", tmp_path / "stderr.txt", tmp_path / "peak_kb.txt"
    began = time.perf_counter()
    with out.open("w") as fout, err.open("w") as ferr:
        proc = subprocess.Popen([sys.executable, "-c", _MEASURED, str(hwm), *map(str, argv)], stdout=fout,
                                stderr=ferr, preexec_fn=cap, env=env, cwd=ROOT)
        timer = threading.Timer(2 * REFUSAL_SECONDS, proc.kill)
        timer.start()
        try:
            proc.wait()
        finally:
            timer.cancel()
    seconds = time.perf_counter() - began
    peak = int(hwm.read_text()) / 1024 if hwm.exists() else math.inf       # none when killed
    return subprocess.CompletedProcess(argv, proc.returncode, out.read_text(), err.read_text()), seconds, peak


# -- 1. the polynomial arithmetic ----------------------------------------------------------------
@pytest.mark.parametrize("n,command", [(8, "check"), (16, "check"), (30, "check"), (16, "design")])
def test_a_chain_plant_with_8_scheduling_components_is_refused_within_seconds(tmp_path, n, command):
    """Before: 8 states ran past 150 s and 2 GB, 16 states past 6 GB in 70 s, 30 states exited 1 (MemoryError)."""
    problem = tmp_path / "chain.toml"
    problem.write_text(chain_problem(n, 8, g=1))
    extra = ("-o", tmp_path / "card.json") if command == "design" else ()
    res, seconds, peak = run_measured(tmp_path, command, problem, *extra)
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr and len(res.stderr.strip().splitlines()) == 1, res.stderr
    for part in ("plant.scheduling: the inverse system of delay r = ", "too large to compute exactly",
                 f"n = {n} states", "s = 8 scheduling component(s)", "a window of L = ", "monomials",
                 "fewer scheduling components", "a smaller plant"):
        assert part in res.stderr, (part, res.stderr)
    assert seconds < REFUSAL_SECONDS, seconds
    assert peak < REFUSAL_MB, peak
    assert not (tmp_path / "card.json").exists()


def test_a_chain_whose_windows_stay_small_designs_in_seconds(tmp_path):
    """30 states and 8 components feeding the states into x_n only: the unknown input's path and the
    outputs' rows stay free of theta, so the windows hold few monomials (the exact zeros are left out)
    and the design goes through; it ran past a minute and gigabytes before."""
    problem = tmp_path / "chain.toml"
    problem.write_text(chain_problem(30, 8, "last row", g=1))
    res, seconds, peak = run_measured(tmp_path, "design", problem, "-o", tmp_path / "card.json")
    assert res.returncode == 0, res.stderr
    assert "window           59 outputs (r = 30, K = 28)" in res.stdout and "verified" in res.stdout, res.stdout
    assert seconds < REFUSAL_SECONDS and peak < REFUSAL_MB, (seconds, peak)


def test_the_windows_are_the_products_of_the_plant_matrices():
    """O(theta_k:k+r) and M(theta_k:k+r), built each from the previous delay's with the lags shifted,
    evaluated at random theta values: the products of the plant's matrices at those values."""
    from test_deadbeat_functional import THETA_PLANT

    from uiofmu.families.deadbeat_functional import Windows
    from uiofmu.problem import problem_from_data

    data = copy.deepcopy(THETA_PLANT)
    data["plant"]["scheduling"][0].update(C=[[0.0, 0.5, 0.0]], E=[[0.0], [0.3], [0.0]], D=[[0.2]])
    data["plant"]["scheduling"].append({"A": [[0.0, 1.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.5]],
                                        "C": [[0.0, 0.0, -1.0]]})
    plant = problem_from_data(data).plant
    rng = np.random.default_rng(4)
    thetas = rng.normal(size=(4, plant.s))
    values = {(lag, i): thetas[lag, i] for lag in range(4) for i in range(plant.s)}
    at = [{name: plant.matrix(name, th) for name in "AECD"} for th in thetas]
    windows = Windows(plant)
    for r in range(4):
        windows.advance()
        blocks, prod = [], np.eye(plant.n)
        for lag in range(r + 1):
            blocks.append(at[lag]["C"] @ prod)
            prod = at[lag]["A"] @ prod
        np.testing.assert_allclose(windows.O(values), np.vstack(blocks), rtol=1e-13, atol=1e-13)
        p, q = plant.p, plant.q                            # M: D on the diagonal, C A...A E below it
        M = np.zeros((p * (r + 1), q * (r + 1)))
        for i in range(r + 1):
            for j in range(i + 1):
                block = at[j]["D"] if i == j else at[i]["C"]
                for lag in range(i - 1, j, -1):
                    block = block @ at[lag]["A"]
                M[p * i:p * (i + 1), q * j:q * (j + 1)] = block if i == j else block @ at[j]["E"]
        np.testing.assert_allclose(windows.M(values), M, rtol=1e-13, atol=1e-13)


def test_the_seed_003_examples_stay_far_inside_the_limits():
    """Both examples design, and their analysis and formula take under 1e-4 of each limit."""
    import uiofmu
    from uiofmu import polynomials
    from uiofmu.families import deadbeat_functional as dbf

    for name in ("seed003_example.toml", "seed003_needs_theta.toml"):
        problem = uiofmu.load_problem(EXAMPLES / name)
        with polynomials.work_limit() as analysis:
            inverse, _ = dbf.inverse_system(problem.plant, problem.options.max_delay)
        found = dbf.analyse(problem)
        with polynomials.work_limit() as formula:
            dbf.formula(problem.options.G, found.data["inverse"], found.data["K"], problem.plant.p)
        for work in (analysis, formula):
            assert 0 < work.used < 1e-4 * polynomials.MAX_WORK
            assert 0 < work.allocated < 1e-4 * polynomials.MAX_ALLOCATED
            assert work.terms <= 3 < 1e-3 * polynomials.max_terms((3, 3))
        assert inverse is not None and uiofmu.design(problem).data["certificate"]["verified"]


def test_a_product_is_refused_before_it_starts():
    """1000 x 1000 monomials of 16x16 coefficients would take 1e6 coefficient products (4e9 multiply-adds
    of work, seconds): refused at once, naming both sizes; the limit is cumulative inside a work_limit."""
    from uiofmu.polynomials import MAX_WORK, PAIR_OVERHEAD, PolyMatrix, TooLarge, work_limit

    rng = np.random.default_rng(0)
    big = PolyMatrix((16, 16), {((("a", i), 1),): rng.normal(size=(16, 16)) for i in range(1000)})
    other = PolyMatrix((16, 16), {((("b", i), 1),): rng.normal(size=(16, 16)) for i in range(1000)})
    began = time.perf_counter()
    with pytest.raises(TooLarge, match=r"matrices of 1000 and 1000 monomials \(16x16 and 16x16\) needs 1000000 "
                                       r"coefficient products") as info:
        big @ other
    assert time.perf_counter() - began < 0.5 and info.value.terms == 1000
    small = PolyMatrix((16, 16), {((("b", i), 1),): rng.normal(size=(16, 16)) for i in range(3)})
    cost = 3000 * (16 ** 3 + PAIR_OVERHEAD)                 # 1000 x 3 coefficient products of 16x16 matrices
    with work_limit(4 * cost) as work, pytest.raises(TooLarge, match="with the 12000 taken so far passes the "
                                                                   "work limit"):
        for _ in range(5):
            big @ small
    assert work.products == 12000 and work.used == 4 * cost
    with work_limit() as default:
        assert default.limit == MAX_WORK and default.used == 0


def test_a_matrix_past_its_bytes_is_refused_and_zero_products_are_left_out(monkeypatch):
    from uiofmu import polynomials
    from uiofmu.polynomials import PolyMatrix, TooLarge, max_terms, stack

    A = PolyMatrix.affine(np.eye(2), {("x", i): np.full((2, 2), i + 1.0) for i in range(4)})
    B = PolyMatrix.affine(np.eye(2), {("y", i): np.full((2, 2), -(i + 1.0)) for i in range(4)})
    values = {**{("x", i): 0.3 * i for i in range(4)}, **{("y", i): -0.7 + i for i in range(4)}}
    np.testing.assert_allclose((A @ B)(values), A(values) @ B(values), rtol=1e-14)
    N = PolyMatrix.affine(np.zeros((2, 2)), {("z", 0): np.array([[0.0, 1.0], [0.0, 0.0]])})
    assert list((N @ N).coeffs) == []                      # e_1 e_2' e_1 e_2' = 0: no monomial kept
    monkeypatch.setattr(polynomials, "MAX_BYTES", 10 * (8 * 4 + polynomials.TERM_BYTES))
    assert max_terms((2, 2)) == 10
    with pytest.raises(TooLarge, match=r"a 2x2 matrix reaches 11 monomials, more than the 10 that fit"):
        A @ B                                              # 25 monomials
    with pytest.raises(TooLarge, match=r"a 6x2 matrix reaches 9 monomials, more than the 8"):
        stack([A, B, A])                                   # refused before the blocks are allocated


def test_a_formula_past_the_limit_is_refused_naming_its_window(monkeypatch):
    """The design's stage (Proposition 4) is bounded too: with a limit below what THETA_PLANT's formula
    takes (13 coefficient products), its design is refused with r, K and the window."""
    from test_deadbeat_functional import THETA_PLANT

    from uiofmu import polynomials
    from uiofmu.families import deadbeat_functional as dbf
    from uiofmu.problem import problem_from_data
    from uiofmu.runtime.errors import ProblemError

    problem = problem_from_data(copy.deepcopy(THETA_PLANT))
    found = dbf.analyse(problem)
    monkeypatch.setattr(polynomials, "MAX_WORK", 5 * (27 + polynomials.PAIR_OVERHEAD))
    with pytest.raises(ProblemError, match=r"plant.scheduling: the window formula \(Proposition 4, r = 1, K = 2\) "
                                           r"is too large .* a window of L = 4 steps: .*passes the work limit"):
        dbf.design(problem, found)


def test_zero_polynomials_and_overflowing_windows_are_refused_not_crashed(tmp_path):
    """An entry of 1e300 exited 1 ("need at least one array to concatenate"): refused at parse; entries
    within range whose products over the window overflow are refused naming the window."""
    text = (EXAMPLES / "seed003_example.toml").read_text()
    big = tmp_path / "big.toml"
    big.write_text(text.replace("A = [[-4.0, 1.0, 0.0]", "A = [[-1e300, 1.0, 0.0]"))
    res = run_cli("check", big)
    assert res.code == 2 and "plant.A[0][0]: -1e+300 is out of range: entries up to 1e+100" in res.err, res.err
    part = tmp_path / "part.toml"
    part.write_text(text.replace("A = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]", "A = [[0.0, 0.0, 0.0], [1e101, 0.0, 0.0]"))
    res = run_cli("check", part)
    assert res.code == 2 and "plant.scheduling[0].A[1][0]: 1e+101 is out of range" in res.err, res.err
    over = tmp_path / "over.toml"                           # C A^3 E = 1e500 in a chain of 4 states
    over.write_text(chain_problem(4, 1).replace("C = [[1.0,", "C = [[1e100,")
                    .replace("[[0.0], [0.0], [0.0], [1.0]]", "[[0.0], [0.0], [0.0], [1e100]]")
                    .replace("A = [[0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]",
                             "A = [[0.0, 1e100, 0.0, 0.0], [0.0, 0.0, 1e100, 0.0], [0.0, 0.0, 0.0, 1e100]"))
    res = run_cli("check", over)
    assert res.code == 2 and "M(theta_k:k+" in res.err and ") overflows" in res.err, res.err
    assert "rescale the plant" in res.err, res.err


# -- 2. extreme numbers of the plant parsers --------------------------------------------------------
def _edited(tmp_path, example: str, old: str, new: str) -> Path:
    text = (EXAMPLES / example).read_text()
    assert old in text
    path = tmp_path / example
    path.write_text(text.replace(old, new, 1))
    return path


@pytest.mark.parametrize("value,message", [
    ("1e308", "plant.parameters.theta[0]: 1e+308 is out of range: entries up to 1e+100"),   # was ZeroDivisionError
    ("1e30", "plant.parameters: the plant's rate ||A|| + sum |D_i| max |theta| ||C|| + sum |D0| = 8.94e+30 1/s is "
             "out of range: at most 1e+09 1/s"),
])
def test_an_extreme_theta_is_refused_naming_the_key_and_the_range(tmp_path, value, message):
    problem = _edited(tmp_path, "seed001_example.toml", "theta = [1.0, 2.0, 0.5]", f"theta = [{value}, 2.0, 0.5]")
    for command in (("check", problem), ("plant", problem, "-o", tmp_path / "plant.fmu")):
        res = run_cli(*command)
        assert res.code == 2 and message in res.err, res.err
    assert not (tmp_path / "plant.fmu").exists()


@pytest.mark.parametrize("example,old", [("seed003_example.toml", "dt = 1.0"),           # LPV
                                         ("seed003_needs_theta.toml", "dt = 0.5"),      # LPV, theta an input
                                         ("seed002_setup2.toml", "dt = 1.0"),           # switched
                                         ("seed000_example1.toml", "dt = 0.1")])        # linear
@pytest.mark.parametrize("value", ["1e308", "5e-324", "1e10"])
def test_a_period_out_of_range_is_refused(tmp_path, example, old, value):
    """dt = 1e308 made the plant FMU's default experiment infinite (exit 1); 5e-324 overflows every t / dt."""
    problem = _edited(tmp_path, example, old, f"dt = {value}")
    res = run_cli("plant", problem, "-o", tmp_path / "plant.fmu")
    assert res.code == 2, res.err
    assert f"plant.dt: expected a period in [1e-09, 1e+09] s, found {float(value):g}" in res.err, res.err


def test_integer_keys_take_integers_in_range_only(tmp_path):
    """Integer keys of these parsers take integers (not bools, not floats) in their range, never wrapped."""
    G = "G = [[3.0, 2.0, 0.0]]"
    for old, new, message in [
        (G, f"{G}\nmax_delay = 1e300", "observer.max_delay: expected an integer from 0 to 12, found 1e+300"),
        (G, f"{G}\nmax_delay = true", "observer.max_delay: expected an integer from 0 to 12, found True"),
        (G, f"{G}\nmax_delay = 9223372036854775807", "observer.max_delay: expected an integer from 0 to 12"),
        ("steps = 12", "steps = 4294967296", "experiment.steps: expected an integer from 1 to 100000"),
        ("steps = 12", "steps = 12.0", "experiment.steps: expected an integer from 1 to 100000, found 12.0"),
    ]:
        res = run_cli("check", _edited(tmp_path, "seed003_example.toml", old, new))
        assert res.code == 2 and message in res.err, res.err
    rule = 'rule = "threshold"             # the paper\'s rule: mode 1 while x[1] < 6, else mode 2\nstate = 1'
    for new, message in [('rule = "input"\nmode0 = 1e300', "plant.switching.mode0: expected a mode from 1 to 2, "
                                                           "found 1e+300"),
                         ('rule = "input"\nmode0 = 9223372036854775807', "plant.switching.mode0: expected a mode"),
                         ('rule = "threshold"\nstate = 4294967297', "plant.switching.state: expected the 1-based")]:
        path = _edited(tmp_path, "seed002_setup2.toml", rule, new)
        if "mode0" in new:
            path.write_text(path.read_text().replace("threshold = 6.0\n", ""))
        res = run_cli("check", path)
        assert res.code == 2 and message in res.err, res.err


# -- 3. substeps per communication step --------------------------------------------------------------
def _parametric_runtime():
    from uiofmu.problem import load_problem
    from uiofmu.runtime.parametric_plant import ParametricPlantRuntime

    return ParametricPlantRuntime(load_problem(EXAMPLES / "seed001_example.toml").plant.to_data())


def test_the_parametric_plant_refuses_a_step_past_its_substeps_at_once():
    """h = 1e300 ran 4e303 RK4 substeps (never returned); now refused in microseconds, nothing changed."""
    from uiofmu.runtime.parametric_plant import MAX_SUBSTEPS
    from uiofmu.runtime.schedules import StepRejected

    rt = _parametric_runtime()
    rt.u[:] = 1.0
    assert rt.max_step == MAX_SUBSTEPS * rt.substep and 1.0 < rt.max_step < 60.0
    before = rt.x.copy()
    for h in (1e300, 1.01 * rt.max_step):
        began = time.perf_counter()
        with pytest.raises(StepRejected) as info:
            rt.step(h)
        assert time.perf_counter() - began < 0.1
        text = str(info.value)
        assert f"h = {h:.6g} s needs" in text and f"RK4 substeps of the plant (at most {rt.substep:.3g} s each), " \
            f"more than the {MAX_SUBSTEPS} a step may take" in text, text
        assert f"take steps of at most {rt.max_step:.6g} s" in text, text
        np.testing.assert_array_equal(rt.x, before)
    assert rt.substeps(rt.max_step) == MAX_SUBSTEPS and rt.substeps(0.5 * rt.substep) == 1
    rt.step(0.01)
    assert np.all(np.isfinite(rt.x)) and not np.array_equal(rt.x, before)


def test_a_linear_plant_whose_exponential_overflows_refuses_the_step():
    """A continuous linear plant (python runtime) given h = 1e300 went on with NaN states: refused now."""
    from uiofmu.runtime.plant_runtime import PlantRuntime
    from uiofmu.runtime.schedules import StepRejected

    rt = PlantRuntime({"time": "continuous", "A": [[0.5, 1.0], [0.0, -1.0]], "B": [[0.0], [1.0]],
                       "E": [[1.0], [0.0]], "C": [[1.0, 0.0]], "x0": [1.0, 0.0]})
    for h in (1e300, 1e4):
        with pytest.raises(StepRejected, match=re.escape(f"communication step h = {h!r} s: the plant's exact step "
                                                         "exp([A B E] h) overflows")):
            rt.step(h)
        np.testing.assert_array_equal(rt.x, [1.0, 0.0])
    rt.step(1.0)
    np.testing.assert_allclose(rt.x[0], math.exp(0.5), rtol=1e-12)


@pytest.mark.parametrize("backend", ["c", "python"])
def test_the_parametric_plant_fmu_answers_a_huge_step_with_a_refusal_not_a_hang(tmp_path, backend):
    """The real FMU built by ``uiofmu plant`` on each backend: h = 1e300 is answered at once with fmi2Discard
    and a log line naming h, the substep and the longest step; the next step goes through (equal to the
    runtime: bit for bit on the python backend, to 1e-12 on the C backend)."""
    from uiofmu.cosim.fmi import Fmu, FmuCallError

    fmu_path = tmp_path / "plant.fmu"
    res = run_cli("plant", EXAMPLES / "seed001_example.toml", "-o", fmu_path, "--backend", backend)
    assert res.code == 0, res.err
    rt = _parametric_runtime()
    with Fmu(fmu_path, "plant") as fmu:
        fmu.initialize(0.0)
        fmu.set("u", [1.0])
        start, began = len(fmu.messages), time.perf_counter()
        with pytest.raises(FmuCallError) as info:
            fmu.step(0.0, 1e300)
        assert info.value.status == 2 and time.perf_counter() - began < 2.0
        log = " ".join(fmu.messages[start:])
        assert "communication step h = 1e+300 s needs" in log and f"(at most {rt.substep:.3g} s each)" in log, log
        assert f"take steps of at most {rt.max_step:.6g} s" in log, log
        np.testing.assert_array_equal(fmu.get("x"), rt.x0)
        fmu.step(0.0, 0.01)
        rt.u[:] = 1.0
        rt.step(0.01)
        np.testing.assert_allclose(fmu.get("x"), rt.x, rtol=0.0 if backend == "python" else 1e-12, atol=0.0)
        assert not np.array_equal(fmu.get("x"), rt.x0)
