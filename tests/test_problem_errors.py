"""Every malformed or inconsistent problem file exits 2 with one clear message, no traceback."""

from __future__ import annotations

import subprocess
import sys

import pytest

PLANT = """[plant]
time = "discrete"
dt = 0.1
A = [[0.0, 1.0], [-0.5, 0.99]]
B = [[0.0], [1.0]]
E = [[0.2], [0.0]]
C = [[1.0, 0.0]]
"""
OBSERVER = """[observer]
family = "lti-uio"
decay = "max"
"""
GOOD = PLANT + OBSERVER


def edit(old: str, new: str, base: str = GOOD) -> str:
    assert old in base, old
    return base.replace(old, new)


CASES = [
    # (id, file text, expected message fragment)
    ("not-toml", "[plant\nA = 1", "not valid TOML"),
    ("missing-plant", OBSERVER, "plant: required key is missing"),
    ("missing-observer", PLANT, "observer: required key is missing"),
    ("missing-A", edit("A = [[0.0, 1.0], [-0.5, 0.99]]\n", ""), "plant.A: required key is missing"),
    ("missing-C", edit("C = [[1.0, 0.0]]\n", ""), "plant.C: required key is missing"),
    ("missing-E", edit("E = [[0.2], [0.0]]\n", ""), "plant.E: required key is missing"),
    ("missing-time", edit('time = "discrete"\n', ""), "plant.time: required key is missing"),
    ("bad-time", edit('"discrete"', '"hybrid"'), "plant.time: expected one of 'continuous', 'discrete'"),
    ("missing-dt", edit("dt = 0.1\n", ""), "plant.dt: required for a discrete plant"),
    ("negative-dt", edit("dt = 0.1", "dt = -0.1"), "plant.dt: expected a value in (0, inf], found -0.1"),
    ("ragged-A", edit("[-0.5, 0.99]]", "[-0.5]]"), "plant.A: ragged matrix, row 1 has 1 entries but row 0 has 2"),
    ("non-square-A", edit("A = [[0.0, 1.0], [-0.5, 0.99]]", "A = [[0.0, 1.0]]"),
     "plant.A: expected a square non-empty matrix, found 1x2"),
    ("string-entry", edit("[-0.5, 0.99]", '[-0.5, "x"]'), "plant.A[1][1]: expected a number, found the string 'x'"),
    ("bool-entry", edit("[1.0, 0.0]]", "[true, 0.0]]"), "plant.C[0][0]: expected a number, found the boolean True"),
    ("nan-entry", edit("[[0.2], [0.0]]", "[[nan], [0.0]]"), "plant.E[0][0]: expected a finite number, found nan"),
    ("inf-entry", edit("[[0.0], [1.0]]", "[[inf], [1.0]]"), "plant.B[0][0]: expected a finite number, found inf"),
    ("flat-matrix", edit("C = [[1.0, 0.0]]", "C = [1.0, 0.0]"), "plant.C: expected a matrix as a list of rows"),
    ("C-columns", edit("C = [[1.0, 0.0]]", "C = [[1.0, 0.0, 0.0]]"), "plant.C: expected 2 columns, found 3"),
    ("E-rows", edit("E = [[0.2], [0.0]]", "E = [[0.2]]"), "plant.E: expected 2 rows, found 1"),
    ("B-rows", edit("B = [[0.0], [1.0]]", "B = [[0.0], [1.0], [2.0]]"), "plant.B: expected 2 rows, found 3"),
    ("x0-size", edit("C = [[1.0, 0.0]]", "C = [[1.0, 0.0]]\nx0 = [1.0]"), "plant.x0: expected 2 entries, found 1"),
    ("w-continuous", edit('time = "discrete"\ndt = 0.1', 'time = "continuous"\nw = [0.0, 0.0]'),
     "plant.w: the affine term is defined for discrete plants only"),
    ("dt-continuous", edit('"discrete"', '"continuous"'), "plant.dt: only discrete plants have a period"),
    ("unknown-plant-key", edit("C = [[1.0, 0.0]]", "C = [[1.0, 0.0]]\nH = [[0.0]]"), "plant.H: unknown key"),
    ("unknown-top-key", "solver = 'scs'\n" + GOOD, "solver: unknown key"),
    ("unknown-family", edit('"lti-uio"', '"kalman"'), "observer.family: unknown family 'kalman'"),
    ("missing-family", edit('family = "lti-uio"\n', ""), "observer.family: required key is missing"),
    ("unknown-observer-key", edit('decay = "max"', 'decay = "max"\ngain = 3'), "observer.gain: unknown key"),
    ("decay-range", edit('decay = "max"', "decay = 1.5"), "observer.decay: expected a value in (0, 1), found 1.5"),
    ("decay-word", edit('decay = "max"', 'decay = "fast"'), 'observer.decay: expected a number or "max"'),
    ("observer-dt-discrete", edit('decay = "max"', 'decay = "max"\ndt = 0.1'),
     "observer.dt: a discrete plant fixes the period"),
    ("continuous-needs-dt", edit('time = "discrete"\ndt = 0.1', 'time = "continuous"'),
     "observer.dt: required for a continuous plant"),
    ("switched-mode-shape", edit("C = [[1.0, 0.0]]", "C = [[1.0, 0.0]]\n[[plant.modes]]\nA = [[1.0]]"),
     "plant.modes[0].A: expected shape 2x2, found 1x1"),
    ("switched-needs-its-family", edit("C = [[1.0, 0.0]]", "C = [[1.0, 0.0]]\n[[plant.modes]]\n[[plant.modes]]\n"
                                       "A = [[0.0, 1.0], [-0.4, 0.9]]"), "plant.modes: a switched plant needs"),
    ("switched-mode-C", edit("C = [[1.0, 0.0]]", "C = [[1.0, 0.0]]\n[[plant.modes]]\nC = [[0.0, 1.0]]"),
     "plant.modes[0].C: a switched plant has one output matrix"),
    ("switched-continuous", edit('C = [[1.0, 0.0]]', 'C = [[1.0, 0.0]]\n[[plant.modes]]').replace(
        'time = "discrete"\ndt = 0.1', 'time = "continuous"'), "plant.time: a switched plant is discrete"),
    ("switched-threshold-state", edit("C = [[1.0, 0.0]]", "C = [[1.0, 0.0]]\n[[plant.modes]]\n[[plant.modes]]\n"
                                      "[plant.switching]\nrule = \"threshold\"\nstate = 3\nthreshold = 1.0"),
     "plant.switching.state: expected the 1-based index of a state, 1 to 2, found 3"),
    ("switched-probabilities", edit("C = [[1.0, 0.0]]", "C = [[1.0, 0.0]]\n[[plant.modes]]\n[[plant.modes]]\n"
                                    "[plant.switching]\nrule = \"random\"\nprobabilities = [0.5, 0.6]"),
     "plant.switching.probabilities: expected 2 non-negative numbers summing to 1"),
    ("signals-channels", GOOD + '[signals]\nu = [[{kind="constant", value=1.0}], []]\n',
     "signals.u: expected 1 channel(s), found 2"),
    ("signal-kind", GOOD + '[signals]\nd = [[{kind="chirp"}]]\n', "signals.d[0][0].kind: expected one of"),
    ("signal-field", GOOD + '[signals]\nd = [[{kind="sine", amplitude=1.0, frequency_hz=1.0, freq=2}]]\n',
     "signals.d[0][0]: unknown field(s) ['freq']"),
    ("signal-seed", GOOD + '[signals]\nd = [[{kind="random", seed=-1, std=1.0, hold=1.0}]]\n',
     "signals.d[0][0].seed: expected a non-negative integer"),
    # a typo of a required key names the key given and the one it is closest to
    ("typo-family", edit("family =", "famliy ="), "observer.famliy: unknown key; did you mean 'family'? "
     "observer.family: required key is missing"),
    ("typo-plant-table", edit("[plant]", "[plnt]"), "plnt: unknown key; did you mean 'plant'?"),
    ("typo-dt", edit("dt = 0.1", "dtt = 0.1"), "plant.dtt: unknown key; did you mean 'dt'? plant.dt: required for "
     "a discrete plant"),
    ("typo-optional", edit('decay = "max"', 'decay = "max"\nscalng = "none"'),
     "observer.scalng: unknown key; did you mean 'scaling'?"),
    ("typo-signal-field", GOOD + '[signals]\nd = [[{kind="random", seed=1, std=1.0, hodl=1.0}]]\n',
     "did you mean 'hold'?"),
    ("random-needs-hold", GOOD + '[signals]\nd = [[{kind="random", seed=1, std=1.0}]]\n',
     "signals.d[0][0].hold: required for kind 'random' (seconds between new draws"),
    ("name-type", 'name = 3\n' + GOOD, "name: expected a string, found int 3"),
    ("no-observer-exists", edit("C = [[1.0, 0.0]]", "C = [[0.0, 1.0]]"),
     "rank(CE) = 0 < rank(E) = 1: the unknown input cannot be decoupled"),
    ("decay-below-zero", edit('decay = "max"', "decay = 0.5"),
     "requested decay 0.5 <= largest fixed mode modulus 0.99"),
]


