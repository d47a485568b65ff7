"""The command line loads only what a command uses: ``uiofmu --help`` neither numpy nor the runtime, and
``check``, ``design``, ``build`` and ``verify`` no optimiser, plotting, FMU importer or scheduler they do not
use (and ``check`` of a discrete plant no scipy). Measured on ``sys.modules`` in a fresh interpreter, not on a clock.

Its BLAS libraries (numpy's and scipy's OpenBLAS) start with one thread, unless the user chose a number,
and the environment is left as it was; ``import uiofmu`` and its API set no variable and start no library
with fewer threads than it would have (:mod:`uiofmu.threads`). Read off threadpoolctl and ``os.environ``."""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys

import pytest

from conftest import EXAMPLES, ROOT
from uiofmu.fmu.c_backend import c_compiler
from uiofmu.threads import REPRODUCIBLE_KERNELS

#: What no command of the default path may load.
NEVER = ("cvxpy", "scipy.optimize", "matplotlib", "fmpy", "dask", "distributed", "tqdm", "mujoco", "pythonfmu")

#: Runs ``uiofmu.cli.main`` on argv (its first argument, JSON) and prints the exit code and the modules loaded.
PROBE = """\
import json, sys
from uiofmu.cli import main
try:
    code = main(json.loads(sys.argv[1]))
except SystemExit as exc:
    code = exc.code
print(json.dumps({"code": code, "modules": sorted(sys.modules)}), file=sys.stderr)
"""


def loaded(*argv, cwd) -> set:
    """The modules a fresh interpreter holds after ``uiofmu ARGV`` (which must exit 0), for a user who set no
    BLAS thread variable (a test run may have one: Dask's workers set ``OMP_NUM_THREADS``, ``make test-blas``
    sets ``OPENBLAS_NUM_THREADS``; with one, scipy is imported up front)."""
    from uiofmu.threads import THREAD_VARIABLES

    env = {k: v for k, v in os.environ.items() if k not in THREAD_VARIABLES}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])
    proc = subprocess.run([sys.executable, "-c", PROBE, json.dumps([str(a) for a in argv])], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)
    report = json.loads(proc.stderr.strip().splitlines()[-1])
    assert report["code"] == 0, proc.stderr
    return set(report["modules"])


#: Runs ``uiofmu.cli.main`` on argv (its first argument, JSON) and prints the exit code, the number of threads of
#: every BLAS library loaded (after main: the number it started with, or the user's) and whether the environment
#: is the one the process had before main.
THREADS_PROBE = """\
import json, os, sys
import threadpoolctl        # first: its import sets KMP_DUPLICATE_LIB_OK (Intel's OpenMP), a default of its own
before = dict(os.environ)
from uiofmu.cli import main
code = main(json.loads(sys.argv[1]))
blas = [i for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"]
threads = {i["filepath"]: i["num_threads"] for i in blas}
kernels = {i["filepath"]: i["architecture"] for i in blas}
kept = dict(os.environ) == before
print(json.dumps({"code": code, "threads": threads, "kernels": kernels, "environment_kept": kept}), file=sys.stderr)
"""

#: The BLAS libraries' threads and the environment after ``import uiofmu`` and a check of Example 1 (the API), or
#: after importing numpy and scipy.linalg alone (its first argument ``"plain"``).
LIBRARY_PROBE = """\
import json, os, sys
import threadpoolctl
before = dict(os.environ)
if sys.argv[1] == "plain":
    import numpy, scipy.linalg
else:
    import uiofmu
    uiofmu.check(uiofmu.load_problem(sys.argv[2]))
blas = [i for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"]
threads = {i["filepath"]: i["num_threads"] for i in blas}
kernels = {i["filepath"]: i["architecture"] for i in blas}
print(json.dumps({"threads": threads, "kernels": kernels, "environment_kept": dict(os.environ) == before}),
      file=sys.stderr)
"""

#: Runs ``uiofmu check`` of its first argument through ``uiofmu.cli.main``, then ``uiofmu.check`` of it (the API),
#: and prints whether scipy.linalg was loaded after each.
AFTER_MAIN_PROBE = """\
import json, sys
import uiofmu
from uiofmu.cli import main
code = main(["check", sys.argv[1]])
by_main = "scipy.linalg" in sys.modules
uiofmu.check(uiofmu.load_problem(sys.argv[1]))
print(json.dumps({"code": code, "by_main": by_main, "by_api": "scipy.linalg" in sys.modules}), file=sys.stderr)
"""

#: The variables OpenBLAS reads for its number of threads (uiofmu.threads.THREAD_VARIABLES).
THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS")


