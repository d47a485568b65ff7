"""CPU time of ``uiofmu design`` on the BLAS kernel the command line pins against the CPU's own, side by side.

    .venv/bin/python benchmarks/blas_kernel.py [--repeat 3]

The command line loads numpy's and scipy's OpenBLAS on one kernel (:data:`uiofmu.threads.REPRODUCIBLE_KERNELS`:
Prescott's on x86-64) so that a problem file gives the same answer on every CPU; this measures what that costs.
Every problem file of ``examples/`` that designs is designed in a fresh interpreter twice per round, alternately:
without ``OPENBLAS_CORETYPE`` (the pinned kernel) and with it set to the kernel OpenBLAS picks for this CPU (read
off threadpoolctl in a plain ``import numpy``). A first round, not counted, writes the bytecode and drops the
files that do not design. Prints one JSON document: the two kernels, each file's median CPU seconds (user +
system, from ``wait4``) on each, the median of the per-pair ratios pinned / own, and the ratio of the totals.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from cli_speed import THREAD_VARIABLES, cpu_of

ROOT = Path(__file__).resolve().parents[1]


def own_kernel(env: dict) -> str:
    """The kernel OpenBLAS picks for this CPU (numpy's library, no ``OPENBLAS_CORETYPE``)."""
    script = ("import numpy, threadpoolctl\n"
              "print(next(i['architecture'] for i in threadpoolctl.threadpool_info() if i['user_api'] == 'blas'))")
    return subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True,
                          check=True).stdout.strip()


def main(argv=None) -> int:
    """Measure and print the numbers."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args(argv)
    from uiofmu.threads import REPRODUCIBLE_KERNELS

    py = sys.executable
    env = {k: v for k, v in os.environ.items()
           if k not in (*THREAD_VARIABLES, "OPENBLAS_CORETYPE", "PYTHONDONTWRITEBYTECODE")}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])
    own = own_kernel(env)
    kernels = {"pinned": env, "own": {**env, "OPENBLAS_CORETYPE": own}}
    files = sorted((ROOT / "examples").glob("*.toml"))
    times = {f.name: {k: [] for k in kernels} for f in files}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for round_ in range(1 + args.repeat):
            for f in list(files):
                for kernel, kenv in kernels.items():
                    command = [py, "-m", "uiofmu", "design", str(f), "-o", str(tmp / "card.json")]
                    try:
                        took = cpu_of(command, tmp, kenv)
                    except SystemExit:                  # a problem that does not design (exit 2 by intent)
                        files.remove(f)
                        times.pop(f.name)
                        break
                    if round_:
                        times[f.name][kernel].append(took)
    med = {name: {k: statistics.median(v) for k, v in t.items()} for name, t in times.items()}
    pairs = [p / o for t in times.values() for p, o in zip(t["pinned"], t["own"])]
    total = {k: sum(m[k] for m in med.values()) for k in kernels}
    print(json.dumps({
        "repeat": args.repeat, "machine": platform.machine(),
        "kernels": {"pinned": REPRODUCIBLE_KERNELS.get(platform.machine()), "own": own},
        "cpu_s": med, "median_pair_ratio_pinned_over_own": statistics.median(pairs),
        "total_cpu_s": total, "total_ratio_pinned_over_own": total["pinned"] / total["own"],
    }, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