@pytest.mark.parametrize("text,fragment", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
@pytest.mark.parametrize("command", ["check", "design"])
def test_bad_problem_exits_2(tmp_path, cli, command, text, fragment):
    path = tmp_path / "problem.toml"
    path.write_text(text)
    res = cli(command, path, *(["-o", tmp_path / "d.json"] if command == "design" else []))
    assert res.code == 2, res
    assert fragment in res.err, res.err
    assert "Traceback" not in res.err
    assert len(res.err.strip().splitlines()) == 1, res.err
    assert not (tmp_path / "d.json").exists()


def test_table_is_large_enough():
    assert len(CASES) >= 20


def test_missing_file(cli, tmp_path):
    res = cli("check", tmp_path / "nope.toml")
    assert res.code == 2 and "no such problem file" in res.err


def test_console_script_exit_code(tmp_path):
    """The installed entry point (not only main()) exits 2 without a traceback."""
    path = tmp_path / "bad.toml"
    path.write_text(edit("[-0.5, 0.99]]", "[-0.5]]"))
    proc = subprocess.run([sys.executable, "-m", "uiofmu", "design", str(path)], capture_output=True, text=True)
    assert proc.returncode == 2
    assert "ragged matrix" in proc.stderr and "Traceback" not in proc.stderr


def test_nothing_is_evaluated(tmp_path, cli):
    """A string that looks like code stays a string (and is rejected as a non-number)."""
    marker = tmp_path / "evaluated"
    text = edit("[-0.5, 0.99]", f"[-0.5, \"__import__('pathlib').Path('{marker}').touch()\"]")
    path = tmp_path / "p.toml"
    path.write_text(text)
    res = cli("check", path)
    assert res.code == 2 and "expected a number, found the string" in res.err
    assert not marker.exists()


def test_a_family_not_available_in_this_version_is_named(monkeypatch):
    """Every known family is available today; a known name without a module is still refused by name."""
    import uiofmu.families as families
    from uiofmu.runtime.errors import ProblemError

    monkeypatch.setattr(families, "AVAILABLE", tuple(n for n in families.AVAILABLE if n != "switched"))
    with pytest.raises(ProblemError, match="observer.family: 'switched' is not available in this version"):
        families.available_family("switched")
