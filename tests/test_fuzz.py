"""Fuzzing the command line with hostile inputs (the bounded part of the harness; ``make fuzz``
runs ``tests/fuzz_campaign.py`` at length).

Every case runs through the real command line (in-process ``run_cli`` for ``check``, ``design``,
``build`` and ``plant``, which load no FMU; ``python -m uiofmu`` in a subprocess for everything
that loads an FMU or could block or exhaust memory) in a fresh sandbox, and is judged by
:func:`hostile.judge`: exit 0 or 2 only; on exit 2 exactly one stderr line
``uiofmu COMMAND: error: ...``; no traceback; nothing created, changed or removed outside the
target; an existing output unchanged by a failing command; no injection marker; and a refusal
where the input is invalid beyond doubt. All examples are derandomised.
"""

from __future__ import annotations

import copy
import random
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

import hostile
from conftest import run_cli

# Hypothesis keeps caches (its example database is off below, but not its constants cache) in
# ./.hypothesis by default; the fuzz tests write nothing into the source tree.
import tempfile  # noqa: E402
from hypothesis.configuration import set_hypothesis_home_dir  # noqa: E402

set_hypothesis_home_dir(Path(tempfile.gettempdir()) / "uiofmu-test-fuzz-hypothesis")

#: Derandomised, no example database, no shrinking (an example is an index or a seed: the first
#: failing one is as small as any, and the case summary says what it is).
FUZZ = dict(deadline=None, derandomize=True, database=None, phases=(Phase.explicit, Phase.generate),
            suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                   HealthCheck.function_scoped_fixture, HealthCheck.filter_too_much])
PROBLEMS = hostile.load_base_problems()
#: Every single edit of every base problem (the systematic part of the problem fuzzing).
PROBLEM_MUTATIONS = [(base, m) for base, (_, doc) in sorted(PROBLEMS.items())
                     for m in hostile.all_mutations(doc, "problem")]
RAW_LABELS = [label for label, _ in hostile.raw_text_mutations(random.Random(0), PROBLEMS["ex1"][0])]


@pytest.fixture(scope="module")
def bases(tmp_path_factory) -> hostile.Bases:
    """Designed cards and built FMUs of the base problems (through the in-process CLI)."""
    return hostile.build_bases(tmp_path_factory.mktemp("fuzz_bases"), runner=run_cli,
                               observers=("ex1-c", "ex1-python", "ltv-c", "building-c"))


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    """Where the sandboxes of this module live."""
    return tmp_path_factory.mktemp("fuzz_cases")


def assert_ok(case: hostile.Case, work: Path, inprocess: bool) -> hostile.Outcome:
    """Run ``case`` and fail with its summary when it broke a promise."""
    outcome = hostile.run_case(case, work, runner=run_cli if inprocess else None)
    assert outcome.ok, outcome.summary()
    return outcome


# ---------------------------------------------------------------------------------------------
# the oracle itself: it must see every broken promise (else the fuzzing proves nothing)
# ---------------------------------------------------------------------------------------------
def _judge(tmp_path, results, before=None, after=None, **case):
    c = hostile.Case("t", "t", {}, [hostile.Run(r.argv, allowed=case.pop("allowed", frozenset({0, 2})))
                                    for r in results], **case)
    return [kind for kind, _ in hostile.judge(c, results, before or {}, after or {}, tmp_path).problems]


