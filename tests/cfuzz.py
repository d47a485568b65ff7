"""Call-sequence fuzzing of the C observer FMU under AddressSanitizer and UBSan.

Builds the C FMU of each design (the three example problems, or cards given by path),
extracts its ``sources/``, compiles ``tests/c/fmu_fuzz.c`` together with the FMU's own C files
(``fmi2_plumbing.c``, ``kernel_affine.c``, ``design_data.c``; and the headers of the same
``sources/``) into one executable with ``-fsanitize=address,undefined -fno-sanitize-recover=all``, runs its
deterministic scenarios, then random sequences until the time is up, and prints one table:
family, sequences, calls, statuses returned, failed checks, sanitizer reports, crashes.

A sanitizer report ends the fuzzer process (nothing is recovered); the campaign records it,
and goes on with the next seed. Run as a script::

    python tests/cfuzz.py --seconds 600                       # all three families, 10 minutes
    python tests/cfuzz.py --seconds 30 --family sampled-data  # one of them
    python tests/cfuzz.py --seconds 600 --family all          # and the step-policy variants
    python tests/cfuzz.py --card my_card.json --seconds 60    # a card of your own
    python tests/cfuzz.py --runtime-rev a9d244b --seconds 60  # the C runtime of an older commit

The exit status is 0 when nothing was found, 1 otherwise.
"""

from __future__ import annotations

import argparse
import atexit
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import types
import uuid
import zipfile
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FUZZER = ROOT / "tests" / "c" / "fmu_fuzz.c"

#: The example problems each schedule kind is fuzzed with.
FAMILIES = {
    "lti-uio": ROOT / "examples" / "seed000_example1.toml",          # constant schedule
    "ltv-auid": ROOT / "examples" / "seed000_example1_ltv.toml",     # geometric schedule
    "sampled-data": ROOT / "plants" / "two_room_building" / "problem.toml",  # interval schedule
}

#: Variants of them with another step policy (the card's schedule.step_policy changed, so
#: another GUID): the interval schedule with 'nearest', the geometric one with 'count'.
VARIANTS = {"sampled-data-nearest": ("sampled-data", "nearest"), "ltv-auid-count": ("ltv-auid", "count")}

SANITIZER_FLAGS = ("-fsanitize=address,undefined,float-cast-overflow", "-fno-sanitize-recover=all",
                   "-fno-omit-frame-pointer", "-g", "-O1")
STATUSES = ("ok", "warning", "discard", "error", "fatal", "pending", "other")
SANITIZER_MARKS = ("ERROR: AddressSanitizer", "ERROR: LeakSanitizer", "runtime error:",
                   "SUMMARY: UndefinedBehaviorSanitizer")


@dataclass
class Target:
    """One fuzzer executable: a design's C runtime compiled with the fuzzer.

    Attributes
    ----------
    family : str
        The name in the table.
    exe : Path
        The sanitized executable.
    sources : Path
        The FMU's ``sources/`` it was compiled from.
    warnings : str
        What the compiler said (empty when nothing).
    fmu : Path or None
        The FMU the sources came from (None for the sources of a git revision).
    """

    family: str
    exe: Path
    sources: Path
    warnings: str = ""
    fmu: Path | None = None


@dataclass
class RunResult:
    """One fuzzer process.

    Attributes
    ----------
    returncode : int
        Its exit status (negative: killed by that signal).
    sequences, calls : int
        Sequences (or scenarios) run and FMI calls made.
    statuses : dict of str to int
        Statuses returned, all functions together.
    functions : dict of str to dict
        Calls and statuses per FMI function.
    failures : list of str
        The checks that failed (``FAIL ...`` lines).
    sanitizer : str or None
        The sanitizer report's key (its ``SUMMARY`` or ``runtime error`` line), if any.
    crashed : bool
        Ended by a signal or an unexplained exit status.
    scenarios : dict of str to str
        Scenario name to ``ok`` / ``FAIL`` (scenario runs).
    stdout, stderr : str
        What it printed.
    seconds : float
        Its wall time.
    """

    returncode: int
    sequences: int = 0
    calls: int = 0
    statuses: dict = field(default_factory=dict)
    functions: dict = field(default_factory=dict)
    failures: list = field(default_factory=list)
    sanitizer: str | None = None
    crashed: bool = False
    scenarios: dict = field(default_factory=dict)
    stdout: str = ""
    stderr: str = ""
    seconds: float = 0.0

    @property
    def clean(self) -> bool:
        """Exit 0, no failed check, no sanitizer report, no crash."""
        return self.returncode == 0 and not self.failures and not self.sanitizer and not self.crashed


