"""``uiofmu/runtime/`` is what ships inside FMUs: it imports nothing but the standard library,
numpy and (in the MuJoCo plant runtime) mujoco, it is copied whole, and plant runtimes do not
depend on the observer runtime."""

from __future__ import annotations

import ast
import sys
import zipfile
from pathlib import Path

import pytest

from uiofmu.fmu.export import RUNTIME, build_plant, runtime_files, runtime_package
from uiofmu.plant import Plant

MODULES = sorted(p.stem for p in RUNTIME.glob("*.py"))
THIRD_PARTY = {"numpy"}
ONLY_IN = {"mujoco": {"mujoco_runtime"}}


def _imports(name: str) -> tuple[set, set]:
    """(absolute top-level modules, sibling modules) that module ``name`` imports anywhere."""
    tree = ast.parse((RUNTIME / f"{name}.py").read_text())
    absolute, siblings = set(), set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            absolute |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                absolute.add(node.module.split(".")[0])
            elif node.level == 1:
                siblings |= {node.module.split(".")[0]} if node.module else {a.name for a in node.names}
            else:
                siblings.add("..")                        # reaches out of the package: refused below
    return absolute, siblings


@pytest.mark.parametrize("name", MODULES)
def test_a_runtime_module_imports_only_numpy_and_the_standard_library(name):
    absolute, siblings = _imports(name)
    foreign = {m for m in absolute if m not in sys.stdlib_module_names and m != "__future__"
               and m not in THIRD_PARTY and name not in ONLY_IN.get(m, ())}
    assert not foreign, f"uiofmu/runtime/{name}.py imports {sorted(foreign)}"
    assert siblings <= set(MODULES), f"uiofmu/runtime/{name}.py imports {sorted(siblings - set(MODULES))}"


def _closure(name: str) -> set:
    seen, todo = set(), [name]
    while todo:
        m = todo.pop()
        if m not in seen:
            seen.add(m)
            todo += [s for s in _imports(m)[1] if s in MODULES]
    return seen


@pytest.mark.parametrize("plant", ["plant_runtime", "mujoco_runtime"])
def test_plant_runtimes_do_not_import_the_observer_runtime(plant):
    assert "observer" not in _closure(plant) and "card" not in _closure(plant)


def test_the_runtime_is_copied_whole_into_a_python_fmu(tmp_path):
    fmu = build_plant(Plant.create([[0.5]], [[1.0]], [[1.0]], time="discrete", dt=0.1), "one", tmp_path / "p.fmu",
                      backend="python")
    with zipfile.ZipFile(fmu) as z:
        shipped = {Path(n).name for n in z.namelist() if f"/{runtime_package()}/" in f"/{n}" and n.endswith(".py")}
    assert shipped == {p.name for p in runtime_files()} == {f"{m}.py" for m in MODULES}
