"""Cards, problem files, step files and tables are data from someone else.

The two code-injection vectors found in earlier versions (a card name that closes a C comment,
a family that rewrites the pythonfmu slave's class line), hostile text in every field of a card,
outputs that must survive a failed command, and reads that must stay bounded.
"""

from __future__ import annotations

import ast
import json
import os
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

import uiofmu
from uiofmu.runtime.card import card_from_data
from uiofmu.runtime.errors import CardError
from uiofmu.fmu.export import model_identifier
from uiofmu.fmu.c_backend import design_source, model_description
from uiofmu.runtime.text import c_string, fill_template, identifier, py_string

ROOT = Path(__file__).resolve().parents[1]

#: Text that has broken code generators: quotes, comment closers, newlines, backslashes, printf and
#: template placeholders, the old placeholder names, NUL and control characters, a very long string.
HOSTILE = ['x"; system("touch PWNED"); //', "x **//", "*/ int evil; /*", "a\nb", "back\\slash\\", "%s%n%x",
           "${runtime}$class_name$$", "FMU_DESCRIPTION", "UIOFMU_RT", "nul\x00byte", "bell\x07\x1b[31m",
           "'''\"\"\"", "??/ trigraph", "é—中文", "x" * 100_000]

C_PAYLOAD = ('x **//\n__attribute__((constructor)) static void f(void) { FILE *f = fopen("MARKER", "w"); '
             'if (f) fclose(f); }\n/*')
PY_FAMILY = "A(__import__('os').system('touch MARKER') or Fmi2Slave):#"


def _card(example1_card) -> dict:
    return json.loads(example1_card[0].to_json())


def _write(tmp_path, data, name="card.json") -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(data))
    return path


def _uiofmu(*args, cwd) -> subprocess.CompletedProcess:
    """The real command line in a subprocess (an FMU that crashes cannot take pytest with it)."""
    return subprocess.run([sys.executable, "-m", "uiofmu", *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=300)


def _one_line_error(proc, command):
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"uiofmu {command}: error: "), proc.stderr
    assert "Traceback" not in proc.stderr


# -- code generation ---------------------------------------------------------------------------

