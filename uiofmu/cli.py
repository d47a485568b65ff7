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
  uiofmu check    plants/two_room_building
  uiofmu design   plants/two_room_building -o out/building.json
  uiofmu build    out/building.json -o out/observer.fmu
  uiofmu plant    plants/two_room_building -o out/plant.fmu
  uiofmu validate out/observer.fmu
  uiofmu cosim    --plant out/plant.fmu --observer out/observer.fmu --steps dropout:600:0.3:11 --out out/run

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


def _cmd_build(args) -> int:
    from .card import read_card
    from .export import build_observer

    card = read_card(args.design)
    out = Path(args.output) if args.output else Path(f"{card.name}_observer.fmu")
    path = build_observer(card, out, backend=args.backend)
    print(f"{card.name}: {card.family} observer FMU ({args.backend} backend) written to {path}")
    return 0


def _cmd_plant(args) -> int:
    from .export import build_plant
    from .problem import load_problem

    problem = load_problem(args.problem)
    out = Path(args.output) if args.output else Path(f"{problem.name}_plant.fmu")
    path = build_plant(problem.plant, problem.name, out)
    print(f"{problem.name}: {problem.plant.time} plant FMU written to {path}")
    return 0


def print_summary(metrics: dict, paths: dict | None = None, file=None) -> None:
    """The co-simulation summary a person reads first."""
    file = file or sys.stdout
    p = lambda *a: print(*a, file=file)  # noqa: E731
    p(f"  steps                {metrics['steps']} (h from {metrics['step_min']:g} to {metrics['step_max']:g} s, "
      f"t_end = {metrics['t_end']:g} s)")
    p(f"  initial error        {metrics['initial_error_norm']:.6g}")
    p(f"  final error          {metrics['final_error_norm']:.6g}")
    k = metrics["steps_to_1pct"]
    p(f"  steps to 1 %         {k if k is not None else 'not reached'}"
      + (f" (t = {metrics['time_to_1pct']:g} s)" if k is not None else ""))
    if "bound_respected" in metrics:
        p(f"  certified bound      {metrics.get('bound_formula')}")
        p(f"                       decay {metrics['certified_decay']:.6g} per step, overshoot "
          f"{metrics['certified_overshoot']:.4g}")
        verdict = "yes" if metrics["bound_respected"] else f"NO (first at step {metrics['first_bound_violation']})"
        p(f"  bound respected      {verdict} at every step (largest ratio {metrics['max_bound_ratio']:.4g})")
    if "dhat_rms_error" in metrics:
        p("  dhat rms error       " + ", ".join(f"{v:.4g}" for v in metrics["dhat_rms_error_second_half"])
          + " (second half of the run)")
    for key, path in (paths or {}).items():
        p(f"  {key:20s} {path}")


def _cmd_cosim(args) -> int:
    from .cosim import (cosimulate, default_steps, default_t_end, load_inputs, observer_card, step_sequence,
                        write_outputs)

    card = observer_card(args.observer)
    spec = args.steps or default_steps(card)
    t_end = args.t_end
    if t_end is None:
        probe = step_sequence(spec, 100 * float(card.dt), seed=args.seed)
        t_end = default_t_end(card, probe)
    steps = step_sequence(spec, t_end, seed=args.seed)
    inputs = load_inputs(args.inputs, args.plant) if args.inputs else None
    result = cosimulate(args.plant, args.observer, steps, inputs)
    paths = write_outputs(result, args.out, title=f"{card.name}: {card.family} observer, steps {spec}")
    print(f"{card.name}: co-simulation of {Path(args.observer).name} against {Path(args.plant).name}")
    print_summary(result.metrics, paths)
    return 0


def _cmd_validate(args) -> int:
    from .errors import FmuError
    from .validate import validate

    report = validate(args.fmu, steps=args.steps, seed=args.seed)
    if args.json:
        print(json.dumps(report.to_data(), indent=2))
    else:
        print(f"{args.fmu}: {report.kind} FMU")
        print(f"  validate_fmu         {'no problem' if not report.problems else str(len(report.problems)) + ' problem(s)'}")
        for prob in report.problems:
            print(f"    - {prob}")
        if not report.problems:
            print(f"  against reference    {report.steps} random steps, largest difference {report.max_abs_diff:.3g} "
                  f"(relative {report.max_rel_diff:.3g}, tolerance {report.tolerance:g})")
    if not report.ok:
        what = report.problems[0] if report.problems else (
            f"largest relative difference {report.max_rel_diff:.3g} > {report.tolerance:g}")
        raise FmuError(f"{args.fmu} is not valid: {what}")
    return 0


