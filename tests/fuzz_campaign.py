"""The fuzz campaign: many hostile cases through the real command line, one table per category.

Usage::

    python tests/fuzz_campaign.py [--cases N] [--seed S] [--seconds T] [--jobs J]
                                  [--only CATEGORY ...] [--workdir DIR] [--report FILE.json]

``--cases N`` is the number of cases in total: each category generates its share (N divided by the
number of categories, rounded up), the categories are interleaved and the first N are run (fewer when
the fixed lists of some categories are shorter than their share; the count is printed first).
A command line that no process can take (an argument of more than :data:`hostile.MAX_ARG_BYTES`, a
NUL byte) reaches the command through a file (:func:`hostile.run_subprocess`).
Each case (``tests/hostile.py``) runs as ``python -m uiofmu ...`` in its own sandbox with a 4 GiB
address-space limit and a timeout; the sandbox is snapshot before and after. The table counts,
per category, the cases tried, their exit codes (0, 2, 1), crashes by a signal, timeouts,
tracebacks, exit-2 messages that are not one line ``uiofmu COMMAND: error: ...``, files created,
changed or removed outside the target, outputs lost by a failing command, injection markers, and
successes on inputs that must be refused. Then every distinct failure, grouped by cause, with the
smallest reproducer found (its command and input files, which are kept under
``WORKDIR/failures``). The exit status is 1 when any case broke a promise, 0 otherwise.

Cases are generated from ``--seed`` alone: the same seed gives the same cases. ``--seconds``
bounds the wall time; cases are interleaved across categories so that a bounded run still covers
every category.
"""

from __future__ import annotations

import argparse
import json
import random
import re
import shutil
import sys
import tempfile
import threading
import time
from collections import Counter, defaultdict
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path

sys.dont_write_bytecode = True  # nothing into the source tree
sys.path.insert(0, str(Path(__file__).resolve().parent))
import hostile  # noqa: E402

#: Table columns: (heading, problem kind or exit code).
COLUMNS = [("tried", None), ("exit 0", 0), ("exit 2", 2), ("exit 1", 1), ("signal", "signal"),
           ("timeout", "timeout"), ("traceback", "traceback"), ("multi-line", "multiline"),
           ("outside", "outside"), ("lost", "lost"), ("marker", "marker"), ("accepted", "accepted"),
           ("other exit", "exit-other")]