def test_c_comment_closer_in_the_name_never_reaches_the_compiler(example1_card, tmp_path):
    """The name of the C injection reproducer builds, and the FMU runs without the payload."""
    data = _card(example1_card)
    data["name"] = C_PAYLOAD.replace("\n", " ")
    card = card_from_data(data)
    source = design_source(card, "0" * 8, model_identifier(card.name, "observer"))
    assert '"MARKER"' not in source and "__attribute__" not in source and "**//" not in source
    card_path = _write(tmp_path, data)
    proc = _uiofmu("build", card_path, "-o", "o.fmu", "--backend", "c", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    with zipfile.ZipFile(tmp_path / "o.fmu") as z:
        sources = b"".join(z.read(n) for n in z.namelist() if n.startswith("sources/design_data"))
    assert b'"MARKER"' not in sources and b"__attribute__" not in sources
    proc = _uiofmu("validate", "o.fmu", "--steps", "5", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert not (tmp_path / "MARKER").exists()


def test_a_name_with_newlines_is_refused(example1_card, tmp_path):
    data = _card(example1_card)
    data["name"] = C_PAYLOAD
    _one_line_error(_uiofmu("build", _write(tmp_path, data), "-o", "o.fmu", cwd=tmp_path), "build")
    assert not (tmp_path / "o.fmu").exists() and not (tmp_path / "MARKER").exists()


def test_family_injection_into_the_pythonfmu_slave_is_refused(example1_card, tmp_path):
    data = _card(example1_card)
    data["name"], data["family"] = "FMU_DESCRIPTION", PY_FAMILY
    proc = _uiofmu("build", _write(tmp_path, data), "-o", "o.fmu", "--backend", "python", cwd=tmp_path)
    _one_line_error(proc, "build")
    assert "family" in proc.stderr
    assert not (tmp_path / "MARKER").exists() and not (tmp_path / "o.fmu").exists()


def test_placeholder_names_build_and_run_on_the_python_backend(example1_card, tmp_path):
    """``FMU_DESCRIPTION`` and template fields in the name are text: the slave builds, loads and runs."""
    data = _card(example1_card)
    data["name"] = "FMU_DESCRIPTION ${class_name} UIOFMU_RT UiofmuModel \"'''"
    proc = _uiofmu("build", _write(tmp_path, data), "-o", "o.fmu", "--backend", "python", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    with zipfile.ZipFile(tmp_path / "o.fmu") as z:
        md = z.read("modelDescription.xml").decode()
    assert 'modelName="FMU_DESCRIPTION_class_name_UIOFMU_RT_UiofmuModel_observer"' in md
    proc = _uiofmu("validate", "o.fmu", "--steps", "5", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr


def test_a_problem_named_like_a_placeholder_gives_a_plant_fmu(tmp_path):
    text = (ROOT / "plants" / "two_room_building" / "problem.toml").read_text()
    (tmp_path / "p.toml").write_text(re.sub(r'(?m)^name = .*$', 'name = "FMU_DESCRIPTION"', text))
    proc = _uiofmu("plant", "p.toml", "-o", "plant.fmu", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert _uiofmu("validate", "plant.fmu", "--steps", "5", cwd=tmp_path).returncode == 0


@pytest.mark.parametrize("text", HOSTILE, ids=range(len(HOSTILE)))
def test_literals_and_identifiers_escape_everything(text):
    ident = identifier(text, "observer")
    assert ident.isascii() and ident.replace("_", "a").isalnum() and ident[0].isalpha() and len(ident) <= 64
    lit = c_string(text)
    inner = lit[1:-1]
    assert lit[0] == lit[-1] == '"' and all(0x20 <= ord(ch) < 0x7F for ch in lit)
    assert '"' not in inner.replace("\\042", "") and "?" not in inner and "\n" not in lit
    # every backslash starts a three-digit octal escape, so the literal decodes to the UTF-8 bytes
    decoded = bytes(int(inner[i + 1:i + 4], 8) if inner[i] == "\\" else ord(inner[i])
                    for i in _literal_starts(inner))
    assert decoded == text.encode("utf-8")
    code = fill_template("x = ${description}\n", {}, {"description": py_string(text)})
    scope: dict = {}
    exec(compile(code, "<generated>", "exec"), scope)          # the literal is a literal: it evaluates to the text
    assert scope["x"] == text


def _literal_starts(inner: str):
    i = 0
    while i < len(inner):
        yield i
        i += 4 if inner[i] == "\\" else 1


def test_a_template_field_must_be_an_identifier():
    with pytest.raises(ValueError, match="not an identifier"):
        fill_template("class ${name}: pass", {"name": "A(object):#"}, {})


def _fields(data, path=()):
    """Every key path of a card document: one entry per matrix (not every number), the first three
    entries of the long per-LMI tables of the certificate."""
    if isinstance(data, dict):
        for key, value in list(data.items())[:3 if len(path) >= 2 else None]:
            yield path + (key,)
            if not (path and path[0] == "matrices"):
                yield from _fields(value, path + (key,))
    elif isinstance(data, list) and data and path[:1] != ("matrices",):
        yield path + (0,)
        yield from _fields(data[0], path + (0,))


def _replace(data, path, value):
    target = data
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value


@pytest.mark.slow
def test_hostile_text_in_every_field_never_reaches_generated_code(building_card):
    """Each field of a card replaced by each hostile string: refused by the schema, or accepted as
    data that never appears in the generated C, XML or Python source."""
    base = json.loads(building_card[0].to_json())
    template = (ROOT / "uiofmu" / "fmu" / "templates" / "pythonfmu_slave.py.tmpl").read_text()
    benign = _code_shape(fill_template(template, {"runtime": "rt", "class_name": "Model"},
                                       {"description": py_string("benign")}))
    tried = refused = 0
    shapes: dict = {}
    for path in _fields(base):
        for text in HOSTILE[:-1] + [HOSTILE[-1][:2000]]:
            data = json.loads(json.dumps(base))
            _replace(data, path, text)
            tried += 1
            try:
                card = card_from_data(data)
            except CardError:
                refused += 1
                continue
            ident = model_identifier(card.name, "observer")
            c_source = design_source(card, "1" * 8, ident)
            assert text not in c_source or re.fullmatch(r"\w+", text, re.ASCII), (path, text)
            if (card.family, card.name) not in shapes:
                slave = fill_template(template, {"runtime": "rt", "class_name": ident},
                                      {"description": py_string(f"{card.family} of {card.name}")})
                shapes[card.family, card.name] = _code_shape(slave)
            assert shapes[card.family, card.name] == benign, (path, text)
            model_description(card, "1" * 8, ident, ["observer.c"])     # ElementTree escapes the text
    assert tried > 500 and refused > 100


def _code_shape(source: str) -> str:
    """The syntax tree of a generated module with its string constants and class names blanked:
    equal for every card when card text can only ever be data."""
    tree = ast.parse(source)
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            node.value = ""
        elif isinstance(node, ast.ClassDef):
            node.name = "Model"
    return ast.dump(tree)


def test_control_characters_in_the_name_are_refused(example1_card, tmp_path):
    data = _card(example1_card)
    data["name"] = "ok\x01"
    with pytest.raises(CardError, match="U\\+0001 at position 2"):
        card_from_data(data)


# -- card schema -------------------------------------------------------------------------------

@pytest.mark.parametrize("mutate,fragment", [
    (lambda d: d["certificate"].update(verified="no"), "certificate.verified: expected true or false"),
    (lambda d: d.update(version=True), "version True is not supported"),
    (lambda d: d["matrices"]["N"][0].__setitem__(0, "0.5"), "matrices.N[0][0]: expected a number, found the string"),
    (lambda d: d.update(name=7), "name: expected a string, found int 7"),
    (lambda d: d.update(dims=[2, 1, 1, 1, 2]), "dims: expected an object, found a list"),
    (lambda d: d.update(matrices=[[1.0]]), "matrices: expected an object, found a list"),
    (lambda d: d["schedule"].update(step_policy="sometimes"), "schedule.step_policy: expected one of 'error'"),
    (lambda d: d["schedule"].update(dt="0.1"), "schedule.dt: expected a number, found the string"),
    (lambda d: d["schedule"].update(dt=-0.1), "schedule.dt: expected a value in (0, inf], found -0.1"),
    (lambda d: d["initial"].pop("xhat0"), "initial.xhat0: required"),
    (lambda d: d["initial"].update(xhat0=[0.0]), "initial.xhat0: expected 2 entries, found 1"),
    (lambda d: d.update(family="psychic"), "family: expected one of 'lti-uio'"),
    (lambda d: d.update(family="delayed-uio"), "family 'delayed-uio' is not its problem's observer.family 'lti-uio'"),
    (lambda d: d.update(decay_bound=1.00009), "decay_bound = 1.00009: a bound of 1 or more certifies no convergence"),
    (lambda d: d["dims"].update(n=10 ** 400), "dims.n: expected an integer in [1, 1000]"),
    (lambda d: d["matrices"]["c"].__setitem__(0, 10 ** 400), "too large for a float"),
    (lambda d: d.update(bound="a\x1b[2Jb"), "bound: character U+001B at position 1"),
])
def test_card_schema_refuses(example1_card, mutate, fragment):
    data = _card(example1_card)
    mutate(data)
    with pytest.raises(CardError) as info:
        card_from_data(data)
    assert fragment in str(info.value), str(info.value)


@pytest.mark.parametrize("mutate,fragment", [
    (lambda s: s.pop("intervals"), "schedule.intervals: required"),
    (lambda s: s["intervals"].__setitem__(3, -600.0), "schedule.intervals[3]: expected a value in (0, inf]"),
    (lambda s: s.update(h_prev0=123.0), "schedule.h_prev0 = 123.0 s is not one of the design intervals"),
    (lambda s: s["intervals"].__setitem__(1, 600.0), "are not distinct steps"),
    (lambda s: s.update(alpha=50), "schedule.alpha: not a key of a interval schedule"),
])
def test_interval_schedule_schema(building_card, mutate, fragment):
    data = json.loads(building_card[0].to_json())
    mutate(data["schedule"])
    with pytest.raises(CardError) as info:
        card_from_data(data)
    assert fragment in str(info.value), str(info.value)


def test_geometric_alpha_out_of_range(ltv_card):
    data = json.loads(ltv_card[0].to_json())
    data["schedule"]["alpha"] = 50
    with pytest.raises(CardError, match=r"schedule.alpha: expected a value in \(0, 1\), found 50"):
        card_from_data(data)


@pytest.mark.parametrize("text,fragment", [
    ('{"format": "uiofmu.design", "dt": NaN}', "NaN is not a number a design card may hold"),
    ('{"format": "uiofmu.design", "dt": Infinity}', "Infinity is not a number"),
    ("[" * 100_000 + "]" * 100_000, "nested too deep"),
    ('{"a":' * 70 + "1" + "}" * 70, "nested more than 64 levels deep"),
])
def test_card_json_limits(cli, tmp_path, text, fragment):
    path = tmp_path / "c.json"
    path.write_text(text)
    res = cli("build", path, "-o", tmp_path / "o.fmu")
    assert res.code == 2 and fragment in res.err and len(res.err.splitlines()) == 1, res


def test_a_forged_verified_flag_does_not_pass_the_recheck(example1_card, tmp_path, cli):
    """``verified: true`` is a claim; build re-checks the matrices and refuses a broken certificate."""
    data = _card(example1_card)
    data["matrices"]["N"] = [[1.5, 0.0], [0.0, 1.5]]
    data["eigenvalues_N"], data["spectral_radius_N"] = [[1.5, 0.0], [1.5, 0.0]], 1.5      # its figures to match
    res = cli("build", _write(tmp_path, data), "-o", tmp_path / "o.fmu")
    assert res.code == 2 and "certificate does not hold at the stored matrices" in res.err, res
    assert not (tmp_path / "o.fmu").exists()


# -- outputs -----------------------------------------------------------------------------------

@pytest.mark.parametrize("backend", ["c", "python"])
def test_a_failed_build_leaves_the_existing_fmu(example1_card, tmp_path, cli, backend):
    _, card_path = example1_card
    out = tmp_path / "o.fmu"
    assert cli("build", card_path, "-o", out, "--backend", backend).code == 0
    before = out.read_bytes()
    data = _card(example1_card)
    data["dims"]["n"] = "two"
    res = cli("build", _write(tmp_path, data, "bad.json"), "-o", out, "--backend", backend)
    assert res.code == 2 and out.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.json", "o.fmu"]      # no temporary left


def test_outputs_that_cannot_be_files_are_refused_before_work(example1_card, example1_path, tmp_path, cli):
    _, card_path = example1_card
    (tmp_path / "folder").mkdir()
    res = cli("build", card_path, "-o", tmp_path / "folder")
    assert res.code == 2 and "is a folder" in res.err
    res = cli("design", example1_path, "-o", "/dev/full")
    assert res.code == 2 and "not a regular file; refusing to replace it" in res.err
    assert Path("/dev/full").exists() and not Path("/dev/full").is_file()
    (tmp_path / "file").write_text("keep")
    res = cli("cosim", "--plant", "p.fmu", "--observer", "o.fmu", "--out", tmp_path / "file")
    assert res.code == 2 and "exists and is not a folder" in res.err
    assert (tmp_path / "file").read_text() == "keep"


def test_missing_folders_are_created_only_inside_an_existing_one(example1_path, tmp_path, cli):
    """``-o /nonexistent/dir/x.json`` (a typo, most likely) creates no folder at the filesystem's root;
    missing folders inside an existing one (here tmp_path, or the current folder) are created."""
    top = Path("/") / f"uiofmu-missing-{tmp_path.name}"
    assert not top.exists()
    for command in (("design", example1_path, "-o", top / "dir" / "x.json"),
                    ("demo", "--out", top / "dir"), ("cosim", "--plant", "p.fmu", "--observer", "o.fmu",
                                                     "--out", top / "dir")):
        res = cli(*command)
        assert res.code == 2 and f"{top} does not exist" in res.err, (command, res.err)
        assert not top.exists(), command
    res = cli("design", example1_path, "-o", tmp_path / "a" / "b" / "x.json")
    assert res.code == 0 and (tmp_path / "a" / "b" / "x.json").is_file()
    relative = tmp_path / "work"                          # relative paths: inside the current folder
    relative.mkdir()
    proc = _uiofmu("design", example1_path, "-o", Path("c") / "d" / "x.json", cwd=relative)
    assert proc.returncode == 0 and (relative / "c" / "d" / "x.json").is_file(), proc.stderr


def test_default_output_names_stay_in_the_working_folder(example1_card, tmp_path):
    data = _card(example1_card)
    data["name"] = "../../../escape/" + "x" * 100
    (tmp_path / "work").mkdir()
    proc = _uiofmu("build", _write(tmp_path, data), "--backend", "c", cwd=tmp_path / "work")
    assert proc.returncode == 0, proc.stderr
    made = list((tmp_path / "work").iterdir())
    assert len(made) == 1 and made[0].name.startswith("escape_xxx") and made[0].suffix == ".fmu"
    assert len(made[0].name) <= 68
    assert sorted(p.name for p in tmp_path.iterdir()) == ["card.json", "work"]


def test_a_write_error_is_an_exit_2(example1_path, tmp_path, cli):
    locked = tmp_path / "locked"
    locked.mkdir()
    (locked / "card.json").write_text("old")
    os.chmod(locked, 0o500)
    try:
        res = cli("design", example1_path, "-o", locked / "card.json")
    finally:
        os.chmod(locked, 0o700)
    if os.geteuid() == 0:       # root writes anyway: the card is replaced whole
        assert res.code == 0 and json.loads((locked / "card.json").read_text())["format"] == "uiofmu.design"
    else:
        assert res.code == 2 and (locked / "card.json").read_text() == "old"


# -- bounded reads -----------------------------------------------------------------------------

def test_devices_fifos_and_huge_files_are_refused(tmp_path, cli, example1_card):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    big = tmp_path / "big.toml"
    with open(big, "wb") as f:
        f.truncate(64 * 2**20 + 1)
    for args, fragment in [(("check", "/dev/zero"), "not a regular file"),
                           (("check", fifo), "not a regular file"),
                           (("check", big), "more than the limit of 67108864"),
                           (("build", fifo, "-o", tmp_path / "o.fmu"), "not a regular file"),
                           (("check", tmp_path), "no such problem file")]:
        res = cli(*args)
        assert res.code == 2 and fragment in res.err, (args, res)


def test_step_files_and_input_tables_are_bounded(tmp_path, example1_card):
    from uiofmu.runtime.errors import ProblemError
    from uiofmu.cosim.inputs import CsvInputs
    from uiofmu.cosim.steps import step_sequence

    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    for spec in ("file:/dev/zero", f"file:{fifo}"):
        with pytest.raises(ProblemError, match="not a regular file"):
            step_sequence(spec, 1.0)
    binary = tmp_path / "in.csv"
    binary.write_bytes(b"time,u[1]\n0,\x00\xff\n")
    with pytest.raises(ProblemError, match="not UTF-8 text"):
        CsvInputs(binary, {"u": 1, "d": 1})
    binary.write_bytes(b"time,u[1]\n0,\x001\n")
    with pytest.raises(ProblemError, match="contains a NUL character"):
        CsvInputs(binary, {"u": 1, "d": 1})


@pytest.mark.parametrize("text,fragment", [
    ("x = " + "[" * 500 + "]" * 500, "nested"),
    ("name = 'a'\n[plant]\ntime = 'discrete'\ndt = 0.1\nA = [[" + "9" * 400 + "]]\nC = [[1.0]]\nE = [[1.0]]\n",
     "too large for a float"),
    ('name = "' + "n" * 5000 + '"\n', "name: at most 128 characters, found 5000"),
])
def test_problem_file_limits(tmp_path, cli, text, fragment):
    path = tmp_path / "p.toml"
    path.write_text(text)
    res = cli("check", path)
    assert res.code == 2 and fragment in res.err and len(res.err.splitlines()) == 1, res


def test_an_fmu_without_its_binary(example1_card, tmp_path, cli):
    _, card_path = example1_card
    assert cli("build", card_path, "-o", tmp_path / "o.fmu").code == 0
    with zipfile.ZipFile(tmp_path / "o.fmu") as src, zipfile.ZipFile(tmp_path / "nobin.fmu", "w") as dst:
        for item in src.infolist():
            if not item.filename.startswith("binaries/"):
                dst.writestr(item, src.read(item))
    res = cli("validate", tmp_path / "nobin.fmu")
    assert res.code == 2 and "cannot be loaded" in res.err and len(res.err.splitlines()) == 1, res


def test_an_internal_error_is_one_line_with_a_hint(monkeypatch, cli, example1_path):
    import uiofmu.synthesis

    def broken(problem):
        raise ZeroDivisionError("boom")

    monkeypatch.setattr(uiofmu.synthesis, "check", broken)
    res = cli("check", example1_path)
    assert res.code == 1 and res.err.startswith("uiofmu check: internal error: ZeroDivisionError: boom")
    assert "please report it" in res.err and len(res.err.splitlines()) == 1


# -- every bound a card prints is re-checked ------------------------------------------------------

_OVERSHOOT_CARDS = ["examples/seed000_example1.toml", "examples/seed000_example1_ltv.toml",
                    "plants/two_room_building/problem.toml", "examples/seed002_setup2.toml",
                    "examples/seed002_three_modes.toml"]


@pytest.fixture(scope="module")
def overshoot_cards():
    from tests.conftest import ROOT

    return {name: uiofmu.design(uiofmu.load_problem(ROOT / name)) for name in _OVERSHOOT_CARDS}


@pytest.mark.parametrize("name", _OVERSHOOT_CARDS)
@pytest.mark.parametrize("claim", [1e-6, 0.0, -1.0, float("nan"), 0.9])
def test_an_overshoot_below_the_certificates_is_refused(overshoot_cards, name, claim, tmp_path, cli):
    """``overshoot_bound`` is what the Lyapunov matrices prove (``sqrt(eig_max / eig_min)``, 1 for a
    dead-beat switched design), never a number anyone may lower: verify fails it and build refuses."""
    card = overshoot_cards[name]
    honest = [c for c in uiofmu.verify(card) if c.name.startswith("overshoot_bound")]
    assert len(honest) == 1 and honest[0].holds and honest[0].bound >= 1.0, (name, honest)
    data = json.loads(json.dumps(card.data))
    data["overshoot_bound"] = claim if claim < 1 else claim * honest[0].bound
    try:
        forged = card_from_data(data)
    except CardError:                       # the schema's own refusal (a non-finite number)
        return
    assert not all(c.holds for c in uiofmu.verify(forged)), (name, claim)
    if claim == 1e-6:                       # and through the command line, before any file is written
        path = _write(tmp_path, data)
        res = cli("build", path, "-o", tmp_path / "o.fmu")
        assert res.code == 2 and "overshoot_bound" in res.err and len(res.err.splitlines()) == 1, res
        assert not (tmp_path / "o.fmu").exists()
        res = cli("verify", path)
        assert res.code == 2 and "overshoot_bound" in res.err and "1e-06" in res.err, res
        honest_path = _write(tmp_path, json.loads(json.dumps(card.data)), "honest.json")
        res = cli("verify", honest_path)
        assert res.code == 0 and "every claim" in res.out and "[ok  ] overshoot_bound" in res.out, res
