"""The contributing page's checklist for a family holds: a family is its module and one registry entry.

A copy of the package gains a family ``scratch-uio``, a copy of ``uiofmu/families/lti_uio.py`` edited
only where its name is, and one entry in ``uiofmu/runtime/registry.py``, nothing else. Through the
copy's command line, a small problem of that family is checked, designed, verified, built on both
backends, its plant packed, both observer FMUs validated and co-simulated against it: every command
exits 0, the card is a verified ``scratch-uio`` card and the FMUs run. The files the copy differs in
are exactly those steps 1 and 2 of the checklist ("A family" in ``docs/contributing.md``) name.
"""

from __future__ import annotations

import filecmp
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cfmu import NEEDS_CC
from conftest import ROOT
from uiofmu.runtime.registry import KNOWN

pytestmark = NEEDS_CC

#: The scratch family: its name and the name of its module.
NAME, MODULE = "scratch-uio", "scratch_uio"

#: Its registry entry, placed before ltv-auid's (the line of the original it goes before, then the entry).
BEFORE = '    Entry("ltv-auid", '
ENTRY = f'    Entry("{NAME}", "a renamed copy of lti-uio", "{MODULE}", certifies="as lti-uio"),\n'

#: A small problem for it: seed 000 Example 1 (examples/seed000_example1.toml) at a fixed decay (its invariant
#: zero is at 0.99), observed by the scratch family.
PROBLEM = (ROOT / "examples" / "seed000_example1.toml").read_text(encoding="utf-8").replace(
    'family = "lti-uio"', f'family = "{NAME}"').replace('decay = "max"', "decay = 0.995")

#: The commands, each an argv of ``uiofmu``, run in this order in one process of the copy.
COMMANDS = {
    "check": ["check", "problem.toml"],
    "design": ["design", "problem.toml", "-o", "card.json"],
    "verify": ["verify", "card.json"],
    "build c": ["build", "card.json", "-o", "observer_c.fmu", "--backend", "c"],
    "build python": ["build", "card.json", "-o", "observer_python.fmu", "--backend", "python"],
    "plant": ["plant", "problem.toml", "-o", "plant.fmu", "--backend", "c"],
    "validate c": ["validate", "observer_c.fmu"],
    "validate python": ["validate", "observer_python.fmu"],
    "cosim c": ["cosim", "--plant", "plant.fmu", "--observer", "observer_c.fmu", "--steps", "fixed:0.1",
                "--t-end", "3", "--out", "run_c", "--no-report"],
    "cosim python": ["cosim", "--plant", "plant.fmu", "--observer", "observer_python.fmu", "--steps", "fixed:0.1",
                     "--t-end", "3", "--out", "run_python", "--no-report"],
}

#: What runs in the copy: each command through the copy's command line, its exit code and output as JSON.
DRIVER = """
import io, json, sys
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path
import uiofmu
from uiofmu.cli import main

package, commands = Path(sys.argv[1]), json.loads(sys.argv[2])
assert Path(uiofmu.__file__).resolve().is_relative_to(package.resolve()), uiofmu.__file__
results = {}
for name, argv in commands.items():
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as exc:
            code = exc.code
    results[name] = {"code": code, "out": out.getvalue(), "err": err.getvalue()}
print(json.dumps(results))
"""


def checklist_files(section: str, steps: tuple) -> set:
    """The file each of ``steps`` of the checklist ``section`` of ``docs/contributing.md`` names first,
    with ``<module>`` read as the scratch family's module."""
    text = (ROOT / "docs" / "contributing.md").read_text()
    body = text.split(f"### {section}\n", 1)[1].split("\n### ", 1)[0]
    files = set()
    for step in steps:
        item = re.search(rf"^{step}\. `([^`]+)`", body, re.M)
        assert item, f"step {step} of {section!r} names no file"
        files.add(item.group(1).replace("<module>", MODULE))
    return files


def differing_files(copy: Path, original: Path) -> set:
    """The files, relative to the parent of ``original``, that ``copy`` adds, removes or changes."""
    found = set()

    def walk(cmp: filecmp.dircmp, rel: Path):
        for name in cmp.left_only + cmp.right_only + cmp.diff_files + cmp.funny_files:
            found.add((rel / name).as_posix())
        for name, sub in cmp.subdirs.items():
            walk(sub, rel / name)

    walk(filecmp.dircmp(copy, original, ignore=["__pycache__"]), Path(original.name))
    # dircmp compares by size and time first: compare every common file's bytes as well
    for path in original.rglob("*"):
        if path.is_file() and "__pycache__" not in path.parts:
            other = copy / path.relative_to(original)
            if other.is_file() and other.read_bytes() != path.read_bytes():
                found.add(path.relative_to(original.parent).as_posix())
    return found


