"""One descriptor per runtime kernel and per plant kind: no module outside the descriptors decides by a kernel's
or a plant kind's name, and what the registry's entries name exists.

The walk reads every module of the package: a comparison (``==``, ``!=``, ``in``, ``not in``) with a kernel or
plant-kind name as a literal, a lookup of such a literal in a module's table (an upper-case name, or ``.get``
of anything), or a literal default of ``.get`` is a decision by name, and only the descriptor modules may
make one.
"""

from __future__ import annotations

import ast

import pytest

from conftest import ROOT
from uiofmu import plant_kinds
from uiofmu.cosim.kernels import COSIM_KERNELS
from uiofmu.cosim.validate import PLANT_DRIVERS
from uiofmu.fmu.c_backend import C_KERNELS, PLANT_KERNELS
from uiofmu.runtime import kernels, plant_kinds as fmu_kinds
from uiofmu.runtime.registry import FAMILIES

PACKAGE = ROOT / "uiofmu"
#: The modules that decide by name: the descriptors (and the registry, which names kernels and kinds).
DESCRIPTORS = {"uiofmu/runtime/kernels.py", "uiofmu/runtime/plant_kinds.py", "uiofmu/plant_kinds.py",
               "uiofmu/cosim/kernels.py", "uiofmu/runtime/registry.py"}
NAMES = frozenset(kernels.KERNELS) | frozenset(fmu_kinds.PLANT_KINDS) | frozenset(plant_kinds.PLANT_KINDS)


def _names_in(node) -> set:
    """The kernel and plant-kind names a literal (a string, or a tuple, list or set of them) holds."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return {node.value} & NAMES
    if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
        return set().union(*(_names_in(e) for e in node.elts)) if node.elts else set()
    return set()


def _table(node) -> bool:
    """Whether ``node`` names a module's table (an upper-case name or attribute)."""
    name = node.id if isinstance(node, ast.Name) else node.attr if isinstance(node, ast.Attribute) else ""
    return name.isupper()


def decisions_by_name(source: str) -> list:
    """``(line, what)`` of every decision by a kernel's or plant kind's name in a module's text."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Compare):
            if any(isinstance(op, (ast.Eq, ast.NotEq, ast.In, ast.NotIn)) for op in node.ops):
                for side in (node.left, *node.comparators):
                    found += [(node.lineno, f"compares with {name!r}") for name in sorted(_names_in(side))]
        elif isinstance(node, ast.Subscript) and _table(node.value):
            found += [(node.lineno, f"looks up {name!r}") for name in sorted(_names_in(node.slice))]
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "get":
            for arg in node.args:
                found += [(node.lineno, f"gets {name!r}") for name in sorted(_names_in(arg))]
    return found


def test_no_module_outside_the_descriptors_decides_by_a_kernel_or_plant_kind_name():
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        if rel not in DESCRIPTORS:
            found += [f"{rel}:{line}: {what}" for line, what in decisions_by_name(path.read_text(encoding="utf-8"))]
    assert not found, "decisions by name outside the descriptors:\n" + "\n".join(found)


@pytest.mark.parametrize("source,count", [
    ('if card.kernel == "window": pass', 1),
    ('x = kind in ("linear", "lpv")', 2),
    ('k = PLANT_KERNELS["linear"]', 1),
    ('k = data.get("kernel", "affine")', 1),
    ('k = metrics["window"]', 0),                      # a result's key, not a table of kernels
    ('k = {"affine": 1}', 0),                          # a table is declared, nothing is decided
    ('if card.stepper.estimates_x: pass', 0),
])
def test_the_walk_finds_decisions_by_name(source, count):
    assert len(decisions_by_name(source)) == count


@pytest.mark.parametrize("entry", FAMILIES.values(), ids=list(FAMILIES))
def test_registry_entries_name_a_kernel_and_plant_kinds_that_exist(entry):
    assert entry.kernel in kernels.KERNELS
    assert entry.plants and set(entry.plants) <= set(plant_kinds.PLANT_KINDS)


def test_every_kernel_has_its_cosimulation_side_and_a_c_kernel_or_a_reason():
    assert set(COSIM_KERNELS) == set(kernels.KERNELS)
    for kernel in kernels.KERNELS.values():
        assert (kernel.c_kernel in C_KERNELS) != bool(kernel.python_only), kernel.name
        assert set(kernel.schedules) <= set(kernels.SCHEDULES), kernel.name
    stepped = [s for k in kernels.KERNELS.values() for s in k.schedules]
    assert sorted(stepped) == sorted(kernels.SCHEDULES)          # each schedule kind has exactly one kernel


def test_every_plant_kind_has_a_c_kernel_or_a_reason():
    for kind in fmu_kinds.PLANT_KINDS.values():
        if kind.c_kernel is None:
            assert kind.python_only, kind.name
        elif kind.variant is None:
            assert kind.c_kernel in PLANT_KERNELS, kind.name
        else:
            assert any(key.startswith(f"{kind.c_kernel}-") for key in PLANT_KERNELS), kind.name
    assert set(plant_kinds.PLANT_KINDS) <= set(fmu_kinds.PLANT_KINDS)
    assert set(PLANT_DRIVERS) == {k.name for k in fmu_kinds.PLANT_KINDS.values() if k.fmu_kind == fmu_kinds.PLANT_FMU}