def test_oracle_flags_every_broken_promise(tmp_path):
    ok2 = hostile.RunResult(["check"], 2, "", "uiofmu check: error: plant.A: ragged\n", 0.1)
    assert _judge(tmp_path, [ok2]) == []
    internal = hostile.RunResult(["check"], 1, "", "uiofmu check: internal error: x\n", 0.1)
    assert _judge(tmp_path, [internal]) == ["exit1"]
    two = hostile.RunResult(["check"], 2, "", "usage: uiofmu check\nuiofmu check: error: x\n", 0.1)
    assert _judge(tmp_path, [two]) == ["multiline"]
    other = hostile.RunResult(["check"], 2, "", "uiofmu design: error: x\n", 0.1)
    assert _judge(tmp_path, [other]) == ["multiline"]
    tb = hostile.RunResult(["check"], 1, "", "Traceback (most recent call last):\nValueError\n", 0.1)
    assert _judge(tmp_path, [tb]) == ["exit1", "traceback"]
    assert _judge(tmp_path, [hostile.RunResult(["check"], -11, "", "", 0.1, signal=11)]) == ["signal"]
    assert _judge(tmp_path, [hostile.RunResult(["check"], None, "", "", 9.0, timed_out=True)]) == ["timeout"]
    ok0 = hostile.RunResult(["build"], 0, "written\n", "", 0.1)
    assert _judge(tmp_path, [ok0], allowed=frozenset({2})) == ["accepted"]
    before = {"in/p.toml": ("file", 3, "a"), "out/x.json": ("file", 3, "b")}
    assert _judge(tmp_path, [ok0], before, {**before, "cwd/stray.json": ("file", 1, "c")},
                  targets=["out/x.json"]) == ["outside"]
    assert _judge(tmp_path, [ok0], before, {**before, "out/x.json": ("file", 9, "new")}, targets=["out/x.json"]) == []
    assert _judge(tmp_path, [ok0], before, {**before, "in/p.toml": ("file", 0, "")},
                  targets=["out/x.json"]) == ["outside"]
    assert _judge(tmp_path, [ok2], before, {**before, "out/x.json": ("file", 0, "")}, targets=["out/x.json"],
                  preserve=["out/x.json"]) == ["lost"]
    assert _judge(tmp_path, [ok2], before, {"in/p.toml": before["in/p.toml"]}, targets=["out/x.json"],
                  preserve=["out/x.json"]) == ["lost"]
    assert _judge(tmp_path, [ok0], before, {**before, "out/d/x.json": ("file", 1, "")},
                  targets=["out/d/x.json"]) == []
    assert _judge(tmp_path, [ok0], before, {**before, "out/.x.json.tmp": ("file", 1, "")},
                  targets=["out/x.json"]) == ["outside"]
    (tmp_path / "cwd").mkdir()
    (tmp_path / "cwd" / "MARKER").write_text("")
    assert _judge(tmp_path, [ok0], markers=["cwd/MARKER"]) == ["marker"]
    assert _judge(tmp_path, [ok0], before, {**before, f"tmp/x/{hostile.MARKER}_a": ("file", 0, "")},
                  targets=["tmp"]) == ["marker"]


def test_sandbox_runner_sees_files_outside_and_leftover_temporaries(tmp_path):
    def rogue(*argv):
        Path("stray.txt").write_text("written into the working folder")
        import tempfile
        tempfile.mkstemp(prefix="leftover_")
        return hostile.RunResult(list(argv), 0, "", "", 0.0)
    case = hostile.Case("t", "rogue", {"in/a": b"x"}, [hostile.Run(["check", hostile.P("in/a")])])
    outcome = hostile.run_case(case, tmp_path, runner=rogue)
    kinds = sorted(detail.split()[1].split("/")[0] for kind, detail in outcome.problems if kind == "outside")
    assert kinds == ["cwd", "tmp"], outcome.summary()

    def hang(*argv):
        import time
        time.sleep(30)
    case = hostile.Case("t", "hang", {}, [hostile.Run(["check"])], timeout=0.5)
    assert [k for k, _ in hostile.run_case(case, tmp_path, runner=hang).problems] == ["timeout"]

    def crash(*argv):
        raise RuntimeError("boom")
    case = hostile.Case("t", "crash", {}, [hostile.Run(["check"])])
    assert [k for k, _ in hostile.run_case(case, tmp_path, runner=crash).problems] == ["exit1", "traceback"]


def test_serialisers_write_what_they_claim():
    import tomllib

    doc = {"name": "a\"b\\\n\x00\x7f\u202e", "plant": {"A": [[float("nan"), float("inf"), -float("inf"), 10**400]],
                                                      "t": {"k": [True, 5e-324]}}}
    back = tomllib.loads(hostile.toml_dumps(doc))
    assert back["name"] == doc["name"]
    assert str(back["plant"]["A"][0][0]) == "nan"
    assert back["plant"]["A"][0][1:] == [float("inf"), -float("inf"), 10**400]
    assert back["plant"]["t"] == {"k": [True, 5e-324]}
    text = hostile.json_text({"a": [float("nan"), float("inf")], "b": hostile.Raw("1e400"),
                              "c": hostile.Deep("list", 3)})
    assert text == '{"a": [NaN, Infinity], "b": 1e400, "c": [[[1.0]]]}'
    deep = hostile.toml_value(hostile.Deep("table", 500))
    assert deep.count("{a = ") == 500