@pytest.fixture(scope="module")
def scratch(tmp_path_factory):
    """The copy of the package with the scratch family, the results of :data:`COMMANDS` and the folder they
    ran in."""
    root = tmp_path_factory.mktemp("scratch")
    package = root / "uiofmu"
    shutil.copytree(ROOT / "uiofmu", package, ignore=shutil.ignore_patterns("__pycache__"))
    lti = (package / "families" / "lti_uio.py").read_text()
    assert lti.count('\nNAME = "lti-uio"\n') == 1
    (package / "families" / f"{MODULE}.py").write_text(lti.replace('\nNAME = "lti-uio"\n', f'\nNAME = "{NAME}"\n'))
    registry = package / "runtime" / "registry.py"
    text = registry.read_text()
    assert text.count(BEFORE) == 1
    registry.write_text(text.replace(BEFORE, ENTRY + BEFORE))

    work = root / "work"
    work.mkdir()
    (work / "problem.toml").write_text(PROBLEM)
    proc = subprocess.run([sys.executable, "-c", DRIVER, str(package), json.dumps(COMMANDS)], cwd=work,
                          capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(root)}, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return {"package": package, "results": json.loads(proc.stdout.splitlines()[-1]), "work": work}


def test_the_original_package_does_not_know_the_scratch_family():
    assert NAME not in KNOWN


@pytest.mark.parametrize("command", list(COMMANDS))
def test_every_command_exits_0(scratch, command):
    result = scratch["results"][command]
    assert result["code"] == 0, result["err"][-2000:]
    assert result["err"] == ""


def test_check_and_design_speak_of_the_scratch_family(scratch):
    results = scratch["results"]
    assert f"existence of a {NAME} observer" in results["check"]["out"]
    assert "=> an observer exists" in results["check"]["out"]
    assert f"{NAME} design written to card.json" in results["design"]["out"]
    assert f"every claim of the {NAME} card re-checks" in results["verify"]["out"]
    for backend in ("c", "python"):
        assert f"{NAME} observer FMU ({backend} backend)" in results[f"build {backend}"]["out"]


def test_the_card_is_a_verified_scratch_card(scratch):
    card = json.loads((scratch["work"] / "card.json").read_text())
    assert card["family"] == NAME
    assert card["existence"]["family"] == NAME
    assert card["certificate"]["verified"] is True
    assert card["decay_bound"] == pytest.approx(0.995)
    assert card["kernel"] == "affine"


@pytest.mark.parametrize("backend", ["c", "python"])
def test_the_fmus_run(scratch, backend):
    results = scratch["results"]
    assert "validate_fmu         no problem" in results[f"validate {backend}"]["out"]
    assert "against reference    200 random steps" in results[f"validate {backend}"]["out"]
    metrics = json.loads((scratch["work"] / f"run_{backend}" / "metrics.json").read_text())
    assert metrics["steps"] == 30
    assert metrics["bound_respected"] is True
    assert metrics["final_error_norm"] < metrics["initial_error_norm"]


def results_table(path: Path) -> tuple[list, np.ndarray]:
    """The column names and the rows of a ``results.csv`` (an empty cell, as the last row's ``h``, is NaN)."""
    return path.read_text().splitlines()[0].split(","), np.genfromtxt(path, delimiter=",", skip_header=1, ndmin=2)


def test_both_backends_give_the_same_run(scratch):
    (names, c), (names_python, python) = (results_table(scratch["work"] / f"run_{backend}" / "results.csv")
                                          for backend in ("c", "python"))
    assert names == names_python and "xhat[1]" in names and "dhat[1]" in names
    assert c.shape == (31, len(names))
    np.testing.assert_allclose(c, python, rtol=1e-12, atol=1e-12)


def test_the_copy_differs_only_in_the_files_the_checklist_names(scratch):
    named = checklist_files("A family", (1, 2))
    assert named == {f"uiofmu/families/{MODULE}.py", "uiofmu/runtime/registry.py"}
    assert differing_files(scratch["package"], ROOT / "uiofmu") == named
