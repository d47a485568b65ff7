"""The C kernels' ports come from uiofmu/runtime/ports.py alone.

(a) A copy of the package whose ports.py renames a port (the plant's ``y``, the observer's ``r``:
their keys stay), reorders a kernel's ports (``KERNEL_PORTS``: the C ids change), reorders a
declaration (the plant's outputs: the value references change) and changes a causality (the
observer's ``xhat0`` becomes an input) builds C FMUs whose ``modelDescription.xml`` and generated C
tables (``kernel_<name>_ports.h``, the variable table of ``design_data.c``) agree value reference by
value reference, and which run: instantiated (the plumbing checks the table against the kernel),
stepped through the new names and equal to the reference runtimes.
(b) The causality a kernel takes from its design (a switched plant's ``mode``) is the one each FMU
declares, and a header that says otherwise is refused at fmi2Instantiate.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description

from cfmu import NEEDS_CC
from conftest import EXAMPLES, ROOT
from uiofmu.cosim.fmi import Fmu
from uiofmu.fmu import c_backend
from uiofmu.fmu.export import build_plant
from uiofmu.problem import load_problem, problem_from_data
from uiofmu.runtime.observer import Runtime
from uiofmu.runtime.plant_runtime import PlantRuntime
from test_c_switched import SETUP2

pytestmark = NEEDS_CC

#: The edits of ports.py: (old text, new text), each old text once in the file.
EDITS = [
    # the plant's y is named ym (its key, the code's name for it, stays y)
    ('PortSpec("y", 0, "output", "measured outputs C x"),',
     'PortSpec("ym", 0, "output", "measured outputs C x", key="y"),'),
    # the plant kernel's x first: UIOFMU_PLANT_X is port id 0
    ('''        PortSpec("x0", 0, "parameter", "initial state"),
        PortSpec("u", 0, "input", "known inputs (held over the step)"),''',
     '''        PortSpec("x", 0, "output", "true state (for validation)"),
        PortSpec("x0", 0, "parameter", "initial state"),
        PortSpec("u", 0, "input", "known inputs (held over the step)"),'''),
    ('''        PortSpec("ym", 0, "output", "measured outputs C x", key="y"),
        PortSpec("x", 0, "output", "true state (for validation)"),''',
     '''        PortSpec("ym", 0, "output", "measured outputs C x", key="y"),'''),
    # a plant declares x before y
    ('ports += [port("y", p), port("x", n)]', 'ports += [port("x", n), port("y", p)]'),
    # the observer's r is named residual, xhat is the affine kernel's port 0, xhat0 is an input
    ('PortSpec("r", 0, "output", "output residual y - C xhat"),',
     'PortSpec("residual", 0, "output", "output residual y - C xhat", key="r"),'),
    ('''        PortSpec("u", 0, "input", "known inputs at the current communication point"),
        PortSpec("xhat", 0, "output", "state estimate at the current communication point"),''',
     '''        PortSpec("u", 0, "input", "known inputs at the current communication point"),'''),
    ('''        PortSpec("xhat0", 0, "parameter", "initial state estimate at the start time"),''',
     '''        PortSpec("xhat", 0, "output", "state estimate at the current communication point"),
        PortSpec("xhat0", 0, "input", "initial state estimate at the start time"),'''),
]

#: What the edited copy builds (run with the copy first on the path).
BUILD = """
import json, sys
from pathlib import Path
import uiofmu
from uiofmu.fmu.export import build_observer, build_plant
from uiofmu.problem import load_problem
from uiofmu.runtime.card import card_from_data