@dataclass
class FamilyResult:
    """The campaign of one target: its scenario run and all its random runs.

    Attributes
    ----------
    family : str
        The target's name.
    scenario : RunResult or None
        The scenarios run in one process.
    scenario_each : list of RunResult
        Each scenario in a process of its own (only when the joint run was not clean, to count
        what it found past the first sanitizer report).
    runs : list of RunResult
        The random runs.
    """

    family: str
    scenario: RunResult | None = None
    scenario_each: list = field(default_factory=list)
    runs: list = field(default_factory=list)

    def all_runs(self) -> list:
        """Every run, scenarios first."""
        return ([self.scenario] if self.scenario else []) + self.scenario_each + self.runs

    @property
    def sanitizer_reports(self) -> list:
        """Keys of the sanitizer reports, one per process that had one."""
        return [r.sanitizer for r in self.all_runs() if r.sanitizer]

    @property
    def clean(self) -> bool:
        """Whether nothing was found."""
        return all(r.clean for r in self.all_runs())


# -- building ------------------------------------------------------------------------------

def design_family(name: str):
    """Design the example problem of one family.

    Parameters
    ----------
    name : str
        A key of :data:`FAMILIES` or :data:`VARIANTS`.

    Returns
    -------
    uiofmu.runtime.card.Card
    """
    import uiofmu

    if name in VARIANTS:
        base, policy = VARIANTS[name]
        return with_step_policy(design_family(base), policy)
    return uiofmu.design(uiofmu.load_problem(FAMILIES[name]))


def with_step_policy(card, policy: str):
    """The card with another ``schedule.step_policy`` (a design of its own: another GUID).

    Parameters
    ----------
    card : uiofmu.runtime.card.Card
        The design.
    policy : str
        ``"error"``, ``"nearest"`` or ``"count"``.

    Returns
    -------
    uiofmu.runtime.card.Card
    """
    from uiofmu.runtime.card import card_from_data

    data = json.loads(json.dumps(card.data))
    data["schedule"]["step_policy"] = policy
    return card_from_data(data)


def load_card(path):
    """A design card from its JSON file.

    Parameters
    ----------
    path : str or Path
        The card file.

    Returns
    -------
    uiofmu.runtime.card.Card
    """
    from uiofmu.runtime.card import read_card

    return read_card(path)


def _git_show(rev: str, path: str) -> str:
    proc = subprocess.run(["git", "-C", str(ROOT), "show", f"{rev}:{path}"], capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"git show {rev}:{path}: {proc.stderr.strip()}")
    return proc.stdout


def _git_files(rev: str, folder: str) -> list:
    proc = subprocess.run(["git", "-C", str(ROOT), "ls-tree", "--name-only", f"{rev}:{folder}"], capture_output=True,
                          text=True)
    return proc.stdout.split() if proc.returncode == 0 else []


#: Where the C runtime and its generator lived: (C folder, generator module, its package).
_RUNTIME_PLACES = (("uiofmu/fmu/c", "uiofmu/fmu/c_backend.py", "uiofmu.fmu"),
                   ("uiofmu/c", "uiofmu/export_c.py", "uiofmu"))


def _runtime_at(rev: str):
    """(C folder, runtime file names, generator module, its package) of the revision ``rev``: the
    C files and headers of the FMU runtime (not the C host or the pythonfmu guard)."""
    for folder, module, package in _RUNTIME_PLACES:
        names = [n for n in _git_files(rev, folder) if n.endswith((".c", ".h"))
                 and n not in ("fmu_host.c", "pythonfmu_guard.c")]
        if names:
            return folder, names, module, package
    raise RuntimeError(f"no C runtime at {rev} (looked in {', '.join(p[0] for p in _RUNTIME_PLACES)})")


