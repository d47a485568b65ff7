"""The Python API documents what it takes: every public function, class and method of every public
module of the package has a docstring, and one with a numpydoc ``Parameters`` section names every
argument (python-control's rule). The modules are found by walking the package, not listed by hand."""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import re

import pytest

import uiofmu


def public_modules() -> list[str]:
    """Every module of the package whose dotted name has no part starting with ``_``."""
    names = ["uiofmu"] + [info.name for info in pkgutil.walk_packages(uiofmu.__path__, "uiofmu.")]
    return sorted(n for n in names if not any(part.startswith("_") for part in n.split(".")))


def _own_doc(cls) -> str | None:
    """The class's own docstring: not a base class's, nor the signature a dataclass makes up."""
    doc = cls.__dict__.get("__doc__")
    if not doc or (hasattr(cls, "__dataclass_fields__") and doc.startswith(f"{cls.__name__}(")):
        return None
    return inspect.cleandoc(doc)


def _routine(obj):
    """The function behind ``obj`` (a function, a static or class method, a cached function), or None."""
    if isinstance(obj, (staticmethod, classmethod)):
        obj = obj.__func__
    obj = inspect.unwrap(obj) if callable(obj) else obj
    return obj if inspect.isfunction(obj) else None


def public_objects():
    """``(dotted name, object, kind)`` for every public function, class and method defined in a public module."""
    for name in public_modules():
        module = importlib.import_module(name)
        for attr, obj in vars(module).items():
            if attr.startswith("_") or getattr(obj, "__module__", None) != name:
                continue
            if inspect.isclass(obj):
                yield f"{name}.{attr}", obj, "class"
                for meth, member in vars(obj).items():
                    fn = _routine(member)
                    if fn is not None and not meth.startswith("_"):
                        yield f"{name}.{attr}.{meth}", fn, "function"
            elif _routine(obj) is not None:
                yield f"{name}.{attr}", _routine(obj), "function"


CASES = list(public_objects())


def test_the_walk_finds_the_modules():
    modules = public_modules()
    for name in ("uiofmu.problem", "uiofmu.cosim.validate", "uiofmu.conic", "uiofmu.families"):
        assert name in modules
    assert len(CASES) > 100


@pytest.mark.parametrize("name,obj,kind", CASES, ids=[c[0] for c in CASES])
def test_documented(name, obj, kind):
    doc = _own_doc(obj) if kind == "class" else inspect.getdoc(obj)
    assert doc, f"{name} has no docstring"
    if kind == "class" or "Parameters\n----------" not in doc:
        return
    section = doc.split("Parameters\n----------", 1)[1]
    section = re.split(r"\n(Returns|Raises|Examples|Yields|Notes)\n-+", section)[0]
    documented = set()
    for line in section.splitlines():
        m = re.match(r"^(\**\w+(?:, \**\w+)*) :", line) or re.match(r"^(\**\w+(?:, \**\w+)*)$", line)
        if m:
            documented.update(p.strip().lstrip("*") for p in m.group(1).split(","))
    params = [p for p in inspect.signature(obj).parameters if p not in ("self", "cls")]
    missing = [p for p in params if p not in documented]
    assert not missing, f"{name}: parameters {missing} are not in its Parameters section"