assert Path(uiofmu.__file__).resolve().is_relative_to(Path.cwd().resolve()), uiofmu.__file__
out, card_file, problem = Path(sys.argv[1]), sys.argv[2], sys.argv[3]
data = json.loads(Path(card_file).read_text())
data.pop("ports")
data["ports"] = [port.to_data() for port in card_from_data(data).ports]     # what `uiofmu design` writes
build_observer(card_from_data(data), out / "observer.fmu", backend="c")
build_plant(load_problem(problem).plant, "plant", out / "plant.fmu", backend="c")
"""

_ROW = re.compile(r"^\s*\{(UIOFMU_\w+), (\d+), (UIOFMU_\w+), (UIOFMU_\w+)\},$", re.M)
_CAUSALITY = {"UIOFMU_PARAMETER": "parameter", "UIOFMU_INPUT": "input", "UIOFMU_OUTPUT": "output"}
_TYPE = {"UIOFMU_REAL": "Real", "UIOFMU_INTEGER": "Integer"}


def c_tables(path: Path, kernel: c_backend.CKernel) -> dict:
    """What the C of the FMU at ``path`` says: the port ids in order (``ids``), by id the names,
    causalities and types (``names``, ``causalities``, ``types``), and per value reference
    ``(name[i], causality, type)`` (``variables``, read from the variable table through the ids)."""
    with zipfile.ZipFile(path) as z:
        header = z.read(f"sources/{kernel.ports_header}").decode()
        design = z.read("sources/design_data.c").decode()
    prefix = kernel.prefix
    ids = re.search(r"enum \{(.*?)\};", header, re.S).group(1).replace(",", " ").split()
    assert ids[-1] == f"{prefix}_PORTS"
    ids = ids[:-1]

    def initialiser(what: str) -> list:
        return [v.strip() for v in re.search(rf"#define {prefix}_PORT_{what} \{{(.*)\}}", header).group(1).split(",")]

    names = [json.loads(v) for v in initialiser("NAMES")]
    causalities = [_CAUSALITY[v] for v in initialiser("CAUSALITIES")]
    types = [_TYPE[v] for v in initialiser("TYPES")]
    assert len(names) == len(causalities) == len(types) == len(ids)
    variables = []
    for enum, index, causality, kind in _ROW.findall(design.split("UiofmuVariable variables[]")[1]):
        port = ids.index(enum)
        assert (_CAUSALITY[causality], _TYPE[kind]) == (causalities[port], types[port]), enum
        variables.append((f"{names[port]}[{int(index) + 1}]", _CAUSALITY[causality], _TYPE[kind]))
    return {"ids": ids, "names": names, "causalities": causalities, "types": types, "variables": variables}


def described(path: Path) -> list:
    """``(name, causality, type)`` of each variable of the FMU's modelDescription.xml, by value reference."""
    variables = read_model_description(str(path)).modelVariables
    assert [v.valueReference for v in variables] == list(range(len(variables)))
    return [(v.name, v.causality, v.type) for v in variables]


@pytest.fixture(scope="module")
def edited(example1_card, tmp_path_factory):
    """The C observer and plant FMUs of seed 000 Example 1 built by a copy of the package with :data:`EDITS`."""
    root = tmp_path_factory.mktemp("edited")
    shutil.copytree(ROOT / "uiofmu", root / "uiofmu", ignore=shutil.ignore_patterns("__pycache__"))
    ports = root / "uiofmu" / "runtime" / "ports.py"
    text = ports.read_text()
    for old, new in EDITS:
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    ports.write_text(text)
    out = root / "fmus"
    out.mkdir()
    proc = subprocess.run([sys.executable, "-c", BUILD, str(out), str(example1_card[1]),
                           str(EXAMPLES / "seed000_example1.toml")], cwd=root, capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(root)}, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out


def test_the_edited_plant_fmu_and_its_c_table_agree(edited):
    path = edited / "plant.fmu"
    c = c_tables(path, c_backend.PLANT_KERNELS["linear"])
    assert c["ids"][:2] == ["UIOFMU_PLANT_X", "UIOFMU_PLANT_X0"]            # the kernel's order, as edited
    assert c["names"][c["ids"].index("UIOFMU_PLANT_Y")] == "ym"
    md = described(path)
    assert c["variables"] == md
    names = [name for name, _, _ in md]
    assert "ym[1]" in names and "y[1]" not in names
    assert names.index("x[1]") < names.index("ym[1]")                       # the declaration's order, as edited


def test_the_edited_plant_fmu_runs_through_its_new_names(edited):
    plant = load_problem(EXAMPLES / "seed000_example1.toml").plant
    rt = PlantRuntime(plant.to_data())
    rng = np.random.default_rng(5)
    with Fmu(edited / "plant.fmu", "plant") as fmu:
        fmu.initialize(0.0)
        for k in range(20):
            u, d = rng.normal(size=plant.m), rng.normal(size=plant.q)
            fmu.set("u", u)
            fmu.set("d", d)
            rt.u[:], rt.d[:] = u, d
            np.testing.assert_allclose(fmu.get("ym"), rt.y(), rtol=1e-13, atol=1e-13)
            np.testing.assert_allclose(fmu.get("x"), rt.x, rtol=1e-13, atol=1e-13)
            fmu.step(k * plant.dt, plant.dt)
            rt.step(plant.dt)