def _design_source_at(rev: str, module_path: str, package: str):
    """``design_source`` as the revision ``rev`` of its module writes it (its runtime and header
    must match the struct it fills)."""
    module = types.ModuleType(f"{package}._design_source_at_{re.sub(r'[^A-Za-z0-9_]', '_', rev)}")
    module.__package__ = package
    module.__file__ = str(ROOT / module_path)
    exec(compile(_git_show(rev, module_path), f"{rev}:{module_path}", "exec"), module.__dict__)
    return module.design_source


def extract_sources(card, out_dir: Path, runtime_rev: str | None = None) -> Path:
    """The ``sources/`` of the C FMU of ``card``, in ``out_dir/sources``.

    Parameters
    ----------
    card : uiofmu.runtime.card.Card
        The design.
    out_dir : Path
        Where to build (the FMU is ``out_dir/observer.fmu``).
    runtime_rev : str, optional
        A git revision: take the C runtime (its ``.c`` and ``.h`` files) and ``design_source`` as
        they were there (to measure an older runtime); default: build the FMU as it is now and
        extract its ``sources/``.
    """
    from uiofmu.fmu.export import build_observer
    from uiofmu.fmu.c_backend import fmi_headers

    out_dir = Path(out_dir)
    src = out_dir / "sources"
    if src.exists():
        shutil.rmtree(src)
    if runtime_rev is None:
        fmu = build_observer(card, out_dir / "observer.fmu", backend="c")
        with zipfile.ZipFile(fmu) as z:
            for name in z.namelist():
                if name.startswith("sources/"):
                    z.extract(name, out_dir)
        return src
    src.mkdir(parents=True)
    folder, names, module, package = _runtime_at(runtime_rev)
    for name in names:
        (src / name).write_text(_git_show(runtime_rev, f"{folder}/{name}"))
    for name in ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h"):
        shutil.copy2(fmi_headers() / name, src / name)
    guid = str(uuid.uuid5(uuid.NAMESPACE_URL, "uiofmu:" + json.dumps(card.data, sort_keys=True)))
    (src / "design_data.c").write_text(_design_source_at(runtime_rev, module, package)(card, guid, "fuzzed_observer"))
    return src


_OBJECTS: dict = {}
_OBJECTS_LOCK = threading.Lock()
_OBJECT_DIR: list = []


def _object(cc: str, source: Path, src: Path, headers: tuple) -> Path:
    """``source`` compiled with the sanitizers against the headers in ``src``, once per process
    for the same text (the fuzzer, the plumbing and the kernel are the same for every design of a
    runtime)."""
    digest = hashlib.sha256(source.read_bytes())
    for name in headers:
        digest.update(name.encode() + b"\0" + (src / name).read_bytes())
    key = (cc, digest.hexdigest())
    with _OBJECTS_LOCK:
        if key not in _OBJECTS:
            if not _OBJECT_DIR:
                _OBJECT_DIR.append(Path(tempfile.mkdtemp(prefix="uiofmu_cfuzz_obj_")))
                atexit.register(shutil.rmtree, _OBJECT_DIR[0], True)
            obj = _OBJECT_DIR[0] / f"{source.stem}_{key[1][:16]}.o"
            cmd = [cc, "-std=c99", *SANITIZER_FLAGS, "-Wall", "-Wextra", *_legacy_flag(src), f"-I{src}", "-c", "-o",
                   str(obj), str(source)]
            proc = subprocess.run(cmd, capture_output=True, text=True)
            if proc.returncode != 0:
                raise RuntimeError(f"compiling {source.name} failed:\n{' '.join(cmd)}\n{proc.stderr[:4000]}")
            _OBJECTS[key] = (obj, proc.stderr.strip())
        return _OBJECTS[key]


def _legacy_flag(src: Path) -> list:
    """``-DUIOFMU_LEGACY_RUNTIME`` for a runtime of one file (``observer.c``, before the plumbing
    and the kernels were apart): the fuzzer then reads the GUID from its design struct."""
    return ["-DUIOFMU_LEGACY_RUNTIME"] if (Path(src) / "observer.c").is_file() else []


