"""Shared fixtures: paths of the examples and an in-process command runner."""

from __future__ import annotations

import io
import os
import shutil
import sys
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"

# The tools the test extra installs as wheels (cmake, ruff) live next to the interpreter: put them on
# PATH as an activated environment does, so `.venv/bin/python -m pytest` finds them too.
os.environ["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), os.environ.get("PATH", "")])

#: Tests marked with a tool no PyPI wheel provides, and that tool: without it they skip, saying why.
SYSTEM_TOOLS = {"valgrind": "valgrind"}


def pytest_collection_modifyitems(config, items):
    """Skip the tests of a system tool that is not installed (valgrind: ``apt-get install valgrind``),
    with the reason; every other tool of the suite comes from the test extra."""
    for mark, tool in SYSTEM_TOOLS.items():
        if shutil.which(tool) is None:
            skip = pytest.mark.skip(reason=f"{tool} is not installed (apt-get install {tool}); ASan/UBSan tests "
                                           "cover the same C code")
            for item in items:
                if mark in item.keywords:
                    item.add_marker(skip)


@dataclass
class Result:
    code: int
    out: str
    err: str


def run_cli(*argv: str) -> Result:
    """Run ``uiofmu ARGV`` in this process and capture its exit code and streams."""
    from uiofmu.cli import main

    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        try:
            code = main([str(a) for a in argv])
        except SystemExit as exc:  # argparse usage errors
            code = exc.code
    return Result(code, out.getvalue(), err.getvalue())


@pytest.fixture
def cli():
    return run_cli


@pytest.fixture(scope="session")
def example1_path() -> Path:
    return EXAMPLES / "seed000_example1.toml"


def designed(path, tmp_path_factory, stem: str):
    """Design the problem at ``path`` and write its card; returns (card, card path)."""
    import uiofmu

    card = uiofmu.design(uiofmu.load_problem(path))
    out = tmp_path_factory.mktemp("cards") / f"{stem}.json"
    card.write(out)
    return card, out


@pytest.fixture(scope="session")
def example1_card(example1_path, tmp_path_factory):
    """The designed card of seed 000 Example 1 (designed once per session)."""
    return designed(example1_path, tmp_path_factory, "example1")


@pytest.fixture(scope="session")
def building_path() -> Path:
    return ROOT / "plants" / "two_room_building" / "problem.toml"


@pytest.fixture(scope="session")
def building_card(building_path, tmp_path_factory):
    """The designed card of the two-room building (alpha = "max"), designed once per session."""
    return designed(building_path, tmp_path_factory, "building")


@pytest.fixture(scope="session")
def ltv_card(tmp_path_factory):
    """The designed LTV card of seed 000 Example 1 (paper parameters)."""
    return designed(EXAMPLES / "seed000_example1_ltv.toml", tmp_path_factory, "ltv")