def test_the_edited_observer_fmu_and_its_c_table_agree(edited):
    path = edited / "observer.fmu"
    c = c_tables(path, c_backend.C_KERNELS["affine"])
    assert c["ids"][:2] == ["UIOFMU_AFFINE_XHAT", "UIOFMU_AFFINE_XHAT0"]
    assert c["causalities"][1] == "input" and c["names"][c["ids"].index("UIOFMU_AFFINE_R")] == "residual"
    md = described(path)
    assert c["variables"] == md
    assert ("xhat0[1]", "input", "Real") in md and ("residual[1]", "output", "Real") in md
    assert not any(name.startswith("r[") for name, _, _ in md)


def test_the_edited_observer_fmu_runs_through_its_new_names(edited, example1_card):
    card = example1_card[0]
    rt = Runtime(card)
    rng = np.random.default_rng(6)
    xhat0 = rng.normal(size=card.dims["n"])
    rt.xhat0 = xhat0.copy()
    rt.reset()
    h = card.schedule["dt"]
    with Fmu(edited / "observer.fmu", "observer") as fmu:
        fmu.initialize(0.0, {"xhat0": xhat0})
        for k in range(20):
            y, u = rng.normal(size=card.dims["p"]), rng.normal(size=card.dims["m"])
            fmu.set("y", y)
            fmu.set("u", u)
            rt.y[:], rt.u[:] = y, u
            np.testing.assert_allclose(fmu.get("xhat"), rt.xhat(), rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(fmu.get("residual"), rt.residual(), rtol=1e-12, atol=1e-12)
            fmu.step(k * h, h)
            rt.step(h)


# -- (b) a causality the kernel takes from its design ---------------------------------------

def _switched(rule: dict):
    """Setup 2 of Millerioux and Daafouz (two modes) with the switching ``rule``."""
    return problem_from_data({**SETUP2, "plant": {**SETUP2["plant"], "switching": rule}}).plant


@pytest.mark.parametrize("rule,causality", [({"rule": "input", "mode0": 1}, "input"),
                                            ({"rule": "threshold", "state": 1, "threshold": 6.0}, "output")])
def test_a_switched_plants_mode_has_the_causality_of_its_rule(tmp_path, rule, causality):
    path = build_plant(_switched(rule), "sw", tmp_path / "sw.fmu", backend="c")
    c = c_tables(path, c_backend.PLANT_KERNELS[f"switched-{rule['rule']}"])
    assert c["causalities"][c["ids"].index("UIOFMU_PLANT_MODE")] == causality
    assert c["variables"] == described(path)
    with Fmu(path, "sw") as fmu:
        fmu.initialize(0.0)
        fmu.step(0.0, 1.0)
    # the same FMU with the other causality in its header: refused at fmi2Instantiate
    other = {"input": "UIOFMU_OUTPUT", "output": "UIOFMU_INPUT"}[causality]
    unzip = tmp_path / "unzip"
    with zipfile.ZipFile(path) as z:
        z.extractall(unzip)
    kernel = c_backend.PLANT_KERNELS["linear"]
    header = unzip / "sources" / kernel.ports_header
    text = header.read_text()
    line = next(ln for ln in text.splitlines() if ln.startswith("#define UIOFMU_PLANT_PORT_CAUSALITIES"))
    values = line.split("{")[1].rstrip("}").split(", ")
    values[c["ids"].index("UIOFMU_PLANT_MODE")] = other
    header.write_text(text.replace(line, f"#define UIOFMU_PLANT_PORT_CAUSALITIES {{{', '.join(values)}}}"))
    ident = next((unzip / "binaries" / "linux64").iterdir()).stem
    c_backend.compile_binary(unzip / "sources", ident, unzip / "binaries" / "linux64",
                             sources=c_backend.kernel_sources(kernel))
    broken = tmp_path / "broken.fmu"
    shutil.make_archive(str(broken.with_suffix("")), "zip", unzip)
    broken.with_suffix(".zip").rename(broken)
    with pytest.raises(c_backend.FmuError) as info:
        Fmu(broken, "sw")
    assert "port mode is declared with causality" in str(info.value), str(info.value)