def runtime_sources(src: Path) -> list:
    """The runtime's C files in ``src`` (every ``*.c`` but the generated ``design_data.c``)."""
    return sorted(p for p in Path(src).glob("*.c") if p.name != "design_data.c")


def compile_fuzzer(src: Path, exe: Path, cc: str = "gcc") -> str:
    """Compile the fuzzer with the runtime in ``src`` into ``exe``.

    ``fmu_fuzz.c``, the runtime's C files (:func:`runtime_sources`) and ``design_data.c`` are
    compiled with
    ``-std=c99 -fsanitize=address,undefined,float-cast-overflow -fno-sanitize-recover=all -g -O1
    -Wall -Wextra`` against the headers of ``src`` and linked with ``-lm`` (objects of equal
    text and headers are compiled once per process).

    Parameters
    ----------
    src : Path
        An FMU's ``sources/`` (runtime, design data, FMI headers).
    exe : Path
        The executable to write.
    cc : str, optional
        The compiler (gcc: the sanitizer runtime and flags are gcc's).

    Returns
    -------
    str
        What the compiler said (empty when it said nothing).

    Raises
    ------
    RuntimeError
        When the compiler fails.
    """
    src = Path(src)
    headers = tuple(sorted(p.name for p in src.glob("*.h")))
    warnings = []
    objects = []
    for source in (FUZZER, *runtime_sources(src)):
        obj, said = _object(cc, source, src, headers)
        objects.append(obj)
        warnings.append(said)
    data = Path(exe).with_name("design_data.o")
    cmd = [cc, "-std=c99", *SANITIZER_FLAGS, "-Wall", "-Wextra", *_legacy_flag(src), f"-I{src}", "-c", "-o",
           str(data), str(src / "design_data.c")]
    for step in (cmd, [cc, *SANITIZER_FLAGS, "-o", str(exe), *map(str, objects), str(data), "-lm"]):
        proc = subprocess.run(step, capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"building the fuzzer failed:\n{' '.join(step)}\n{proc.stderr[:4000]}")
        warnings.append(proc.stderr.strip())
    return "\n".join(w for w in warnings if w)


def prepare(family: str, card, work: Path, runtime_rev: str | None = None) -> Target:
    """Build the fuzzer executable of one design.

    Parameters
    ----------
    family : str
        Its name in the table.
    card : uiofmu.runtime.card.Card
        The design.
    work : Path
        A directory of its own.
    runtime_rev : str, optional
        See :func:`extract_sources`.

    Returns
    -------
    Target
    """
    work = Path(work)
    work.mkdir(parents=True, exist_ok=True)
    src = extract_sources(card, work, runtime_rev)
    exe = work / "fmu_fuzz"
    warnings = compile_fuzzer(src, exe)
    fmu = work / "observer.fmu"
    return Target(family, exe, src, warnings, fmu if runtime_rev is None and fmu.is_file() else None)


# -- running -------------------------------------------------------------------------------

_NUMBER = re.compile(r"[-+]?(?:\d+(?:\.\d*)?(?:e[-+]?\d+)?|inf|nan)\b")


def _sanitizer_key(stderr: str) -> str | None:
    """What a sanitizer report is about, without its values: the kind and the first frame in
    the fuzzed code (``heap-buffer-overflow in pack kernel_affine.c:473``,
    ``kernel_affine.c:484: runtime error: N is outside the range of representable values of type
    'long int'``); None when there is no report."""
    if not any(mark in stderr for mark in SANITIZER_MARKS):
        return None
    lines = stderr.splitlines()
    for i, line in enumerate(lines):
        m = re.search(r"ERROR: (AddressSanitizer|LeakSanitizer): ([\w-]+)", line)
        if not m:
            continue
        for frame in lines[i + 1:]:
            f = re.match(r"\s+#\d+ 0x[0-9a-f]+ in (\S+) (\S+)", frame)
            if f and "libsanitizer" not in f.group(2) and "sanitizer_common" not in f.group(2):
                where = re.sub(r"^(.*?:\d+):\d+$", r"\1", Path(f.group(2)).name)  # file:line, no column
                return f"{m.group(1)}: {m.group(2)} in {f.group(1)} {where}"
        return f"{m.group(1)}: {m.group(2)}"
    for line in lines:
        m = re.search(r"([^\s/]+):(\d+):\d+: runtime error: (.*)", line)
        if m:
            return f"{m.group(1)}:{m.group(2)}: runtime error: {_NUMBER.sub('N', m.group(3))}"
    return "sanitizer report"