def _single_then_other(rng, pool, n, make_single, make_other):
    """Half the cases from a shuffled pool of single edits (without repetition), half of
    the other kinds."""
    pool = list(pool)
    rng.shuffle(pool)
    singles = [make_single(item) for item in pool[: n // 2]]
    return singles + [make_other() for _ in range(n - len(singles))]


def spread(cases: list, n: int) -> list:
    """At most ``n`` of ``cases``, evenly spread over the list (its kinds come in blocks)."""
    return cases[:: max(1, len(cases) // max(n, 1))][:n]


def generate(bases: hostile.Bases, total: int, seed: int, only: set | None = None) -> dict:
    """Every category's cases: its share of ``total``.

    Parameters
    ----------
    bases : hostile.Bases
    total : int
        Cases of all categories together: each generates ``ceil(total / categories)`` (fixed lists
        are cut to it), and :func:`interleave` then :func:`first_cases` keep ``total`` of them.
    seed : int
    only : set of str, optional
        Categories to generate.

    Returns
    -------
    dict
        Category -> list of Case.
    """
    def rng_for(name):
        return random.Random(f"{seed}:{name}")
    problem_pool = [(b, m) for b in sorted(bases.problems) for m in hostile.mutation_pool(bases, "problem", b)]
    card_pool = [(b, m) for b in sorted(bases.cards) for m in hostile.mutation_pool(bases, "card", b)]
    makers = {}
    for command in ("check", "design", "plant"):
        cat = f"problem-{command}"

        def make(cat=cat, command=command):
            rng = rng_for(cat)
            return _single_then_other(
                rng, problem_pool, n,
                lambda item: hostile.problem_case(rng, bases, command, cat, mutation=item[1], base=item[0]),
                lambda: hostile.problem_case(rng, bases, command, cat,
                                             mode=rng.choices(["compound", "raw", "random", "deep"], [4, 3, 2, 1])[0]))
        makers[cat] = make
    for backend in ("c", "python"):
        cat = f"card-build-{backend}"

        def make(cat=cat, backend=backend):
            rng = rng_for(cat)
            return _single_then_other(
                rng, card_pool, n,
                lambda item: hostile.card_case(rng, bases, backend, cat, mutation=item[1], base=item[0]),
                lambda: hostile.card_case(rng, bases, backend, cat,
                                          mode=rng.choices(["compound", "raw", "problem", "deep"], [4, 3, 2, 1])[0]))
        makers[cat] = make
    makers["card-in-fmu"] = lambda: [hostile.card_in_fmu_case(rng, bases, "card-in-fmu")
                                     for rng in [rng_for("card-in-fmu")] for _ in range(n)]
    makers["card-tamper"] = lambda: spread(hostile.tamper_cases(bases), n)
    makers["injection"] = lambda: hostile.injection_cases(bases)[: max(n, 0)]
    kinds = ["steps", "steps", "steps", "seed", "t-end", "out", "inputs", "inputs", "inputs", "fmus"]
    makers["cosim-args"] = lambda: [hostile.cosim_case(rng, bases, "cosim-args", kinds[i % len(kinds)])
                                    for rng in [rng_for("cosim-args")] for i in range(n)]
    makers["outputs"] = lambda: hostile.output_cases(bases)[:n]
    makers["input-files"] = lambda: hostile.input_file_cases(bases)[:n]
    makers["fmu-level"] = lambda: hostile.fmu_level_cases(bases)[:n]
    makers["arguments"] = lambda: hostile.argument_cases(bases)[:n]
    makers["mujoco-spec"] = lambda: [hostile.mujoco_case(rng, "mujoco-spec")
                                     for rng in [rng_for("mujoco-spec")] for _ in range(max(n // 4, 1))]

    def sizes():
        rng = rng_for("sizes")
        out = []
        for size in (20, 40, 80):
            for command in ("check", "design"):
                doc = hostile.random_plant_problem(rng, size)
                argv = [command, hostile.P("in/problem.toml")] + (["-o", hostile.P("out/c.json")]
                                                                 if command == "design" else [])
                out.append(hostile.Case("sizes", f"random discrete plant, n = {size}: {command}",
                                        {"in/problem.toml": hostile.problem_text(doc)}, [hostile.Run(argv)],
                                        ["out/c.json"], timeout=120))
        return out[:n]
    makers["sizes"] = sizes
    opt_in = {"sizes"}  # slow by nature (large LMIs): run with --only sizes
    chosen = [cat for cat in makers if (cat in only if only else cat not in opt_in)]
    n = -(-total // max(1, len(chosen)))
    return {cat: makers[cat]() for cat in chosen}


def first_cases(groups: dict, total: int) -> list:
    """The first ``total`` cases of the categories interleaved (every category gets its share)."""
    return interleave(groups)[:total]


def interleave(groups: dict) -> list:
    """Round-robin over the categories (so a time-bounded run covers all)."""
    out, lists = [], [list(v) for v in groups.values()]
    while any(lists):
        for lst in lists:
            if lst:
                out.append(lst.pop(0))
    return out


def normalise(detail: str) -> str:
    """A failure's detail without paths, numbers and quoted values (the cause, not the case)."""
    text = re.sub(r"/\S*case_[^/\s]+", "SANDBOX", detail)
    text = re.sub(r"/tmp/\S+", "PATH", text)
    text = re.sub(r"'[^']{0,400}'|\"[^\"]{0,400}\"", "'…'", text)
    text = re.sub(r"\d+(\.\d+)?(e[+-]?\d+)?", "N", text)
    return text[:220]


def cause(kind: str, detail: str, outcome) -> str:
    """The grouping key of one problem of an outcome."""
    if kind in ("exit1", "traceback"):
        err = "\n".join(r.err for r in outcome.results)
        m = re.findall(r"internal error: (\w+(?:Error|Exception|Warning)?)", err) or \
            re.findall(r"^(\w+(?:Error|Exception)): ", err, flags=re.M)
        exc = m[-1] if m else ""
        return f"{kind}: {exc}: {normalise(detail.split(': ', 2)[-1])}"
    if kind in ("outside", "lost"):
        return f"{kind}: {normalise(re.sub(r'tmp[a-z0-9_]{6,}', 'tmpXXXX', detail))} ({outcome.case.runs[0].command})"
    if kind == "accepted":
        return f"accepted: {outcome.case.category}: {_field_of(outcome.case.label)}"
    if kind == "multiline":
        return f"multiline: {normalise(detail)}"
    return f"{kind}: {normalise(detail)}"


def _field_of(label: str) -> str:
    """``card ex1: dims.n := integer:true`` -> ``dims.n``, the field an acceptance is about."""
    m = re.search(r": ([^:;]+?) (?::=|deleted|\+=)", label)
    if m:
        return re.sub(r"\[\d+\]", "[i]", m.group(1))
    return re.sub(r"\(.*\)", "", label)


def size_of(outcome) -> int:
    """Total bytes of a case's inputs (to pick the smallest reproducer)."""
    total = 0
    for content in outcome.case.files.values():
        if isinstance(content, bytes):
            total += len(content)
        elif isinstance(content, hostile.Zip):
            total += sum(len(v) for v in content.members.values())
        else:
            total += getattr(content, "size", 0)
    return total + len(outcome.case.label)


def table(outcomes: list, categories: list) -> str:
    """The per-category table."""
    rows = []
    totals = Counter()
    for cat in categories:
        outs = [o for o in outcomes if o.case.category == cat]
        if not outs:
            continue
        counts = Counter()
        for o in outs:
            counts[None] += 1
            first = o.results[0] if o.results else None
            if first is not None and not first.timed_out and first.code in (0, 1, 2):
                counts[first.code] += 1
            for kind in {k for k, _ in o.problems}:
                counts[kind] += 1
        totals.update(counts)
        rows.append([cat] + [str(counts[key]) for _, key in COLUMNS])
    rows.append(["TOTAL"] + [str(totals[key]) for _, key in COLUMNS])
    heads = ["category"] + [h for h, _ in COLUMNS]
    widths = [max(len(r[i]) for r in rows + [heads]) for i in range(len(heads))]
    line = lambda r: "  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths)))  # noqa: E731
    return "\n".join([line(heads), line(["-" * w for w in widths])] + [line(r) for r in rows])


def describe_files(case, names: dict) -> list[str]:
    """The input files of a case, for a reproducer (short text inline; base FMUs by name).

    Parameters
    ----------
    case : hostile.Case
    names : dict
        Bytes of the base FMUs -> their names.

    Returns
    -------
    list of str
    """
    out = []
    for rel, content in case.files.items():
        if isinstance(content, bytes) and content in names:
            out.append(f"    {rel}: the base FMU {names[content]}")
        elif isinstance(content, bytes) and (b"\x00" in content[:4096] or content[:2] == b"PK"):
            out.append(f"    {rel}: {len(content)} bytes of binary data")
        elif isinstance(content, bytes):
            text = content.decode("utf-8", "backslashreplace")
            shown = text if len(text) <= 600 else text[:300] + f"\n... <{len(content)} bytes> ...\n" + text[-200:]
            body = "\n".join("      " + line for line in shown.splitlines())
            out.append(f"    {rel} ({len(content)} bytes):\n" + body)
        elif isinstance(content, hostile.Zip):
            out.append(f"    {rel}: zip of {', '.join(sorted(content.members))[:300]}")
        else:
            out.append(f"    {rel}: {content!r}")
    return out


def main(argv=None) -> int:
    """Run the campaign; exit status 1 when any case broke a promise."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", type=int, default=3000,
                        help="cases in total, shared evenly by the categories (default 3000)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the generators (default 0)")
    parser.add_argument("--seconds", type=float, default=None, help="wall-time budget (default: none)")
    parser.add_argument("--jobs", type=int, default=2, help="cases run at once (default 2)")
    parser.add_argument("--only", nargs="*", default=None,
                        help="categories to run (default: all but 'sizes', which designs plants of 20 to 80 states)")
    parser.add_argument("--workdir", default=None, help="sandboxes, failures and report (default: a temp folder)")
    parser.add_argument("--report", default=None, help="JSON report (default WORKDIR/report.json)")
    parser.add_argument("--keep-per-cause", type=int, default=2, help="failing sandboxes kept per cause (default 2)")
    args = parser.parse_args(argv)

    workdir = Path(args.workdir or tempfile.mkdtemp(prefix="uiofmu_fuzz_"))
    workdir.mkdir(parents=True, exist_ok=True)
    started = time.monotonic()
    print(f"uiofmu fuzz campaign: seed {args.seed}, {args.cases} cases in total, workdir {workdir}", flush=True)
    try:
        bases = hostile.build_bases(workdir / "bases")
    except RuntimeError as exc:
        print(f"cannot build the valid base inputs, nothing to fuzz: {exc}", file=sys.stderr)
        return 3
    groups = generate(bases, args.cases, args.seed, set(args.only) if args.only else None)
    cases = first_cases(groups, args.cases)
    print(f"  {len(cases)} cases in {len(groups)} categories, at most {-(-args.cases // max(1, len(groups)))} each "
          f"(bases built in {time.monotonic() - started:.0f} s)", flush=True)
    sandboxes = workdir / "cases"
    failures_dir = workdir / "failures"
    failures_dir.mkdir(exist_ok=True)
    deadline = started + args.seconds if args.seconds else None
    outcomes, lock = [], threading.Lock()
    kept = Counter()

    def one(index, case):
        if deadline and time.monotonic() > deadline:
            return None
        outcome = hostile.run_case(case, sandboxes, keep=True)
        root = outcome.root
        if outcome.ok:
            shutil.rmtree(root, ignore_errors=True)
        else:
            with lock:
                key = cause(*outcome.problems[0], outcome)
                kept[key] += 1
                keep = kept[key] <= args.keep_per_cause
            if keep:
                dest = failures_dir / f"{index:05d}_{re.sub(r'[^A-Za-z0-9_.-]+', '_', case.category)}"
                shutil.move(str(root), dest)
                outcome.root = dest
            else:
                shutil.rmtree(root, ignore_errors=True)
                outcome.root = None
        return outcome

    done = 0
    with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        futures = [pool.submit(one, i, c) for i, c in enumerate(cases)]
        for fut in as_completed(futures):
            outcome = fut.result()
            if outcome is None:
                continue
            outcomes.append(outcome)
            done += 1
            if done % 50 == 0:
                bad = sum(not o.ok for o in outcomes)
                print(f"  {done}/{len(cases)} cases, {bad} broke a promise, {time.monotonic() - started:.0f} s",
                      file=sys.stderr, flush=True)
    order = {id(c): i for i, c in enumerate(cases)}
    outcomes.sort(key=lambda o: order[id(o.case)])

    print()
    print(table(outcomes, list(groups)))
    skipped = len(cases) - len(outcomes)
    if skipped:
        print(f"\n{skipped} case(s) not run: the --seconds budget ran out")

    names = {blob: name for name, blob in bases.fmus.items()}
    by_cause = defaultdict(list)
    for o in outcomes:
        for kind, detail in o.problems:
            by_cause[cause(kind, detail, o)].append(o)
    if by_cause:
        print(f"\n{len(by_cause)} distinct failure(s), grouped by cause (smallest reproducer of each):")
    for n, (key, outs) in enumerate(sorted(by_cause.items(), key=lambda kv: (-len(kv[1]), kv[0])), 1):
        uniq = list({id(o): o for o in outs}.values())
        best = min(uniq, key=size_of)
        cats = Counter(o.case.category for o in uniq)
        print(f"\n[{n}] {key}")
        print(f"    {len(uniq)} case(s) in " + ", ".join(f"{c} ({k})" for c, k in cats.most_common()))
        print("    e.g. " + best.case.label[:300])
        for line in best.case.command_line():
            print("    $ " + line)
        for r in best.results:
            err = [line for line in r.err.strip().splitlines() if line.strip()]
            print(f"    -> {' '.join(map(str, r.argv[:1]))}: exit {r.code}"
                  f"{' (timeout)' if r.timed_out else ''}{f' (signal {r.signal})' if r.signal else ''}")
            for line in err[:2] + (["..."] + err[-1:] if len(err) > 3 else err[2:3]):
                print("       | " + line[:400])
        for kind, detail in best.problems:
            print(f"    !! {kind}: {detail[:300]}")
        print("\n".join(describe_files(best.case, names)))
        if getattr(best, "root", None):
            print(f"    kept in {best.root}")

    report = Path(args.report) if args.report else workdir / "report.json"
    data = {"seed": args.seed, "cases": len(cases), "seconds": time.monotonic() - started,
            "outcomes": [{"category": o.case.category, "label": o.case.label, "commands": o.case.command_line(),
                          "codes": [r.code for r in o.results], "timed_out": [r.timed_out for r in o.results],
                          "stderr": [r.err[-2000:] for r in o.results], "problems": o.problems,
                          "kept": str(getattr(o, "root", "") or "")} for o in outcomes],
            "causes": {k: len({id(o) for o in v}) for k, v in by_cause.items()}}
    report.write_text(json.dumps(data, indent=1) + "\n")
    bad = sum(not o.ok for o in outcomes)
    print(f"\n{len(outcomes)} cases in {time.monotonic() - started:.0f} s: {bad} broke a promise "
          f"({len(by_cause)} distinct cause(s)); report {report}")
    shutil.rmtree(sandboxes, ignore_errors=True)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
