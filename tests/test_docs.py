"""The documentation holds: every public function, class and method of every public module of the
package has a docstring, and one with a numpydoc ``Parameters`` section names every argument
(python-control's rule; the modules are found by walking the package, not listed by hand); the README
is a front door of at most 250 lines whose examples run; every relative link of the README and of
``docs/`` resolves; and the site builds with ``mkdocs build --strict``."""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import json
import os
import pkgutil
import re
import shlex
import subprocess
import sys
from pathlib import Path

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


# ------------------------------------------------------------------ the README and the site

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
#: Files the contributing page names before they exist: the descriptors that registry entries name.
DESCRIPTORS = {"uiofmu/runtime/kernels.py", "uiofmu/plant_kinds.py"}


def markdown_files() -> list[Path]:
    """The README and every page of the site."""
    return [README, *sorted(DOCS.rglob("*.md"))]


def _prose(text: str) -> str:
    """``text`` without its fenced code blocks (a link or a heading in a code block is code)."""
    return re.sub(r"^```.*?^```", "", text, flags=re.M | re.S)


def github_slug(heading: str) -> str:
    """The anchor GitHub gives a heading: lower case, punctuation dropped, each space a hyphen."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def mkdocs_slug(heading: str) -> str:
    """The anchor Python-Markdown's ``toc`` gives a heading: runs of spaces and hyphens become one hyphen."""
    text = re.sub(r"[^\w\s-]", "", heading).strip().lower()
    return re.sub(r"[-\s]+", "-", text)


def anchors(path: Path) -> set[str]:
    """The anchors of the headings of a Markdown file, as the reader that shows it makes them."""
    slug = github_slug if path == README else mkdocs_slug
    return {slug(m.group(1)) for m in re.finditer(r"^#{1,6} +(.+?) *$", _prose(path.read_text(encoding="utf-8")),
                                                   flags=re.M)}


def relative_links(path: Path) -> list[str]:
    """Every link target of a Markdown file that is neither a URL nor a mail address."""
    targets = re.findall(r"\]\(([^)\s]+)\)", _prose(path.read_text(encoding="utf-8")))
    return [t for t in targets if not re.match(r"^[a-z][a-z0-9+.-]*:", t)]


@pytest.mark.parametrize("path", markdown_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(path):
    links = relative_links(path)
    broken = []
    for link in links:
        target, _, anchor = link.partition("#")
        file = (path.parent / target).resolve() if target else path
        if not file.exists():
            broken.append(f"{link}: no file {file}")
        elif anchor and file.suffix == ".md" and anchor not in anchors(file):
            broken.append(f"{link}: no heading with the anchor #{anchor} in {file.relative_to(ROOT)}")
    assert not broken, "\n".join(broken)


def test_the_link_checker_sees_a_broken_link_and_a_broken_anchor(tmp_path):
    page = DOCS / "commands.md"
    assert "api/index.md" in relative_links(page)
    assert "two-room-building" not in anchors(page) and "exit-codes" not in anchors(README)
    assert mkdocs_slug("Communication steps (`cosim --steps SPEC`)") == "communication-steps-cosim-steps-spec"
    assert github_slug("Communication steps (`cosim --steps SPEC`)") == "communication-steps-cosim---steps-spec"


def test_the_readme_is_a_front_door():
    """At most 250 lines; the two commands and the true system requirements in its first lines."""
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 250, f"README.md has {len(lines)} lines"
    head = "\n".join(lines[:25])
    for needed in ("make demo", "make test", "Python ≥ 3.11", "gcc"):
        assert needed in head, f"{needed!r} is not in the README's first 25 lines"


def test_every_command_and_family_has_its_page():
    """The command line's commands and the registry's families are found in the code, not listed here."""
    from uiofmu.cli import build_parser
    from uiofmu.runtime.registry import AVAILABLE

    parser = build_parser()
    commands = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction").choices
    reference = (DOCS / "commands.md").read_text(encoding="utf-8")
    missing = [c for c in commands if f"`uiofmu {c} " not in reference]
    assert not missing, f"docs/commands.md has no row for {missing}"
    nav = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    for family in AVAILABLE:
        page = DOCS / "families" / f"{family}.md"
        assert page.exists(), f"no page {page.relative_to(ROOT)}"
        assert f"families/{family}.md" in nav, f"mkdocs.yml's nav lacks families/{family}.md"
        text = page.read_text(encoding="utf-8")
        assert "does not reproduce" in text and re.search(r"\(\d+\)", text), \
            f"{page.name} needs the paper's equation numbers and what does not reproduce"


def test_the_contributing_page_names_files_that_exist():
    """Every path of the checklists exists, but for the descriptors (and the ``<name>`` of a new file)."""
    text = (DOCS / "contributing.md").read_text(encoding="utf-8")
    paths = set(re.findall(r"`((?:uiofmu|tests|examples|docs)/[\w/.<>-]+)`", text))
    assert len(paths) > 30 and DESCRIPTORS <= paths
    missing = sorted(p for p in paths - DESCRIPTORS if "<" not in p and not (ROOT / p).exists())
    assert not missing, f"docs/contributing.md names files that do not exist: {missing}"
    for heading in ("A family", "A plant kind", "A kernel", "An importer test", "A CLI command"):
        assert f"### {heading}\n" in text, heading


def test_the_readme_python_example_runs(tmp_path):
    """The README's Python example, run as it is written, from a folder of its own."""
    block = re.search(r"^```python\n(.*?)^```", README.read_text(encoding="utf-8"), flags=re.M | re.S).group(1)
    (tmp_path / "plants").symlink_to(ROOT / "plants")
    proc = subprocess.run([sys.executable, "-c", block], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["bound_respected"] is True and (tmp_path / "observer.fmu").is_file()


@pytest.mark.slow
def test_the_readme_tour_runs(tmp_path):
    """Each command of the README's tour, in its order, exits 0 (the campaign on one worker)."""
    text = README.read_text(encoding="utf-8")
    tour = text[text.index("## A short tour"):text.index("## Documentation")]
    commands = [line for block in re.findall(r"^```sh\n(.*?)^```", tour, flags=re.M | re.S)
                for line in block.splitlines() if line.strip()]
    assert [c.split()[1] for c in commands] == ["check", "design", "build", "plant", "validate", "cosim", "campaign"]
    for name in ("plants", "examples"):
        (tmp_path / name).symlink_to(ROOT / name)
    for command in commands:
        argv = [sys.executable, "-m", "uiofmu", *shlex.split(command)[1:]]
        if argv[3] == "campaign":
            argv += ["--workers", "1"]
        proc = subprocess.run(argv, cwd=tmp_path, capture_output=True, text=True, timeout=900)
        assert proc.returncode == 0, f"{command}: exit {proc.returncode}\n{proc.stderr[-3000:]}"
    assert (tmp_path / "out" / "run" / "report.png").is_file()
    assert (tmp_path / "out" / "campaign" / "campaign.csv").is_file()


def test_the_site_builds_strictly(tmp_path):
    """``mkdocs build --strict``, as ``make docs`` runs it: a broken link, anchor or docstring fails it."""
    if importlib.util.find_spec("mkdocs") is None or importlib.util.find_spec("mkdocstrings_handlers") is None:
        pytest.skip("the docs extra is not installed (pip install -e '.[docs]'; make test installs it)")
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                          cwd=ROOT, capture_output=True, text=True, timeout=600,
                          env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert (tmp_path / "site" / "api" / "cosim.html").read_text(encoding="utf-8").count("cosimulate") > 1
