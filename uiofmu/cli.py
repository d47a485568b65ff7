"""The ``uiofmu`` command line: a thin layer over the Python API.

Exit codes: 0 success; 2 a problem the user can fix (one message on stderr, no traceback);
1 an internal error.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .errors import UserError

EPILOG = """\
typical session:
  uiofmu check  examples/seed000_example1.toml
  uiofmu design examples/seed000_example1.toml -o out/example1.json

exit codes: 0 success, 2 a problem you can fix (bad file or value, no observer exists,
infeasible LMI), 1 an internal error.
"""


def _cmd_check(args) -> int:
    from .problem import load_problem
    from .synthesis import check

    problem = load_problem(args.problem)
    report = check(problem)
    if args.json:
        print(json.dumps(report.to_data(), indent=2))
    else:
        print(f"{problem.name}: existence of a {problem.family} observer")
        for c in report.conditions:
            mark = "ok  " if c.holds else ("FAIL" if c.required else "note")
            print(f"  [{mark}] {c.message}")
        print("  => an observer exists" if report.exists else "  => no observer exists")
    report.require()
    return 0


def _cmd_design(args) -> int:
    from .problem import load_problem
    from .synthesis import design

    problem = load_problem(args.problem)
    card = design(problem)
    out = Path(args.output) if args.output else Path(f"{problem.name}.design.json")
    card.write(out)
    cert = card.data["certificate"]
    print(f"{problem.name}: {card.family} design written to {out}")
    for key in ("decay_bound", "overshoot_bound", "alpha"):
        if card.data.get(key) is not None:
            print(f"  {key:16s} {card.data[key]:.6g}")
    search = card.data.get("search")
    if search:
        print(f"  search           {search['parameter']} over {search['solves']} solves in {search['seconds']:.3f} s")
    print(f"  certificate      {'verified' if cert['verified'] else 'NOT verified'} "
          f"(CLARABEL {cert['status']}, solver {cert['solve_time_s'] * 1e3:.1f} ms, "
          f"construction {cert['setup_time_s'] * 1e3:.1f} ms)")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (also used to document the commands)."""
    parser = argparse.ArgumentParser(
        prog="uiofmu", formatter_class=argparse.RawDescriptionHelpFormatter, epilog=EPILOG,
        description="Design unknown-input observers from a TOML problem file, certify them, and ship them "
                    "as FMI 2.0 Co-Simulation FMUs.")
    from . import __version__
    parser.add_argument("--version", action="version", version=f"uiofmu {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    p = sub.add_parser("check", help="existence analysis: rank conditions, invariant zeros, detectability",
                       description="Check whether the problem's observer family exists: rank(CE) = rank(E), the "
                                   "invariant zeros of (A, E, C), detectability of the decoupled pair and its "
                                   "fixed modes (on the sampled plant for continuous plants). Exit 0 when an "
                                   "observer exists, 2 when not.")
    p.add_argument("problem", help="problem file (TOML) or a plants/NAME folder")
    p.add_argument("--json", action="store_true", help="print the conditions as JSON (name, holds, values)")
    p.set_defaults(func=_cmd_check)

    p = sub.add_parser("design", help="solve the LMI design, re-check the certificate, write the design card",
                       description="Solve the family's LMIs with CLARABEL, re-check the certificate with numpy "
                                   "at the stored matrices, and write the design card (JSON).")
    p.add_argument("problem", help="problem file (TOML) or a plants/NAME folder")
    p.add_argument("-o", "--output", metavar="DESIGN.json", help="card path (default: NAME.design.json)")
    p.set_defaults(func=_cmd_design)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``uiofmu`` console script."""
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except UserError as exc:
        print(f"uiofmu {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"uiofmu {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