def _check_key(line: str) -> str:
    """A failed check without where it happened and its numbers (to count distinct ones)."""
    text = re.sub(r"^FAIL \[[^]]*\] ", "", line)
    text = re.sub(r" \(last log line: .*\)$", "", text)
    return _NUMBER.sub("N", text)


def parse_output(proc_returncode: int, stdout: str, stderr: str, seconds: float) -> RunResult:
    """A :class:`RunResult` from what a fuzzer process printed.

    Parameters
    ----------
    proc_returncode : int
        Its exit status.
    stdout, stderr : str
        Its output (counts on stdout; failed checks and sanitizer reports on stderr).
    seconds : float
        Its wall time.

    Returns
    -------
    RunResult
    """
    res = RunResult(proc_returncode, stdout=stdout, stderr=stderr, seconds=seconds)
    for line in stdout.splitlines():
        words = line.split()
        if not words:
            continue
        pairs = dict(w.split("=", 1) for w in words[1:] if "=" in w)
        if words[0] == "fuzz":
            res.sequences = int(pairs.get("sequences", 0))
            res.calls = int(pairs.get("calls", 0))
        elif words[0] == "statuses":
            res.statuses = {k: int(v) for k, v in pairs.items()}
        elif words[0] == "fn" and len(words) > 1:
            res.functions[words[1]] = {k: int(v) for k, v in pairs.items()}
        elif words[0] == "scenario" and len(words) == 3:
            res.scenarios[words[1]] = words[2]
    res.failures = [line for line in stderr.splitlines() if line.startswith("FAIL")]
    res.sanitizer = _sanitizer_key(stderr)
    res.crashed = proc_returncode < 0 and not res.sanitizer or (
        proc_returncode not in (0, 1) and not res.sanitizer)
    return res


def _env() -> dict:
    env = dict(os.environ)
    env["ASAN_OPTIONS"] = "detect_leaks=1:halt_on_error=1:abort_on_error=0:symbolize=1:" + env.get("ASAN_OPTIONS", "")
    env["UBSAN_OPTIONS"] = "print_stacktrace=1:halt_on_error=1:" + env.get("UBSAN_OPTIONS", "")
    return env


def run(target: Target, *args: str, timeout: float = 600.0) -> RunResult:
    """Run the fuzzer of one target.

    Parameters
    ----------
    target : Target
        The fuzzer executable.
    *args : str
        Its arguments (``random --seed 3 --seconds 5``, ``scenarios``).
    timeout : float, optional
        Seconds before the process is killed (a crash then).

    Returns
    -------
    RunResult
    """
    start = time.perf_counter()
    try:
        proc = subprocess.run([str(target.exe), *args], capture_output=True, text=True, timeout=timeout,
                              env=_env(), errors="replace")
        code, out, err = proc.returncode, proc.stdout, proc.stderr
    except subprocess.TimeoutExpired as exc:
        code = -9
        out = exc.stdout.decode("utf-8", "replace") if isinstance(exc.stdout, bytes) else (exc.stdout or "")
        err = (exc.stderr.decode("utf-8", "replace") if isinstance(exc.stderr, bytes) else (exc.stderr or ""))
        err += f"\n(timeout after {timeout} s)"
    return parse_output(code, out, err, time.perf_counter() - start)


def run_scenarios(target: Target, timeout: float = 120.0) -> RunResult:
    """The deterministic scenarios, all in one process.

    Parameters
    ----------
    target : Target
        The fuzzer executable.
    timeout : float, optional
        Seconds before the process is killed.

    Returns
    -------
    RunResult
    """
    return run(target, "scenarios", timeout=timeout)