def probe(script: str, *args, cwd, **variables) -> dict:
    """What ``script`` reports (its last line on stderr, JSON) in a fresh interpreter whose environment has no
    thread variable and no ``OPENBLAS_CORETYPE`` but ``variables``."""
    env = {k: v for k, v in os.environ.items() if k not in (*THREAD_VARIABLES, "OPENBLAS_CORETYPE")}
    env.update(variables, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.run([sys.executable, "-c", script, *map(str, args)], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stderr.strip().splitlines()[-1])


def unwanted(modules: set, names) -> list:
    """Those of ``names`` (or their submodules) among ``modules``."""
    return sorted(m for m in modules if any(m == n or m.startswith(n + ".") for n in names))


def test_help_loads_no_numpy(tmp_path):
    modules = loaded("--help", cwd=tmp_path)
    assert "uiofmu.cli" in modules
    assert not unwanted(modules, ("numpy", "scipy", "uiofmu.runtime", "threadpoolctl", *NEVER))


def test_design_help_lists_the_families(tmp_path):
    """The design command's description, written only when shown, still names every family."""
    from uiofmu.runtime.registry import FAMILIES

    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-m", "uiofmu", "design", "--help"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    text = " ".join(proc.stdout.split())
    assert all(name in text for name in FAMILIES), text


def test_check_design_verify_build_load_only_what_they_use(tmp_path):
    example = EXAMPLES / "seed000_example1.toml"
    card = tmp_path / "card.json"
    check = loaded("check", example, cwd=tmp_path)
    design = loaded("design", example, "-o", card, cwd=tmp_path)
    verify = loaded("verify", card, cwd=tmp_path)
    for name, modules in (("check", check), ("design", design), ("verify", verify)):
        assert not unwanted(modules, NEVER), (name, unwanted(modules, NEVER))
    assert "clarabel" in design and "uiofmu.synthesis" in verify          # the probe saw the work done
    assert not unwanted(check | verify, ("clarabel",))                  # no solve in check and verify
    assert "scipy.linalg" in design and not unwanted(check, ("scipy",))  # a discrete plant's check needs none


@pytest.mark.skipif(c_compiler() is None, reason="no C compiler for the C backend")
def test_build_loads_no_fmu_importer(tmp_path):
    card = tmp_path / "card.json"
    loaded("design", EXAMPLES / "seed000_example1.toml", "-o", card, cwd=tmp_path)
    modules = loaded("build", card, "-o", tmp_path / "observer.fmu", "--backend", "c", cwd=tmp_path)
    assert (tmp_path / "observer.fmu").is_file()
    assert not unwanted(modules, NEVER), unwanted(modules, NEVER)


def test_the_command_line_starts_its_blas_libraries_with_one_thread(tmp_path):
    """numpy's and scipy's OpenBLAS start with one thread in ``uiofmu design`` and ``verify``; the variable that
    does it is set around their imports only, so the process's environment (its children's) is the user's."""
    example, card = EXAMPLES / "seed000_example1.toml", tmp_path / "card.json"
    for argv in (["design", example, "-o", card], ["verify", card]):
        report = probe(THREADS_PROBE, json.dumps([str(a) for a in argv]), cwd=tmp_path)
        assert report["code"] == 0 and report["environment_kept"], (argv[0], report)
        assert len(report["threads"]) == 2, report["threads"]             # numpy's and scipy's
        assert set(report["threads"].values()) == {1}, (argv[0], report["threads"])


def test_the_command_line_keeps_the_users_number_of_threads(tmp_path):
    """A user's OPENBLAS_NUM_THREADS is the number the libraries start with (``make test-blas`` sets 2)."""
    plain = probe(LIBRARY_PROBE, "plain", cwd=tmp_path, OPENBLAS_NUM_THREADS="2")
    report = probe(THREADS_PROBE, json.dumps(["check", str(EXAMPLES / "seed000_example1.toml")]), cwd=tmp_path,
                   OPENBLAS_NUM_THREADS="2")
    assert report["code"] == 0 and report["environment_kept"], report
    assert report["threads"] == plain["threads"], (report["threads"], plain["threads"])


def test_import_uiofmu_sets_no_variable(tmp_path):
    """The library (``import uiofmu``, its API) sets no environment variable, and the BLAS libraries it loads
    start with the threads and on the kernel they start with in a plain ``import numpy, scipy.linalg``."""
    plain = probe(LIBRARY_PROBE, "plain", cwd=tmp_path)
    report = probe(LIBRARY_PROBE, "uiofmu", EXAMPLES / "seed000_example1.toml", cwd=tmp_path)
    assert plain["environment_kept"] and report["environment_kept"], (plain, report)
    assert report["threads"] == plain["threads"], (report["threads"], plain["threads"])
    assert report["kernels"] == plain["kernels"], (report["kernels"], plain["kernels"])


@pytest.mark.skipif(platform.machine() not in REPRODUCIBLE_KERNELS,
                    reason=f"no reproducible OpenBLAS kernel known for a {platform.machine()} machine")
def test_the_command_line_runs_on_one_blas_kernel(tmp_path):
    """``uiofmu design`` and ``verify`` load numpy's and scipy's OpenBLAS on the machine's reproducible kernel
    (the one a plain import loads with ``OPENBLAS_CORETYPE`` set to it), whatever kernel the CPU would have
    chosen, and leave the environment as it was."""
    kernel = REPRODUCIBLE_KERNELS[platform.machine()]
    pinned = probe(LIBRARY_PROBE, "plain", cwd=tmp_path, OPENBLAS_CORETYPE=kernel)["kernels"]
    example, card = EXAMPLES / "seed000_example1.toml", tmp_path / "card.json"
    for argv in (["design", example, "-o", card], ["verify", card]):
        report = probe(THREADS_PROBE, json.dumps([str(a) for a in argv]), cwd=tmp_path)
        assert report["code"] == 0 and report["environment_kept"], (argv[0], report)
        assert report["kernels"] == pinned, (argv[0], report["kernels"], pinned)


def test_a_program_that_loaded_numpy_keeps_its_kernel(tmp_path):
    """A program that imported numpy before it calls ``uiofmu.cli.main`` runs the command on numpy's kernel, scipy's
    loads on it too (one kernel in a process: a campaign's replay in it reproduces its workers' runs)."""
    plain = probe(LIBRARY_PROBE, "plain", cwd=tmp_path)["kernels"]
    report = probe("import numpy\n" + THREADS_PROBE, json.dumps(["design", str(EXAMPLES / "seed000_example1.toml"),
                                                                "-o", str(tmp_path / "card.json")]), cwd=tmp_path)
    assert report["code"] == 0 and report["environment_kept"], report
    assert report["kernels"] == plain, (report["kernels"], plain)


@pytest.mark.skipif(platform.machine() not in ("x86_64", "AMD64"), reason="Haswell is an x86-64 kernel")
def test_the_command_line_keeps_the_users_blas_kernel(tmp_path):
    """A user's ``OPENBLAS_CORETYPE`` is the kernel the command's libraries load with (``make test-blas``
    sets each in turn)."""
    plain = probe(LIBRARY_PROBE, "plain", cwd=tmp_path, OPENBLAS_CORETYPE="Haswell")["kernels"]
    report = probe(THREADS_PROBE, json.dumps(["design", str(EXAMPLES / "seed000_example1.toml"), "-o",
                                              str(tmp_path / "card.json")]), cwd=tmp_path, OPENBLAS_CORETYPE="Haswell")
    assert report["code"] == 0 and report["environment_kept"], report
    assert report["kernels"] == plain and set(plain.values()) == {"Haswell"}, (report["kernels"], plain)


#: The kernels of the BLAS libraries of a campaign's Dask worker, started as ``uiofmu campaign`` starts it (a
#: LocalCluster of one worker process within the command's start).
WORKER_PROBE = """\
import json, sys
from uiofmu.threads import start_with_one_thread

def kernels():
    import numpy, scipy.linalg, threadpoolctl
    return sorted(i["architecture"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas")

if __name__ == "__main__":
    with start_with_one_thread():
        from uiofmu.cosim.campaign.scheduler import start_client     # as the command imports it: after the start

        client, cluster = start_client(1, None)
        try:
            found = client.submit(kernels).result()
        finally:
            client.close()
            cluster.close()
    print(json.dumps({"kernels": found}), file=sys.stderr)
"""


@pytest.mark.skipif(platform.machine() not in REPRODUCIBLE_KERNELS,
                    reason=f"no reproducible OpenBLAS kernel known for a {platform.machine()} machine")
def test_a_campaigns_workers_run_on_the_commands_kernel(tmp_path):
    """The Dask workers a campaign starts load their BLAS libraries on the command's kernel too (their runs step
    observers with numpy)."""
    pinned = probe(LIBRARY_PROBE, "plain", cwd=tmp_path, OPENBLAS_CORETYPE=REPRODUCIBLE_KERNELS[platform.machine()])
    script = tmp_path / "workers.py"
    script.write_text(WORKER_PROBE)
    report = probe(f"import runpy; runpy.run_path({str(script)!r}, run_name='__main__')", cwd=tmp_path)
    assert report["kernels"] == sorted(pinned["kernels"].values()), (report, pinned)


def test_version_names_the_solver_and_the_blas_kernel(tmp_path):
    """``uiofmu --version``: the version first, then the numerical libraries' versions and each BLAS library's
    kernel, and who chose it."""
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_CORETYPE"}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])
    out = subprocess.run([sys.executable, "-m", "uiofmu", "--version"], cwd=tmp_path, env=env, capture_output=True,
                         text=True, timeout=300)
    lines = out.stdout.splitlines()
    assert out.returncode == 0 and lines[0].startswith("uiofmu "), out
    assert "clarabel " in lines[1] and "numpy " in lines[1], lines
    assert sum(line.strip().startswith("BLAS ") and ", kernel " in line for line in lines) == 2, lines
    kernel = REPRODUCIBLE_KERNELS.get(platform.machine())
    assert (f"OPENBLAS_CORETYPE={kernel} for uiofmu's commands" if kernel else "no kernel chosen") in lines[-1], lines


def test_a_program_that_runs_main_goes_on_as_a_library(tmp_path):
    """After ``uiofmu.cli.main`` returns, uiofmu imports scipy as a library does again: the API's check loads
    scipy.linalg first (to hold its OpenBLAS to one thread), where the command's own check needed none."""
    report = probe(AFTER_MAIN_PROBE, EXAMPLES / "seed000_example1.toml", cwd=tmp_path)
    assert report == {"code": 0, "by_main": False, "by_api": True}, report
