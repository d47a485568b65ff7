"""The Python API documents what it takes: every public function has a docstring, and one with a
numpydoc ``Parameters`` section names every argument (python-control's rule)."""

from __future__ import annotations

import importlib
import inspect
import re

import pytest

MODULES = ["uiofmu.problem", "uiofmu.plant", "uiofmu.synthesis", "uiofmu.card", "uiofmu.runtime", "uiofmu.export",
           "uiofmu.export_c", "uiofmu.cosim", "uiofmu.steps", "uiofmu.validate", "uiofmu.mujoco_plant",
           "uiofmu.lmi", "uiofmu.conic", "uiofmu.structure", "uiofmu.matrices", "uiofmu.metrics", "uiofmu.fmi",
           "uiofmu.pythonfmu_guard", "uiofmu.files", "uiofmu.text", "uiofmu.state"]


def public_functions():
    for name in MODULES:
        module = importlib.import_module(name)
        for attr, obj in vars(module).items():
            if attr.startswith("_") or getattr(obj, "__module__", None) != name:
                continue
            if inspect.isfunction(obj):
                yield f"{name}.{attr}", obj
            elif inspect.isclass(obj):
                for meth, fn in vars(obj).items():
                    if inspect.isfunction(fn) and not meth.startswith("_"):
                        yield f"{name}.{attr}.{meth}", fn


CASES = list(public_functions())


@pytest.mark.parametrize("name,fn", CASES, ids=[c[0] for c in CASES])
def test_documented(name, fn):
    doc = inspect.getdoc(fn)
    assert doc, f"{name} has no docstring"
    if "Parameters\n----------" not in doc:
        return
    section = doc.split("Parameters\n----------", 1)[1]
    section = re.split(r"\n(Returns|Raises|Examples|Yields|Notes)\n-+", section)[0]
    documented = set()
    for line in section.splitlines():
        m = re.match(r"^(\**\w+(?:, \**\w+)*) :", line) or re.match(r"^(\**\w+(?:, \**\w+)*)$", line)
        if m:
            documented.update(p.strip().lstrip("*") for p in m.group(1).split(","))
    params = [p for p in inspect.signature(fn).parameters if p not in ("self", "cls")]
    missing = [p for p in params if p not in documented]
    assert not missing, f"{name}: parameters {missing} are not in its Parameters section"
