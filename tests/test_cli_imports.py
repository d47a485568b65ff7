"""The command line loads only what a command uses: ``uiofmu --help`` neither numpy nor the runtime, and
``check``, ``design``, ``build`` and ``verify`` no optimiser, plotting, FMU importer or scheduler they do not
use. Measured on ``sys.modules`` in a fresh interpreter, not on a clock."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from conftest import EXAMPLES, ROOT
from uiofmu.fmu.c_backend import c_compiler

#: What no command of the default path may load.
NEVER = ("cvxpy", "scipy.optimize", "matplotlib", "fmpy", "dask", "distributed", "tqdm", "mujoco", "pythonfmu")

#: Runs ``uiofmu.cli.main`` on argv (its first argument, JSON) and prints the exit code and the modules loaded.
PROBE = """\
import json, sys
from uiofmu.cli import main
try:
    code = main(json.loads(sys.argv[1]))
except SystemExit as exc:
    code = exc.code
print(json.dumps({"code": code, "modules": sorted(sys.modules)}), file=sys.stderr)
"""


def loaded(*argv, cwd) -> set:
    """The modules a fresh interpreter holds after ``uiofmu ARGV`` (which must exit 0)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-c", PROBE, json.dumps([str(a) for a in argv])], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)
    report = json.loads(proc.stderr.strip().splitlines()[-1])
    assert report["code"] == 0, proc.stderr
    return set(report["modules"])


def unwanted(modules: set, names) -> list:
    """Those of ``names`` (or their submodules) among ``modules``."""
    return sorted(m for m in modules if any(m == n or m.startswith(n + ".") for n in names))


def test_help_loads_no_numpy(tmp_path):
    modules = loaded("--help", cwd=tmp_path)
    assert "uiofmu.cli" in modules
    assert not unwanted(modules, ("numpy", "scipy", "uiofmu.runtime", "threadpoolctl", *NEVER))


def test_design_help_lists_the_families(tmp_path):
    """The design command's description, written only when shown, still names every family."""
    from uiofmu.runtime.registry import FAMILIES

    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-m", "uiofmu", "design", "--help"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    text = " ".join(proc.stdout.split())
    assert all(name in text for name in FAMILIES), text


def test_check_design_verify_build_load_only_what_they_use(tmp_path):
    example = EXAMPLES / "seed000_example1.toml"
    card = tmp_path / "card.json"
    check = loaded("check", example, cwd=tmp_path)
    design = loaded("design", example, "-o", card, cwd=tmp_path)
    verify = loaded("verify", card, cwd=tmp_path)
    for name, modules in (("check", check), ("design", design), ("verify", verify)):
        assert not unwanted(modules, NEVER), (name, unwanted(modules, NEVER))
    assert "clarabel" in design and "uiofmu.synthesis" in verify          # the probe saw the work done
    assert not unwanted(check | verify, ("clarabel",))                  # no solve in check and verify


@pytest.mark.skipif(c_compiler() is None, reason="no C compiler for the C backend")
def test_build_loads_no_fmu_importer(tmp_path):
    card = tmp_path / "card.json"
    loaded("design", EXAMPLES / "seed000_example1.toml", "-o", card, cwd=tmp_path)
    modules = loaded("build", card, "-o", tmp_path / "observer.fmu", "--backend", "c", cwd=tmp_path)
    assert (tmp_path / "observer.fmu").is_file()
    assert not unwanted(modules, NEVER), unwanted(modules, NEVER)
