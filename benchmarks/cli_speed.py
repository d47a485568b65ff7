"""CPU time of the command line's quick commands against a bare Python, side by side in one run.

    .venv/bin/python benchmarks/cli_speed.py [--repeat 7]

Each command runs in a fresh interpreter (``python -m uiofmu ...``), alternately, ``--repeat`` times;
its CPU time (user + system of the child and of what it waited for, from ``wait4``) is compared with
``python -c pass`` and with ``python -c "import numpy"`` (the floor of every command that touches a
matrix) measured in the same rounds. The commands: ``--help``, and ``check``, ``design``, ``verify`` and
``build --backend c`` (which also runs the C compiler) of seed 000 Example 1. Two more floors, with
``OPENBLAS_NUM_THREADS=1`` as the command line loads its BLAS libraries: ``import numpy``, the imports
of ``design`` from outside uiofmu (numpy, scipy.linalg, scipy.sparse, clarabel, threadpoolctl), and
CLARABEL solving one 2x2 semidefinite cone (the least any LMI design costs). Medians in
seconds; prints one JSON document with the goals of the quick command line (``design`` under 0.12 s,
``--help`` under 0.08 s).

The children run in the environment of the benchmark without the variables that set BLAS threads (the
defaults are measured) and without ``PYTHONDONTWRITEBYTECODE``: a first round, not counted, writes uiofmu's
bytecode, as an installed package has it, so that the rounds do not measure Python's compiler.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "seed000_example1.toml"

#: The variables OpenBLAS reads for its number of threads (uiofmu.threads.THREAD_VARIABLES).
THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS")

#: What ``uiofmu design`` of Example 1 imports from outside uiofmu.
DESIGN_IMPORTS = "import numpy, scipy.linalg, scipy.sparse, clarabel, threadpoolctl"

#: The least any LMI design costs: CLARABEL solving one 2x2 semidefinite cone (``t I >= [[0, 1], [1, 0]]``,
#: least ``t``). Its semidefinite cones take their LAPACK from scipy, so that solve imports scipy's package
#: (and with it what scipy's own start imports) even where the caller imported no scipy.
CLARABEL_SDP = ("import numpy as np, clarabel\n"
                "from scipy.sparse import csc_matrix\n"
                "s = clarabel.DefaultSettings(); s.verbose = False\n"
                "A = csc_matrix(-np.array([[1.0], [0.0], [1.0]]))\n"
                "b = np.array([0.0, -2.0 ** 0.5, 0.0])\n"
                "x = clarabel.DefaultSolver(csc_matrix((1, 1)), np.ones(1), A, b, [clarabel.PSDTriangleConeT(2)], s)"
                ".solve().x\n"
                "assert abs(x[0] - 1.0) < 1e-6, x\n")


def cpu_of(argv: list[str], cwd: Path, env: dict) -> float:
    """CPU seconds (user + system) of one child process and the processes it waited for."""
    proc = subprocess.Popen(argv, cwd=cwd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    err = proc.stderr.read().decode()
    proc.stderr.close()
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} exited {proc.returncode}: {err[-500:]}")
    return usage.ru_utime + usage.ru_stime


def main(argv=None) -> int:
    """Measure and print the numbers."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7)
    args = parser.parse_args(argv)
    py = sys.executable
    env = {k: v for k, v in os.environ.items() if k not in (*THREAD_VARIABLES, "PYTHONDONTWRITEBYTECODE")}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])
    one_thread = {**env, "OPENBLAS_NUM_THREADS": "1"}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        card = tmp / "card.json"
        cpu_of([py, "-m", "uiofmu", "design", str(EXAMPLE), "-o", str(card)], tmp, env)
        commands = {
            "python_pass": [py, "-c", "pass"],
            "python_import_numpy": [py, "-c", "import numpy"],
            "python_import_numpy_1_thread": [py, "-c", "import numpy"],
            "python_imports_of_design_1_thread": [py, "-c", DESIGN_IMPORTS],
            "python_clarabel_sdp_1_thread": [py, "-c", CLARABEL_SDP],
            "help": [py, "-m", "uiofmu", "--help"],
            "check": [py, "-m", "uiofmu", "check", str(EXAMPLE)],
            "design": [py, "-m", "uiofmu", "design", str(EXAMPLE), "-o", str(tmp / "again.json")],
            "verify": [py, "-m", "uiofmu", "verify", str(card)],
            "build_c": [py, "-m", "uiofmu", "build", str(card), "-o", str(tmp / "observer.fmu"), "--backend", "c"],
        }
        times: dict = {name: [] for name in commands}
        for round_ in range(1 + args.repeat):                 # the first round writes the bytecode
            for name, command in commands.items():
                took = cpu_of(command, tmp, one_thread if name.endswith("_1_thread") else env)
                if round_:
                    times[name].append(took)
    med = {name: statistics.median(v) for name, v in times.items()}
    bare, numpy_floor = med["python_pass"], med["python_import_numpy"]
    report = {
        "repeat": args.repeat, "cpu_s": med,
        "over_bare_python": {name: value / bare for name, value in med.items() if bare > 0},
        "over_numpy_import": {name: value / numpy_floor for name, value in med.items()},
        "goal_design_under_0_12_s": med["design"] < 0.12,
        "goal_help_under_0_08_s": med["help"] < 0.08,
    }
    print(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