def scenario_names(target: Target) -> list:
    """The scenarios the fuzzer knows.

    Parameters
    ----------
    target : Target
        The fuzzer executable.

    Returns
    -------
    list of str
    """
    proc = subprocess.run([str(target.exe), "list"], capture_output=True, text=True, env=_env())
    return proc.stdout.split()


def run_random(target: Target, seconds: float, seed: int = 1, sequences: int | None = None) -> RunResult:
    """One random run, ending after ``sequences`` sequences or ``seconds``, whichever comes first.

    Parameters
    ----------
    target : Target
        The fuzzer executable.
    seconds : float
        Its time.
    seed : int, optional
        The seed of its sequences.
    sequences : int, optional
        At most this many sequences.

    Returns
    -------
    RunResult
    """
    args = ["random", "--seed", str(seed), "--seconds", repr(float(seconds))]
    if sequences is not None:
        args += ["--iterations", str(int(sequences))]
    return run(target, *args, timeout=seconds + 120.0)


def fuzz_family(target: Target, seconds: float, seed: int = 1, sequences: int | None = None,
                chunk: float = 60.0) -> FamilyResult:
    """The campaign of one target: scenarios, then random runs until the time is up.

    When the scenario run is not clean, each scenario is run again in a process of its own (a
    sanitizer report ends a process, so this counts what the later scenarios find). A random
    run that a sanitizer ends is followed by one with the next seed.

    Parameters
    ----------
    target : Target
        The fuzzer executable.
    seconds : float
        Wall time of the random runs.
    seed : int, optional
        Seed of the first random run.
    sequences : int, optional
        At most this many random sequences in all.
    chunk : float, optional
        At most this many seconds per process.

    Returns
    -------
    FamilyResult
    """
    result = FamilyResult(target.family)
    result.scenario = run_scenarios(target)
    if not result.scenario.clean:  # count every scenario's findings, not only the first report
        for name in scenario_names(target):
            result.scenario_each.append(run(target, "scenarios", "--scenario", name, timeout=120.0))
    deadline = time.perf_counter() + seconds
    done = 0
    while True:
        left = deadline - time.perf_counter()
        if left <= 0.05 or (sequences is not None and done >= sequences):
            break
        res = run_random(target, min(left, chunk), seed, None if sequences is None else sequences - done)
        result.runs.append(res)
        done += res.sequences
        seed += 1
        if res.sequences == 0 and res.clean:
            break
    return result


def campaign(targets: list, seconds: float, jobs: int | None = None, seed: int = 1,
             sequences: int | None = None) -> list:
    """Fuzz every target for ``seconds`` of wall time each, ``jobs`` targets at a time.

    By default all targets run at once (sharing the CPUs), so the campaign takes about
    ``seconds`` plus the scenarios; with fewer jobs than targets, it runs in rounds.

    Parameters
    ----------
    targets : list of Target
        The fuzzer executables.
    seconds : float
        Wall time of each target's random runs.
    jobs : int, optional
        Targets at a time (default: all).
    seed : int, optional
        First seed (target i starts at ``seed + 1000 i``).
    sequences : int, optional
        At most this many random sequences per target.

    Returns
    -------
    list of FamilyResult
    """
    jobs = max(1, jobs or len(targets) or 1)
    with ThreadPoolExecutor(max_workers=jobs) as pool:
        futures = [pool.submit(fuzz_family, t, seconds, seed + 1000 * i, sequences) for i, t in enumerate(targets)]
        return [f.result() for f in futures]


# -- the table -----------------------------------------------------------------------------

