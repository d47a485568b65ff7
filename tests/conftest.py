"""Shared fixtures: paths of the examples and an in-process command runner."""

from __future__ import annotations

import io
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"


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


@pytest.fixture(scope="session")
def example1_card(example1_path, tmp_path_factory):
    """The designed card of seed 000 Example 1 (designed once per session)."""
    import uiofmu

    card = uiofmu.design(uiofmu.load_problem(example1_path))
    path = tmp_path_factory.mktemp("cards") / "example1.json"
    card.write(path)
    return card, path


@pytest.fixture(scope="session")
def building_path() -> Path:
    return ROOT / "plants" / "two_room_building" / "problem.toml"


@pytest.fixture(scope="session")
def building_card(building_path, tmp_path_factory):
    """The designed card of the two-room building (alpha = "max"), designed once per session."""
    import uiofmu

    card = uiofmu.design(uiofmu.load_problem(building_path))
    path = tmp_path_factory.mktemp("cards") / "building.json"
    card.write(path)
    return card, path


@pytest.fixture(scope="session")
def ltv_card(tmp_path_factory):
    """The designed LTV card of seed 000 Example 1 (paper parameters)."""
    import uiofmu

    card = uiofmu.design(uiofmu.load_problem(EXAMPLES / "seed000_example1_ltv.toml"))
    path = tmp_path_factory.mktemp("cards") / "ltv.json"
    card.write(path)
    return card, path