def test_payloads_are_live_when_pasted_into_code(tmp_path):
    """Positive control: pasted naively into C or Python source, the payloads do write their
    marker, so a marker that never appears in the fuzz cases means they were defused."""
    cc = next((c for c in ("cc", "gcc") if subprocess.run(["which", c], capture_output=True).returncode == 0), None)
    assert cc, "the C payloads need a C compiler to be checked"
    payloads = dict(hostile.injection_payloads())
    contexts = {"c-close-comment": "/* {} */\nint x;\n", "c-short-close-comment": "/* {} */\nint x;\n",
                "c-string-breakout": 'const char *n = "{}";\n', "c-short-string-breakout": 'const char *n = "{}";\n'}
    for label, context in contexts.items():
        work = tmp_path / label
        work.mkdir()
        name = payloads[label]["name"]
        (work / "design_data.c").write_text(context.replace("{}", name))
        proc = subprocess.run([cc, "-shared", "-fPIC", "-o", str(work / "lib.so"), str(work / "design_data.c")],
                              capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr
        subprocess.run([sys.executable, "-c", f"import ctypes; ctypes.CDLL({str(work / 'lib.so')!r})"], cwd=work,
                       check=True)
        assert any(hostile.MARKER in p.name for p in work.iterdir()), label
    py = {"py-name-quote-short": "description = '{}'\n", "py-name-triple-quote-short": 'description = """{}"""\n',
          "py-description-key": "description = '''{}'''\n"}
    for label, context in py.items():
        work = tmp_path / label
        work.mkdir()
        text = next(v for v in payloads[label].values())
        subprocess.run([sys.executable, "-c", context.replace("{}", text)], cwd=work, capture_output=True)
        assert any(hostile.MARKER in p.name for p in work.iterdir()), label


# ---------------------------------------------------------------------------------------------
# (a) problem files
# ---------------------------------------------------------------------------------------------
@settings(max_examples=100, **FUZZ)
@given(st.sampled_from(range(len(PROBLEM_MUTATIONS))))
def test_every_problem_edit_through_check(bases, work, pick):
    base, mutation = PROBLEM_MUTATIONS[pick]
    case = hostile.problem_case(random.Random(0), bases, "check", "problem-check", mutation=mutation, base=base)
    assert_ok(case, work, inprocess=True)


@settings(max_examples=40, **FUZZ)
@given(st.sampled_from(range(len(PROBLEM_MUTATIONS))), st.integers(0, 2**31))
def test_problem_edits_through_design_keep_existing_output(bases, work, pick, seed):
    base, mutation = PROBLEM_MUTATIONS[pick]
    case = hostile.problem_case(random.Random(seed), bases, "design", "problem-design", mutation=mutation, base=base)
    assert_ok(case, work, inprocess=True)


@settings(max_examples=30, **FUZZ)
@given(st.integers(0, 2**31), st.sampled_from(["check", "design"]))
def test_compound_problem_edits(bases, work, seed, command):
    case = hostile.problem_case(random.Random(seed), bases, command, "problem-compound", mode="compound")
    assert_ok(case, work, inprocess=True)


@settings(max_examples=40, **FUZZ)
@given(st.sampled_from(RAW_LABELS), st.sampled_from(sorted(PROBLEMS)), st.integers(0, 2**31))
def test_raw_problem_text(bases, work, label, base, seed):
    rng = random.Random(seed)
    content = dict(hostile.raw_text_mutations(rng, PROBLEMS[base][0]))[label]
    case = hostile.Case("problem-raw", f"{base}: raw {label}", {"in/problem.toml": content},
                        [hostile.Run(["check", hostile.P("in/problem.toml")])])
    assert_ok(case, work, inprocess=True)


@settings(max_examples=30, **FUZZ)
@given(st.integers(0, 2**31))
def test_random_toml(bases, work, seed):
    case = hostile.problem_case(random.Random(seed), bases, "check", "problem-random", mode="random")
    assert_ok(case, work, inprocess=True)


@pytest.mark.parametrize("label", [label for label, _ in hostile.deep_toml_texts()])
def test_deep_problem_files_are_refused(work, label):
    content = dict(hostile.deep_toml_texts())[label]
    for command in ("check", "design"):
        tail = ["-o", hostile.P("out/c.json")] if command == "design" else []
        argv = [command, hostile.P("in/problem.toml")] + tail
        case = hostile.Case("problem-deep", label, {"in/problem.toml": content},
                            [hostile.Run(argv, allowed=frozenset({2}))], ["out/c.json"])
        assert_ok(case, work, inprocess=True)


@settings(max_examples=20, **FUZZ)
@given(st.sampled_from(range(len(PROBLEM_MUTATIONS))), st.integers(0, 2**31))
def test_problem_edits_through_plant(bases, work, pick, seed):
    base, mutation = PROBLEM_MUTATIONS[pick]
    case = hostile.problem_case(random.Random(seed), bases, "plant", "problem-plant", mutation=mutation, base=base)
    assert_ok(case, work, inprocess=True)


# ---------------------------------------------------------------------------------------------
# (b) design cards
# ---------------------------------------------------------------------------------------------
def _card_mutation(bases, index: int):
    base = sorted(bases.cards)[index % 3]
    pool = hostile.mutation_pool(bases, "card", base)
    return base, pool[(index // 3) % len(pool)]


@pytest.mark.slow
@settings(max_examples=35, **FUZZ)
@given(st.integers(0, 10**9), st.integers(0, 2**31))
def test_every_card_field_through_build_python(bases, work, index, seed):
    base, mutation = _card_mutation(bases, index)
    case = hostile.card_case(random.Random(seed), bases, "python", "card-build-python", mutation=mutation, base=base)
    assert_ok(case, work, inprocess=True)


@settings(max_examples=15, **FUZZ)
@given(st.integers(0, 10**9), st.integers(0, 2**31))
def test_card_fields_through_build_c(bases, work, index, seed):
    base, mutation = _card_mutation(bases, index)
    case = hostile.card_case(random.Random(seed), bases, "c", "card-build-c", mutation=mutation, base=base)
    assert_ok(case, work, inprocess=True)


@settings(max_examples=20, **FUZZ)
@given(st.integers(0, 2**31), st.sampled_from(["compound", "raw", "problem"]))
def test_compound_and_raw_cards(bases, work, seed, mode):
    case = hostile.card_case(random.Random(seed), bases, "python", f"card-{mode}", mode=mode)
    assert_ok(case, work, inprocess=True)


#: Cards invalid beyond doubt: building them must fail (exit 2) on both backends.
INVALID_CARD_EDITS = [
    ("format", ("format",), "uiofmu.designx"),
    ("version true", ("version",), True),
    ("version string", ("version",), "1"),
    ("verified no", ("certificate", "verified"), "no"),
    ("verified 1", ("certificate", "verified"), 1),
    ("verified missing", ("certificate", "verified"), hostile._DELETED),
    ("dims.n true", ("dims", "n"), True),
    ("dims.n 3", ("dims", "n"), 3),
    ("dims.p 10**18", ("dims", "p"), 10**18),
    ("xhat0 shorter than n", ("initial", "xhat0"), [0.0]),
    ("xhat0 NaN", ("initial", "xhat0"), [float("nan"), 0.0]),
    ("matrices.N NaN literal", ("matrices", "N", 0, 0), hostile.Raw("NaN")),
    ("matrices.N 1e400", ("matrices", "N", 0, 0), hostile.Raw("1e400")),
    ("matrices.C ragged", ("matrices", "C", 0), [1.0]),
    ("matrices.Xz zeroed, verified kept true", ("matrices", "Xz"), [[0.0, 0.0], [0.0, 0.0]]),
    ("matrices.N scaled by 10, verified kept true", ("matrices", "N"), [[0.0, 0.0], [-6.3e-12, 9.9]]),
    ("schedule.dt zero", ("schedule", "dt"), 0.0),
    ("dt negative", ("dt",), -0.1),
    ("schedule.kind unknown", ("schedule", "kind"), "exec"),
    ("family swapped", ("family",), "ltv-auid"),
    ("family unknown", ("family",), "kalman"),
    ("name FMU_DESCRIPTION with payload family", ("family",),
     "A(__import__('os').system('touch MARKER') or Fmi2Slave):#"),
]
INVALID_SCHEDULE_EDITS = [
    ("building", "negative interval", ("schedule", "intervals", 0), -600.0),
    ("building", "zero interval", ("schedule", "intervals", 0), 0.0),
    ("building", "h_prev0 negative", ("schedule", "h_prev0"), -1.0),
    ("ltv", "alpha 50", ("schedule", "alpha"), 50.0),
    ("ltv", "alpha zero", ("schedule", "alpha"), 0.0),
]


@pytest.mark.parametrize("backend", ["python", "c"])
@pytest.mark.parametrize("edit", INVALID_CARD_EDITS + INVALID_SCHEDULE_EDITS,
                         ids=lambda e: e[1] if len(e) == 4 else e[0])
def test_invalid_cards_are_refused(bases, work, edit, backend):
    base, label, path, value = edit if len(edit) == 4 else ("ex1", *edit)
    doc = copy.deepcopy(bases.cards[base][1])
    hostile.get_path(doc, path)  # the edit names a real field
    if value is hostile._DELETED:
        hostile.Mutation("delete", path).apply(doc)
    else:
        hostile.Mutation("set", path, label, value).apply(doc)
    if label.startswith("name FMU_DESCRIPTION"):
        doc["name"] = "FMU_DESCRIPTION"
    case = hostile.Case("card-invalid", f"{base}: {label}", {"in/card.json": hostile.card_text(doc),
                                                             "out/obs.fmu": hostile.PREEXISTING},
                        [hostile.Run(["build", hostile.P("in/card.json"), "-o", hostile.P("out/obs.fmu"),
                                      "--backend", backend], allowed=frozenset({2}))],
                        ["out/obs.fmu"], ["out/obs.fmu"], markers=["cwd/MARKER"])
    assert_ok(case, work, inprocess=True)


def test_consistent_forgeries_through_verify_and_build(bases, work):
    """The card-tamper cases of ``make fuzz``, consistent forgeries included, a spread of them in
    process: ``verify`` and ``build`` exit 2 with one line, and no FMU appears."""
    from fuzz_campaign import spread

    cases = [c for c in hostile.tamper_cases(bases) if "consistent forgery" in c.label]
    assert len(cases) >= 20, len(cases)
    for case in spread(cases, 12):
        assert_ok(case, work, inprocess=True)


@pytest.mark.parametrize("label", [label for label, _ in hostile.deep_json_texts()])
def test_deep_cards_are_refused(work, label):
    case = hostile.Case("card-deep", label, {"in/card.json": dict(hostile.deep_json_texts())[label]},
                        [hostile.Run(["build", hostile.P("in/card.json"), "-o", hostile.P("out/obs.fmu"), "--backend",
                                      "python"], allowed=frozenset({2}))], ["out/obs.fmu"])
    assert_ok(case, work, inprocess=True)


# ---------------------------------------------------------------------------------------------
# injection: never at build (both backends), at FMU load, or when the FMU runs
# ---------------------------------------------------------------------------------------------
def _combined(*labels: str, **where: str) -> dict:
    """Several payloads in one card: each label's edit, or its text put at the given key."""
    payloads = dict(hostile.injection_payloads())
    edit = {}
    for label in labels:
        edit.update(payloads[label])
    for key, label in where.items():
        edit[key.replace("__", ".")] = next(iter(payloads[label].values()))
    return edit


#: Payload cards of the test (``make fuzz`` runs every payload alone): the two known ones, and
#: cards carrying several payloads at once (name, an extra description, the recorded problem's name).
INJECTIONS = {
    "known C: name x **// + constructor": _combined("c-comment-newline"),
    "known Python: family A(...) or Fmi2Slave):# + name FMU_DESCRIPTION": _combined("py-family-verbatim"),
    "short C close-comment name + Python description + XML generator": _combined(
        "c-short-close-comment", "py-description-key", generator="xml-name"),
    "short C inline-comment name + Python quote in problem.name": _combined(
        "c-short-comment-inline", problem__name="py-name-quote-short"),
    "short C string break-out name": _combined("c-short-string-breakout"),
    "Python triple-quote name": _combined("py-name-triple-quote-short"),
}
COSIM_INJECTIONS = ("short C close-comment name + Python description + XML generator",)
#: Every marker any payload may write.
MARKERS = sorted({m for name in dict(hostile.injection_payloads()) for m in hostile.injection_markers(name)})


def _payload_card(bases, label: str) -> dict:
    """The ex1 card carrying the payloads of ``INJECTIONS[label]``."""
    doc = copy.deepcopy(bases.cards["ex1"][1])
    for key, value in INJECTIONS[label].items():
        if "." in key:
            outer, inner = key.split(".")
            doc[outer][inner] = value
        else:
            doc[key] = value
    return doc


@pytest.mark.parametrize("backend", ["c", "python"])
@pytest.mark.parametrize("label", list(INJECTIONS))
def test_injection_payloads_never_run(bases, work, label, backend):
    """No payload runs at build (in-process, both backends), nor when the FMU built from it is
    loaded and run by ``validate`` and ``cosim`` (subprocesses)."""
    doc = _payload_card(bases, label)
    files = {"in/card.json": hostile.card_text(doc), "in/plant.fmu": bases.fmus["plant-ex1"]}
    build = hostile.Case("injection", f"{label}: build --backend {backend}", files,
                         [hostile.Run(["build", hostile.P("in/card.json"), "-o", hostile.P("out/obs.fmu"),
                                       "--backend", backend])], ["out/obs.fmu"], markers=MARKERS)
    root = None
    outcome = hostile.run_case(build, work, runner=run_cli, keep=True)
    try:
        root = outcome.root
        assert outcome.ok, outcome.summary()
        if outcome.results[0].code != 0:
            return
        fmu = (root / "out" / "obs.fmu").read_bytes()
    finally:
        if root is not None:
            import shutil
            shutil.rmtree(root, ignore_errors=True)
    runs = [hostile.Run(["validate", hostile.P("in/obs.fmu"), "--steps", "5"])]
    if label in COSIM_INJECTIONS:
        runs.append(hostile.cosim_runs("in/obs.fmu", "in/plant.fmu", "out/run", ["--t-end", "0.5"], "ex1"))
    run = hostile.Case("injection", f"{label}: the FMU built with --backend {backend} loaded and run",
                       {"in/obs.fmu": fmu, "in/plant.fmu": bases.fmus["plant-ex1"]}, runs, ["out/run"],
                       markers=MARKERS)
    assert_ok(run, work, inprocess=False)


@pytest.mark.parametrize("backend", ["c", "python"])
@pytest.mark.parametrize("label", ["known Python: family A(...) or Fmi2Slave):# + name FMU_DESCRIPTION",
                                   "short C close-comment name + Python description + XML generator"])
def test_injection_spliced_into_a_valid_fmu_never_runs(bases, work, label, backend):
    """A payload card packed into a valid FMU (as a foreign FMU could be) never runs when the
    FMU is loaded and run by ``validate``."""
    fmu = hostile.fmu_with_card(bases.fmus[f"obs-ex1-{backend}"], hostile.card_text(_payload_card(bases, label)))
    case = hostile.Case("injection", f"{label} spliced into a {backend} FMU", {"in/obs.fmu": fmu},
                        [hostile.Run(["validate", hostile.P("in/obs.fmu"), "--steps", "5"])], [], markers=MARKERS)
    assert_ok(case, work, inprocess=False)


def test_injection_through_a_problem_name(bases, work):
    name = dict(hostile.injection_payloads())["c-short-close-comment"]["name"]
    doc = copy.deepcopy(PROBLEMS["ex1"][1])
    doc["name"] = name
    runs = [hostile.Run(["design", hostile.P("in/problem.toml"), "-o", hostile.P("out/card.json")])]
    for backend in ("c", "python"):
        runs.append(hostile.Run(["build", hostile.P("out/card.json"), "-o", hostile.P(f"out/obs-{backend}.fmu"),
                                 "--backend", backend], after_success=True))
    case = hostile.Case("injection", "problem name payload", {"in/problem.toml": hostile.problem_text(doc)}, runs,
                        ["out"], markers=MARKERS)
    assert_ok(case, work, inprocess=True)


# ---------------------------------------------------------------------------------------------
# (c) co-simulation arguments, outputs and input files
# ---------------------------------------------------------------------------------------------
@pytest.mark.slow
@settings(max_examples=10, **FUZZ)
@given(st.integers(0, 2**31), st.sampled_from(["steps", "steps", "seed", "t-end", "out", "inputs", "inputs", "fmus"]))
def test_cosim_arguments(bases, work, seed, kind):
    case = hostile.cosim_case(random.Random(seed), bases, "cosim", kind)
    assert_ok(case, work, inprocess=False)


def _fake_bases():
    """Stand-ins for the bases, enough to enumerate the labels of the fixed case lists."""
    from types import SimpleNamespace

    return SimpleNamespace(problems=PROBLEMS, cards={"ex1": ("{}", {})}, fmus={"obs-ex1-c": b"", "plant-ex1": b""})


@pytest.mark.parametrize("label", [c.label for c in hostile.output_cases(_fake_bases())])
def test_output_targets(bases, work, label):
    case = next(c for c in hostile.output_cases(bases) if c.label == label)
    fifo = any(isinstance(v, hostile.Fifo) for v in case.files.values())
    assert_ok(case, work, inprocess=not fifo)


#: Kinds of input file that cannot block or exhaust memory in this process.
IN_PROCESS_SAFE = {"folder", "sparse-above-limit", "empty", "missing", "valid-above-limit", "device-null",
                   "proc-file"}


def _selected_input_cases() -> list[str]:
    """Every hostile input file for the commands that load no FMU; for the others (each case a
    subprocess) every kind for ``validate`` and the blocking kinds for ``cosim`` (``make fuzz``
    runs them all)."""
    out = []
    for case in hostile.input_file_cases(_fake_bases()):
        slot, kind = case.label.split(" given ")
        if slot in ("check", "design", "plant", "build") or slot.startswith("check given a folder"):
            if kind in IN_PROCESS_SAFE or slot in ("check", "build"):
                out.append(case.label)
        elif slot == "validate" or kind in ("fifo", "device-zero", "folder"):
            out.append(case.label)
    return out


@pytest.mark.parametrize("label", _selected_input_cases())
def test_input_files(bases, work, label):
    case = next(c for c in hostile.input_file_cases(bases) if c.label == label)
    slot, kind = label.split(" given ")
    inprocess = slot in hostile.IN_PROCESS_COMMANDS and kind in IN_PROCESS_SAFE
    assert_ok(case, work, inprocess=inprocess)


FMU_VARIANTS = ["no-binary", "garbage-binary", "empty-binary", "model-description-not-xml",
                "model-description-entity-bomb", "no-model-json", "model-json-deep", "model-json-card-list",
                "traversal-member", "not-a-zip", "truncated"]


@pytest.mark.parametrize("variant", FMU_VARIANTS)
def test_broken_observer_fmus(bases, work, variant):
    content = dict(hostile.broken_fmus(bases.fmus["obs-ex1-c"]))[variant]
    case = hostile.Case("fmu-level", f"obs-ex1-c {variant}: validate", {"in/x.fmu": content},
                        [hostile.Run(["validate", hostile.P("in/x.fmu"), "--steps", "5"], allowed=frozenset({2}))],
                        [], timeout=60)
    assert_ok(case, work, inprocess=False)


@pytest.mark.parametrize("variant", ["no-binary", "model-json-not-json"])
def test_broken_python_fmus_in_cosim(bases, work, variant):
    files = {"in/x.fmu": dict(hostile.broken_fmus(bases.fmus["obs-ex1-python"]))[variant],
             "in/plant.fmu": bases.fmus["plant-ex1"]}
    case = hostile.Case("fmu-level", f"obs-ex1-python {variant}: cosim", files,
                        [hostile.Run(["cosim", "--plant", hostile.P("in/plant.fmu"),
                                      "--observer", hostile.P("in/x.fmu"),
                                      "--out", hostile.P("out/run"), "--t-end", "0.5"], allowed=frozenset({2}))],
                        ["out/run"], timeout=60)
    assert_ok(case, work, inprocess=False)


def test_argument_errors(bases, work):
    failures = []
    for case in hostile.argument_cases(bases):
        outcome = hostile.run_case(case, work)
        if not outcome.ok:
            failures.append(outcome.summary())
    assert not failures, "\n".join(failures)


HOSTILE_SIZES = {
    "intervals.count = 10**9": ("building", ("observer", "intervals", "count"), 10**9),
    "intervals.count = 2**63": ("building", ("observer", "intervals", "count"), 2**63),
    "intervals as 10**5 equal entries": ("building", ("observer", "intervals"), [600.0] * 100_000),
}


@pytest.mark.parametrize("label", list(HOSTILE_SIZES))
def test_hostile_sizes_are_refused_not_attempted(work, label):
    """A size no design can use is refused (exit 2) quickly, in a subprocess with 4 GiB of
    address space, rather than attempted until memory or time runs out."""
    base, path, value = HOSTILE_SIZES[label]
    doc = copy.deepcopy(PROBLEMS[base][1])
    hostile.Mutation("set", path, label, value).apply(doc)
    case = hostile.Case("sizes", label, {"in/problem.toml": hostile.problem_text(doc)},
                        [hostile.Run(["check", hostile.P("in/problem.toml")], allowed=frozenset({2}))], timeout=30)
    assert_ok(case, work, inprocess=False)