def summary_table(results: list) -> str:
    """The campaign as a table, then what it found.

    One line per family: processes, sequences, calls, statuses returned, failed checks
    (distinct / all), sanitizer reports (distinct / processes ended by one), crashes, seconds;
    then each distinct sanitizer report with its count and the first kinds of failed checks.

    Parameters
    ----------
    results : list of FamilyResult
        What :func:`campaign` returned.

    Returns
    -------
    str
    """
    head = ("family", "runs", "sequences", "calls", *STATUSES[:5], "failed checks", "sanitizer", "crashes", "s")
    rows = []
    for r in results:
        runs = r.all_runs()
        statuses = {k: sum(x.statuses.get(k, 0) for x in runs) for k in STATUSES}
        reports = r.sanitizer_reports
        rows.append((r.family, len(runs), sum(x.sequences for x in runs), sum(x.calls for x in runs),
                     *(statuses[k] for k in STATUSES[:5]),
                     f"{len({_check_key(f) for x in runs for f in x.failures})}/{sum(len(x.failures) for x in runs)}",
                     f"{len(set(reports))}/{len(reports)}", sum(x.crashed for x in runs),
                     f"{sum(x.seconds for x in runs):.1f}"))
    widths = [max(len(str(v)) for v in col) for col in zip(head, *rows)]
    line = lambda vals: "  ".join(str(v).rjust(w) if i else str(v).ljust(w)  # noqa: E731
                                  for i, (v, w) in enumerate(zip(vals, widths)))
    out = [line(head), line(["-" * w for w in widths])] + [line(row) for row in rows]
    for r in results:
        seen = {}
        for key in r.sanitizer_reports:
            seen[key] = seen.get(key, 0) + 1
        for key, n in seen.items():
            out.append(f"{r.family}: sanitizer ({n}x) {key}")
        kinds = {}
        for x in r.all_runs():
            for f in x.failures:
                kinds.setdefault(_check_key(f), f)
        for f in list(kinds.values())[:12]:
            out.append(f"{r.family}: {f}")
        if len(kinds) > 12:
            out.append(f"{r.family}: ... {len(kinds) - 12} more kinds of failed checks")
        for x in r.all_runs():
            if x.crashed:
                out.append(f"{r.family}: crash, exit status {x.returncode}: {x.stderr.strip()[-300:]}")
    return "\n".join(out)


def main(argv=None) -> int:
    """The command line (see the module docstring).

    Parameters
    ----------
    argv : list of str, optional
        The arguments (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        0 when nothing was found, 1 otherwise.
    """
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=60.0, help="wall time of the random fuzzing of each family; "
                    "the families run at the same time (default 60)")
    ap.add_argument("--sequences", type=int, default=None, help="at most this many random sequences per family")
    ap.add_argument("--family", action="append", choices=sorted(FAMILIES) + sorted(VARIANTS) + ["all"],
                    help="fuzz this example (repeatable; default: the three of FAMILIES; 'all': those and the "
                    "step-policy VARIANTS)")
    ap.add_argument("--card", action="append", default=[], help="fuzz the design in this card file (repeatable)")
    ap.add_argument("--jobs", type=int, default=None, help="families fuzzed at a time (default: all)")
    ap.add_argument("--seed", type=int, default=1, help="first seed (default 1)")
    ap.add_argument("--runtime-rev", default=None, help="fuzz the C runtime and design_source as they are at "
                    "this git revision")
    ap.add_argument("--work", default=None, help="keep the builds in this directory")
    args = ap.parse_args(argv)
    families = args.family or ([] if args.card else list(FAMILIES))
    if "all" in families:
        families = list(FAMILIES) + list(VARIANTS)
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="uiofmu_cfuzz_"))
    t0 = time.perf_counter()
    targets = []
    try:
        for name in families:
            targets.append(prepare(name, design_family(name), work / name, args.runtime_rev))
        for i, path in enumerate(args.card):
            name = f"{Path(path).stem}"
            targets.append(prepare(name, load_card(path), work / f"card{i}_{name}", args.runtime_rev))
        for t in targets:
            if t.warnings:
                print(f"{t.family}: compiler warnings:\n{t.warnings}", file=sys.stderr)
        built = time.perf_counter() - t0
        results = campaign(targets, args.seconds, args.jobs, args.seed, args.sequences)
    finally:
        if not args.work:
            shutil.rmtree(work, ignore_errors=True)
    print(summary_table(results))
    print(f"built in {built:.1f} s, fuzzed in {time.perf_counter() - t0 - built:.1f} s"
          f"{' (runtime of ' + args.runtime_rev + ')' if args.runtime_rev else ''}")
    return 0 if all(r.clean for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