def _cmd_demo(args) -> int:
    from .demo import run_demo

    metrics = run_demo(args.out)
    return 0 if metrics.get("bound_respected", True) else 1


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

    p = sub.add_parser("build", help="pack a design card as an FMI 2.0 Co-Simulation FMU",
                       description="Pack the observer of a design card as an FMI 2.0 Co-Simulation FMU with inputs "
                                   "y[i], u[i], outputs xhat[i], r[i] (and dhat[i]), parameter xhat0[i]. The "
                                   "python backend (pythonfmu) needs Python with numpy in the importing tool.")
    p.add_argument("design", help="design card (JSON) from `uiofmu design`")
    p.add_argument("-o", "--output", metavar="OBS.fmu", help="FMU path (default: NAME_observer.fmu)")
    p.add_argument("--backend", default="python", choices=["python"], help="FMU implementation (default: python)")
    p.set_defaults(func=_cmd_build)

    p = sub.add_parser("plant", help="pack the plant of a problem as an FMU (exact between communication points)",
                       description="Pack a problem's linear plant as an FMU with inputs u[i], d[i], outputs y[i] and "
                                   "the true state x[i], parameter x0[i]. A continuous plant is integrated exactly "
                                   "for any step (inputs held); a discrete plant accepts only steps of its dt.")
    p.add_argument("problem", help="problem file (TOML) or a plants/NAME folder")
    p.add_argument("-o", "--output", metavar="PLANT.fmu", help="FMU path (default: NAME_plant.fmu)")
    p.set_defaults(func=_cmd_plant)

    p = sub.add_parser("cosim", help="co-simulate a plant FMU and an observer FMU with aperiodic steps",
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       description="Run the plant and observer FMUs together (fmpy) and write DIR/results.csv, "
                                   "DIR/metrics.json and DIR/report.png.\n\nstep SPEC:\n"
                                   "  fixed:H              every step H seconds (default: the observer's dt)\n"
                                   "  choice:H1,H2,...     each step drawn uniformly from the list (--seed)\n"
                                   "  uniform:HMIN:HMAX    each step drawn uniformly from [HMIN, HMAX] (--seed)\n"
                                   "  dropout:H:P:MAX      nominal H, each sample lost with probability P, at most "
                                   "MAX in a row (--seed)\n"
                                   "  file:PATH            one step per line\n\n"
                                   "inputs: the [signals] of the observer's problem, or --inputs CSV with columns "
                                   "time,u[1],...,d[1],... (each row held from its time).")
    p.add_argument("--plant", required=True, metavar="P.fmu", help="plant FMU (inputs u, d; outputs y, x)")
    p.add_argument("--observer", required=True, metavar="O.fmu", help="observer FMU built by uiofmu")
    p.add_argument("--steps", metavar="SPEC", help="communication steps (see above)")
    p.add_argument("--t-end", type=float, metavar="T",
                   help="end time in s (default: until the certified bound falls to 1e-3, 50 to 5000 steps)")
    p.add_argument("--seed", type=int, default=0, help="seed of random step kinds (default 0)")
    p.add_argument("--inputs", metavar="CSV", help="input table instead of the problem's [signals]")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.set_defaults(func=_cmd_cosim)

    p = sub.add_parser("validate", help="fmpy's validate_fmu plus a self-test against the reference runtime",
                       description="Check an FMU built by uiofmu: fmpy's validate_fmu must report nothing, then "
                                   "the FMU runs side by side with the reference (runtime for observers, exact "
                                   "discretisation for plants) on random inputs and steps. Exit 2 on any problem.")
    p.add_argument("fmu", help="FMU built by uiofmu")
    p.add_argument("--steps", type=int, default=200, help="length of the random sequence (default 200)")
    p.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.set_defaults(func=_cmd_validate)

    p = sub.add_parser("demo", help="the main job: two-room building, sampled-data UIO, packet drop-outs",
                       description="Design the sampled-data UIO of the two-room building (seed 004) with the "
                                   "largest certified decay, build observer and plant FMUs, co-simulate two days "
                                   "with random packet drop-outs and report measured against certified convergence.")
    p.add_argument("--out", default="out/demo", metavar="DIR", help="output folder (default out/demo)")
    p.set_defaults(func=_cmd_demo)
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
