"""Shared fixtures: paths of the examples, an in-process command runner, the example cards designed once per
session and their observer FMUs built once per session (``observer_fmus``)."""

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

#: The DC motor whose load torque is the unknown input, with the sampled-data observer on 0.01..0.05 s at
#: alpha 0.9: certified with gains of millions (test_design_robustness.py, test_cosim_noise.py).
DC_MOTOR_LOAD_TORQUE = """
name = "dc-motor-load-torque"
[plant]
time = "continuous"
A = [[0.0, 1.0, 0.0], [0.0, -10.0, 1.0], [0.0, -0.02, -2.0]]
B = [[0.0], [0.0], [2.0]]
E = [[0.0], [-100.0], [0.0]]
C = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
[observer]
family = "sampled-data"
intervals = [0.01, 0.02, 0.03, 0.04, 0.05]
alpha = 0.9
"""

#: The delayed UIO of seed 001 as the paper gives it (Fouka et al.), for test_delayed_fmus.py.
DELAYED_EXAMPLE = """\
name = "fouka-example"
[plant]
time = "continuous"
A = [[-30.0, 12.0, -20.0], [-50.0, -13.0, 0.0], [10.0, 2.0, -14.0]]
B = [[1.5], [0.0], [2.0]]
C = [[1.0, 0.0, 0.0], [0.0, 1.0, -2.0]]
[plant.parameters]
theta = [1.0, 2.0, 0.5]
[[plant.parameters.Dy]]
output = 1
D = [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]]
[[plant.parameters.Dy]]
output = 2
D = [[1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
[observer]
family = "delayed-uio"
delays = [0.5]
decay = 1.0
premise = { signals = "u", count = 6, samples = 300, seed = 1 }
[signals]
u = [[{kind = "sine", amplitude = 20.0, frequency_hz = 0.5},
      {kind = "sine", amplitude = 10.0, frequency_hz = 1.3},
      {kind = "sine", amplitude = 5.0, frequency_hz = 3.1}]]
"""
#: The example with a delay of 0.1 s, valid from it (premise.start = tau: the start-up transient designed in), so that
#: runs of 0.3 s have valid estimates.
DELAYED_SHORT = DELAYED_EXAMPLE.replace("delays = [0.5]", "delays = [0.1]").replace("seed = 1 }",
                                                                                  "seed = 1, start = 0.1 }")


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


def built_with_both_backends(problem, folder):
    """``uiofmu design`` of the problem file into ``folder/card.json``, its plant FMU ``folder/plant.fmu`` and its
    observer built by each backend (``folder/obs_c.fmu``, ``folder/obs_python.fmu``); returns ``folder``."""
    assert run_cli("design", problem, "--out", folder / "card.json").code == 0
    assert run_cli("plant", problem, "-o", folder / "plant.fmu").code == 0
    for backend in ("c", "python"):
        res = run_cli("build", folder / "card.json", "-o", folder / f"obs_{backend}.fmu", "--backend", backend)
        assert res.code == 0, res.err
    return folder


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


@pytest.fixture(scope="session")
def setup2_card(tmp_path_factory):
    """The designed switched card of seed 002, setup 2 (two modes, dead-beat)."""
    return designed(EXAMPLES / "seed002_setup2.toml", tmp_path_factory, "setup2")


@pytest.fixture(scope="session")
def needs_theta_card(tmp_path_factory):
    """The designed dead-beat functional card of seed 003 whose formula takes theta as an input."""
    return designed(EXAMPLES / "seed003_needs_theta.toml", tmp_path_factory, "needs_theta")


@pytest.fixture(scope="session")
def delayed_card(tmp_path_factory):
    """The designed delayed UIO of seed 001 with a delay of 0.1 s (:data:`DELAYED_SHORT`: valid estimates
    within 0.3 s), designed once per session."""
    problem = tmp_path_factory.mktemp("delayed") / "problem.toml"
    problem.write_text(DELAYED_SHORT, encoding="utf-8")
    return designed(problem, tmp_path_factory, "delayed_short")


@pytest.fixture(scope="session")
def observer_fmus(request, tmp_path_factory):
    """``observer_fmus(name, backend)``: ``(card, observer FMU path)`` of the session card fixture ``name``
    (``example1_card``, say) on ``backend``, built once per session; tests that edit an FMU copy it first."""
    from uiofmu.fmu.export import build_observer

    made: dict = {}

    def get(name: str, backend: str):
        if (name, backend) not in made:
            card = request.getfixturevalue(name)[0]
            path = tmp_path_factory.mktemp("observers") / f"{name}-{backend}.fmu"
            made[name, backend] = card, build_observer(card, path, backend=backend)
        return made[name, backend]

    return get
