"""The ``uiofmu`` command line: a thin layer over the Python API.

Exit codes: 0 success; 2 a problem the user can fix (one message on stderr, no traceback);
1 an internal error.

Each command imports what it uses when it runs: ``uiofmu --help`` and the parser load neither numpy nor
the runtime package, and ``check``, ``design``, ``build`` and ``verify`` neither cvxpy, scipy.optimize,
matplotlib, fmpy nor dask (``tests/test_cli_imports.py``). numpy's and scipy's BLAS libraries start with
one thread unless the user chose a number (:func:`uiofmu.threads.start_with_one_thread`).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import warnings
from pathlib import Path

EPILOG = """\
typical session:
  uiofmu check    plants/two_room_building
  uiofmu design   plants/two_room_building -o out/building.json
  uiofmu build    out/building.json -o out/observer.fmu
  uiofmu plant    plants/two_room_building -o out/plant.fmu
  uiofmu validate out/observer.fmu
  uiofmu cosim    --plant out/plant.fmu --observer out/observer.fmu --steps dropout:600:0.3:11 --out out/run
  uiofmu report   out/run

exit codes: 0 success, 2 a problem you can fix (bad file or value, no observer exists,
infeasible LMI), 1 an internal error.

Inputs are data: problem files, design cards, step files and input tables are read only
when they are regular files of at most 64 MiB, never run as code; outputs are written
atomically (a failed command leaves an existing file as it was).
"""


def _cmd_check(args) -> int:
    from .problem import load_problem
    from .synthesis import check

    problem = load_problem(args.problem)
    report = check(problem)
    if args.json:
        print(json.dumps(report.to_data(), indent=2))
    else:
        order = getattr(problem.options, "order", "full")
        print(f"{problem.name}: existence of a {problem.family} observer"
              + ("" if order == "full" else f" of {order} order ({problem.plant.n - problem.plant.p} states)"))
        for line in check_summary(report):
            print(line)
    report.require()
    return 0


def check_summary(report) -> list[str]:
    """The lines ``uiofmu check`` prints under its first: each condition, then the verdict."""
    lines = []
    for c in report.conditions:
        mark = "ok  " if c.holds else ("FAIL" if c.required else "note")
        lines.append(f"  [{mark}] {c.message}")
        if c.hint and not c.holds:
            lines.append(f"         would help: {c.hint}")
    lines.append("  => an observer exists" if report.exists else "  => no observer exists")
    return lines


def _cmd_design(args) -> int:
    from .problem import load_problem
    from .runtime.files import check_output_file
    from .runtime.text import identifier
    from .synthesis import design

    problem = load_problem(args.problem)
    out = check_output_file(args.output or f"{identifier(problem.name)}.design.json", "design card")
    card = design(problem)
    card.write(out)
    print(f"{problem.name}: {card.family} design written to {out}")
    for line in design_summary(card):
        print(line)
    return 0


def _cmd_tradeoff(args) -> int:
    from .problem import load_problem
    from .progress import progress
    from .runtime.files import check_output_file
    from .runtime.text import identifier
    from .tradeoff import POINTS, tradeoff, write

    problem = load_problem(args.problem)
    out = check_output_file(args.output or f"{identifier(problem.name)}.tradeoff.png", "trade-off plot")
    points = POINTS if args.points is None else args.points
    with progress(total=3 + 2 * points, desc="designs", unit="design") as bar:
        result = tradeoff(problem, points, bar.update)
    png, table = write(result, out)
    print(f"{problem.name}: noise gain against decay, {len(result.points)} decays from the fastest certified one, "
          f"{result.fastest:.6g}: {png} (table: {table})")
    print(f"  {'decay':>10s}  {'gain_y default':>14s}  {'gain_y least':>12s}")
    text = lambda v: "-" if v is None else f"{v:.3g}"     # noqa: E731
    for p in result.points:
        print(f"  {p.decay:10.6g}  {text(p.gain_default):>14s}  {text(p.gain_least):>12s}")
    for label, (decay, gain) in result.marks.items():
        print(f"  {label}: decay {decay:.6g}, gain_y {text(gain)}")
    return 0


def design_summary(card, timing: bool = True) -> list[str]:
    """The lines ``uiofmu design`` prints under its first: bounds, formula, search, certificate, time.

    The bounds of a design at given tunables are optimal values of its LMIs, printed to the digits
    the solver's tolerance determines (the overshoot to the card's ``overshoot_digits``, 4 or 2):
    the same on every machine, like the verdict. The solver's own word (``optimal`` or
    ``optimal_inaccurate``) is printed only for a refused certificate: a verified one was re-checked
    without the solver, and that word moved with the BLAS kernel. The result of a ``"max"`` search
    (on the ``search`` line where no line above shows it: ltv-auid's ``mu``)
    is decided by optimal values (largest margins); where a plant's margin is lost in the solver's
    own noise over a range of values, the search ends somewhere in that range, and that value and
    the figures at it can differ between machines. The seconds always differ; so can the number of solves
    a search made (a margin near its threshold is decided twice, and which margins lie near it moves with
    the kernel, also where the search ends at the same value), the largest gain (:mod:`uiofmu.gains`) and
    the noise gains of an LMI design (:mod:`uiofmu.noise`), read off the solver's point: they are left out
    with ``timing=False`` (the warning about a large gain stays, and so do the noise gains of a
    closed-form design that the problem determines; one it does not is said to be left out,
    :func:`uiofmu.noise.noise_lines`).
    """
    from .certificate import overshoot_text
    from .gains import gain_lines
    from .noise import noise_design_lines, noise_lines

    lines, shown = [], []
    for key, digits in (("decay_bound", 6), ("overshoot_bound", 0), ("alpha", 6)):
        if card.data.get(key) is not None:
            text = overshoot_text(card.data) if key == "overshoot_bound" else f"{card.data[key]:.{digits}g}"
            lines.append(f"  {key:16s} {text}")
            shown.append(card.data[key])
    if card.data.get("order"):                    # a reduced-order observer: its state's size
        lines.append(f"  order            {card.data['order']} ({card.data['dims']['nz']} states, n = "
                     f"{card.data['dims']['n']})")
    if card.data.get("formula"):                  # a functional observer (window kernel)
        lines.append(f"  formula          {card.data['formula']}")
        lines.append(f"  window           {card.data['window']} outputs (r = {card.data['r']}, K = {card.data['K']}), "
                     f"gx is G x of {card.data['delay']} step(s) back")
    search = card.data.get("search")
    if search:
        found = card.data.get(search["parameter"])     # the value found, where no line above shows it (ltv-auid's mu)
        new = isinstance(found, (int, float)) and found not in shown
        lines.append(f"  search           {search['parameter']}" + (f" = {found:.6g}" if new else "")
                     + (f" over {search['solves']} solve(s) in {search['seconds']:.3f} s" if timing else ""))
    lines += gain_lines(card.data, figures=timing)
    lines += noise_lines(card.data, figures=timing)
    lines += noise_design_lines(card.data, figures=timing)
    cert = card.data["certificate"]
    if cert["verified"]:
        found = "re-checked at the stored matrices" + (", point from CLARABEL" if cert["solver"] == "CLARABEL" else "")
    else:
        found = f"CLARABEL {cert['status']}" if cert["solver"] == "CLARABEL" else cert["status"]
    lines.append(f"  certificate      {'verified' if cert['verified'] else 'NOT verified'} ({found})")
    if timing:
        t = card.data["timing"]
        rest = t["total_s"] - t["solver_s"] - t["lmi_assembly_s"]
        lines.append(f"  time             {t['total_s'] * 1e3:.1f} ms: CLARABEL {t['solver_s'] * 1e3:.1f} ms "
                     f"({t['solves']} solve(s)), LMI assembly {t['lmi_assembly_s'] * 1e3:.1f} ms, "
                     f"rest {rest * 1e3:.1f} ms")
    return lines


def _cmd_build(args) -> int:
    from .runtime.card import read_card
    from .runtime.files import check_output_file
    from .fmu.export import build_observer, choose_backend, model_identifier
    from .synthesis import recheck

    card = read_card(args.design)
    out = check_output_file(args.output or f"{model_identifier(card.name, 'observer')}.fmu", "FMU", ".fmu")
    recheck(card)
    backend, note = choose_backend(card, args.backend)
    if note:
        print(f"{card.name}: note: {note}")
    path = build_observer(card, out, backend=backend)
    print(f"{card.name}: {card.family} observer FMU ({backend} backend) written to {path}")
    return 0


def _cmd_verify(args) -> int:
    from .runtime.card import read_card
    from .synthesis import recheck

    card = read_card(args.design)
    checks = recheck(card)            # exit 2 naming the first claim that does not re-check
    print(f"{card.name}: every claim of the {card.family} card re-checks at its stored matrices, without a solver "
          f"({len(checks)} checks)")
    for c in checks:
        print(f"  [ok  ] {c.name} = {c.value:.6g} ({'<=' if c.at_most else '>='} {c.bound:.6g})")
    return 0


def _cmd_plant(args) -> int:
    from .fmu.export import build_plant, choose_backend, model_identifier, plant_kind
    from .mujoco_plant import build_mujoco_plant, is_mujoco_plant, load_spec
    from .problem import load_problem
    from .runtime.files import check_output_file

    if is_mujoco_plant(args.problem):
        spec = load_spec(args.problem)
        out = check_output_file(args.output or f"{model_identifier(spec.name, 'plant')}.fmu", "FMU", ".fmu")
        linearised = Path(args.problem) / "problem.toml"          # its observer's step, for the default experiment
        step = load_problem(linearised).options.step if linearised.is_file() else None
        backend, _ = choose_backend(None, args.backend)
        path = build_mujoco_plant(spec, out, step=step, backend=backend)
        print(f"{spec.name}: MuJoCo plant FMU ({spec.mujoco['integrator']}, substeps of {spec.mujoco['timestep']:g} s; "
              f"{backend} backend) written to {path}")
        return 0
    problem = load_problem(args.problem)
    out = check_output_file(args.output or f"{model_identifier(problem.name, 'plant')}.fmu", "FMU", ".fmu")
    backend, note = choose_backend(problem.plant, args.backend)
    if note:
        print(f"{problem.name}: note: {note}")
    path = build_plant(problem.plant, problem.name, out, step=problem.options.step, backend=backend,
                       experiment_steps=problem.experiment_steps, labels=problem.labels)
    print(f"{problem.name}: {problem.plant.time} {plant_kind(problem.plant)} FMU ({backend} backend) written to {path}")
    return 0


def _cmd_linearize(args) -> int:
    from .mujoco_plant import linearize, load_spec, problem_document
    from .problem import to_toml
    from .runtime.files import check_output_file, write_atomic

    spec = load_spec(args.plant)
    out = check_output_file(args.output or spec.folder / "problem.toml", "problem file")
    lin = linearize(spec)
    header = (f"Generated by `uiofmu linearize {args.plant}` from {spec.mujoco['model']}: the continuous model\n"
              f"at rest, from the MJCF's masses, springs, dampers and actuator moments; it agrees with finite\n"
              f"differences of MuJoCo's accelerations to {lin.mismatch:.1e} (relative).")
    write_atomic(out, to_toml(problem_document(spec, lin), header), "problem file")
    print(f"{spec.name}: linearised ({lin.A.shape[0]} states, {lin.B.shape[1]} known and {lin.E.shape[1]} unknown "
          f"inputs, {lin.C.shape[0]} outputs); parameter model against finite differences: {lin.mismatch:.2e} "
          f"relative; problem file written to {out}")
    return 0



def _cmd_cosim(args) -> int:
    from .cosim.master import (check_format, cosimulate, default_steps, default_t_end, load_inputs, observer_card,
                               step_sequence, write_outputs)
    from .cosim.noise import noises
    from .cosim.steps import short_spec
    from .cosim.summary import print_summary
    from .runtime.files import check_output_dir

    check_output_dir(args.out, "--out folder")
    check_format(args.format)
    card = observer_card(args.observer)
    spec = args.steps or default_steps(card)
    t_end = args.t_end if args.t_end is not None else default_t_end(card)
    steps = step_sequence(spec, t_end, seed=args.seed)
    inputs = load_inputs(args.inputs, args.plant, args.observer) if args.inputs else None
    noise = noises(args.noise)
    result = cosimulate(args.plant, args.observer, steps, inputs, noise=list(noise.values()),
                        native=not args.python_loop)
    paths = write_outputs(result, args.out, title=f"{card.name}: {card.family} observer, steps {short_spec(spec)}",
                          report=not args.no_report, fmt=args.format)
    print(f"{card.name}: co-simulation of {Path(args.observer).name} against {Path(args.plant).name}")
    print_summary(result.metrics, paths)
    return 0


def _cmd_ssp(args) -> int:
    import tempfile

    from .cosim.master import load_inputs
    from .cosim.ssp import write_ssp
    from .runtime.errors import ProblemError
    from .runtime.files import check_output_file

    pair = (args.plant, args.observer)
    if args.problem is not None and any(pair):
        raise ProblemError("give a PROBLEM or --plant and --observer, not both")
    if args.problem is None and not all(pair):
        raise ProblemError("give a PROBLEM (designed and built here) or both --plant P.fmu and --observer O.fmu")
    out = check_output_file(args.output, "SSP", ".ssp")
    with tempfile.TemporaryDirectory(prefix="uiofmu_ssp_") as tmp:
        if args.problem is not None:
            plant, observer = _loop_fmus(args.problem, Path(tmp))
        else:
            plant, observer = pair
        inputs = load_inputs(args.inputs, plant, observer) if args.inputs else None
        bundle = write_ssp(plant, observer, out, inputs)
    exp = bundle.experiment
    played = ", ".join(f"{k}[{v}]" for k, v in bundle.table.sizes.items()) or "nothing"
    print(f"SSP bundle written to {out}: source (plays {played}, {bundle.table.times.size} rows), plant, observer; "
          f"{len(bundle.connections)} connections by name; default experiment 0 to {exp['stopTime']:g} s, "
          f"step {exp['stepSize']:g} s ({bundle.steps} steps)")
    return 0


def _loop_fmus(problem_path, folder: Path) -> tuple:
    """Design the problem's observer and build it and its plant (default backends) into ``folder``."""
    from .fmu.export import build_observer, build_plant, choose_backend
    from .problem import load_problem
    from .synthesis import design

    problem = load_problem(problem_path)
    card = design(problem)
    observer = build_observer(card, folder / "observer.fmu", backend=choose_backend(card)[0])
    plant = build_plant(problem.plant, problem.name, folder / "plant.fmu", step=problem.options.step,
                        backend=choose_backend(problem.plant)[0], experiment_steps=problem.experiment_steps,
                        labels=problem.labels)
    print(f"{problem.name}: {card.family} observer designed, observer and plant FMUs built")
    return plant, observer


def _cmd_report(args) -> int:
    from .cosim.report import redraw

    path = redraw(args.run_dir, title=args.title)
    print(f"{args.run_dir}: report drawn again from its results table and metrics.json: {path}")
    return 0


def _cmd_campaign(args) -> int:
    from .cosim.campaign import load_campaign, replay, run_campaign
    from .cosim.steps import short_spec
    from .cosim.summary import print_summary
    from .runtime.files import check_output_dir

    campaign = load_campaign(args.spec)
    check_output_dir(args.out, "--out folder")
    if args.replay is not None:
        rep = replay(campaign, args.out, args.replay)
        print(f"{args.spec}: row {args.replay} replayed ({short_spec(rep['scenario']['steps'])}, seed "
              f"{rep['scenario']['steps_seed']}): {rep['status']}" + (f" ({rep['reason']})" if rep["reason"] else ""))
        if rep["metrics"] is not None:
            print_summary(rep["metrics"], rep["paths"])
        if rep["matches"] is not None:
            print("  campaign row         " + ("reproduced bit for bit" if rep["matches"] else "DIFFERS"))
        return 0 if rep["matches"] is not False else 1
    print(f"{args.spec}: campaign of {campaign.runs} runs")
    data = run_campaign(campaign, args.out, workers=args.workers, scheduler=args.scheduler, say=print)
    print(f"  finished             {data['finished']} runs in {data['elapsed_s']:.1f} s "
          f"({data['runs_per_s']:.2f} runs/s), {data['failures']} failure(s)")
    worst = data.get("worst_max_bound_ratio")
    if worst and worst["every_run_at_bound_start"]:
        print(f"  worst bound ratio    {worst['value']:.6g}, every run nearest its bound at k = 1 (the bound's "
              "start; at k = 0 the ratio is 1 / overshoot by construction)")
    elif worst:
        print(f"  worst bound ratio    {worst['value']:.6g} (row {worst['row']} at k = {worst['step']}, steps "
              f"{short_spec(worst['scenario']['steps'])})")
    for entry in data["failure_reasons"][:3]:
        print(f"  {entry['count']:>6} x {entry['status']:<8} {entry['kind'][:160]}")
        print(f"{'':17}e.g. row {entry['rows'][0]}: {entry['example'][:160]}")
    if len(data["failure_reasons"]) > 3:
        print(f"{'':17}{len(data['failure_reasons']) - 3} more kind(s) of failure in the summary")
    print(f"  table                {Path(args.out) / 'campaign.csv'}")
    print(f"  summary              {Path(args.out) / 'summary.json'}")
    print(f"  figure               {Path(args.out) / 'campaign.png'}")
    return 0


def _cmd_validate(args) -> int:
    from .runtime.errors import FmuError
    from .cosim.validate import validate

    report = validate(args.fmu, steps=args.steps, seed=args.seed)
    if args.json:
        print(json.dumps(report.to_data(), indent=2))
    else:
        print(f"{args.fmu}: {report.kind} FMU")
        found = f"{len(report.problems)} problem(s)" if report.problems else "no problem"
        print(f"  validate_fmu         {found}")
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


def _count(low: int):
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, found {text!r}") from None
        if value < low:
            raise argparse.ArgumentTypeError(f"expected an integer >= {low}, found {value}")
        return value
    return parse


def _seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, found {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a finite time > 0, found {text!r}")
    return value


class Parser(argparse.ArgumentParser):
    """argparse with the project's one-line errors (``uiofmu cosim: error: ...``, exit 2)."""

    def error(self, message):
        """Print one line naming the argument and exit with code 2."""
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")

    def format_help(self):
        """The help text; a description or an argument's help given as a function is written when the help
        is shown (so that the parser imports nothing it would need only for the help)."""
        if callable(self.description):
            self.description = self.description()
        for action in self._actions:
            if callable(action.help):
                action.help = action.help()
        return super().format_help()


def _add_check(sub) -> None:
    """The arguments of ``uiofmu check``."""
    p = sub.add_parser("check", help="existence analysis: rank conditions, invariant zeros, detectability",
                       description="Check whether the problem's observer family exists: rank(CE) = rank(E), the "
                                   "invariant zeros of (A, E, C), detectability of the decoupled pair and its "
                                   "fixed modes (on the sampled plant for continuous plants). Exit 0 when an "
                                   "observer exists, 2 when not.")
    p.add_argument("problem", help="problem file (TOML) or a plants/NAME folder")
    p.add_argument("--json", action="store_true", help="print the conditions as JSON (name, holds, values)")
    p.set_defaults(func=_cmd_check)


def _design_description() -> str:
    """The description of ``uiofmu design`` (the families' list needs the runtime package: written on demand)."""
    from .runtime.registry import summary

    return ("Solve the family's LMIs with CLARABEL, re-check the certificate with numpy at the stored matrices, and "
            "write the design card (JSON). A tunable set to \"max\" is searched from the limit the existence "
            "analysis gives. Prints the bounds, the search and where the time went (CLARABEL, LMI assembly, the "
            "rest); the card keeps the times under \"timing\". Families (observer.family): "
            f"{summary()}.")


def _add_design(sub) -> None:
    """The arguments of ``uiofmu design``."""
    p = sub.add_parser("design", help="solve the LMI design, re-check the certificate, write the design card",
                       description=_design_description)
    p.add_argument("problem", help="problem file (TOML) or a plants/NAME folder")
    p.add_argument("-o", "--output", metavar="DESIGN.json", help="card path (default: NAME.design.json)")
    p.set_defaults(func=_cmd_design)


def _points_help() -> str:
    """The help of ``tradeoff --points`` (its default is :mod:`uiofmu.tradeoff`'s: written when shown)."""
    from .tradeoff import POINTS

    return f"decays to design at, the fastest included (default {POINTS})"


def _add_tradeoff(sub) -> None:
    """The arguments of ``uiofmu tradeoff``."""
    p = sub.add_parser("tradeoff", help="plot the certified noise gain against the decay over the certified range",
                       description="Design the problem at decays from the fastest one its family certifies "
                                   "(decay = \"max\") toward 1, by default (least overshoot bound) and by least "
                                   "noise gain (observer.noise = \"min\"), each certified as `uiofmu design` "
                                   "certifies it, and plot the cards' gain_y (l2 gain from sensor noise to the "
                                   "estimation error) and overshoot bounds against the decay, with the problem's own "
                                   "design and its noise-optimal one marked. A CSV table with the same numbers is "
                                   "written next to the plot. lti-uio problems.")
    p.add_argument("problem", help="problem file (TOML) or a plants/NAME folder")
    p.add_argument("-o", "--output", metavar="TRADEOFF.png", help="plot path (default: NAME.tradeoff.png); the "
                                                                  "table goes next to it as .csv")
    p.add_argument("--points", type=int, metavar="N").help = _points_help      # written when shown
    p.set_defaults(func=_cmd_tradeoff)


def _add_build(sub) -> None:
    """The arguments of ``uiofmu build``."""
    p = sub.add_parser("build", help="pack a design card as an FMI 2.0 Co-Simulation FMU",
                       description="Pack the observer of a design card as an FMI 2.0 Co-Simulation FMU with inputs "
                                   "y[i], u[i], outputs xhat[i], r[i] (and dhat[i]), parameter xhat0[i] (and "
                                   "h_prev0 for observers scheduled on design intervals); a functional observer "
                                   "(family deadbeat-functional) has inputs y[i] (and theta[i]), outputs gx[i] and "
                                   "the Integer gx_valid[1]; a delayed observer (family delayed-uio) has inputs y[i], "
                                   "ydot[i], u[i], outputs xhat[i], thetahat[i], r[i], sigma_min[1] and the Integer "
                                   "valid[1]; a functional lti-uio observer (observer.functional) has inputs y[i], "
                                   "u[i] and the one output zhat[i], its estimate of Lf x.")
    p.add_argument("design", help="design card (JSON) from `uiofmu design`")
    p.add_argument("-o", "--output", metavar="OBS.fmu", help="FMU path (default: NAME_observer.fmu)")
    p.add_argument("--backend", choices=["c", "python"],
                   help="c: a standalone native binary with its sources (no Python needed by the importer; the "
                        "default when a C compiler is found); python: pythonfmu (the importer needs Python and numpy)")
    p.set_defaults(func=_cmd_build)


def _add_verify(sub) -> None:
    """The arguments of ``uiofmu verify``."""
    p = sub.add_parser("verify", help="re-check every claim of a design card, without a solver",
                       description="Re-check a design card someone gave you, as build and cosim do before they use "
                                   "it: that what its recorded problem determines (the plant matrices the FMU runs, "
                                   "the schedule, the stated bound, the figures derived from the certificate) is what "
                                   "the card says, the certificate's inequalities and identities at the stored "
                                   "matrices, and the bounds the card prints (decay_bound, overshoot_bound). Exit 0 "
                                   "when every claim holds, 2 naming the first that does not, with its numbers.")
    p.add_argument("design", help="design card (JSON)")
    p.set_defaults(func=_cmd_verify)


def _add_plant(sub) -> None:
    """The arguments of ``uiofmu plant``."""
    p = sub.add_parser("plant", help="pack the plant of a problem (or a MuJoCo plant folder) as an FMU",
                       description="Pack a problem's linear plant as an FMU with inputs u[i], d[i], outputs y[i] and "
                                   "the true state x[i], parameter x0[i]. A continuous plant is integrated exactly "
                                   "for any step (inputs held); a discrete plant accepts only steps of its dt. A "
                                   "folder with mujoco.toml gives a MuJoCo plant FMU (fixed substeps, a shorter last "
                                   "one so every step ends exactly on time; physical parameters settable). An LPV "
                                   "plant has the inputs d[i] (and theta[i] for [plant.theta] kind = \"input\"), "
                                   "outputs y[i], x[i] (and theta[i] = T x for kind = \"state\").")
    p.add_argument("problem", help="problem file (TOML) or a plants/NAME folder")
    p.add_argument("-o", "--output", metavar="PLANT.fmu", help="FMU path (default: NAME_plant.fmu)")
    p.add_argument("--backend", choices=["c", "python"],
                   help="linear plants: c, a standalone native binary with its sources (no Python needed by the "
                        "importer; the default when a C compiler is found); python: pythonfmu (the importer needs "
                        "Python and numpy). MuJoCo plants too: c links the mujoco wheel's libmujoco and ships it in "
                        "the FMU; python needs Python, numpy and mujoco where it runs")
    p.set_defaults(func=_cmd_plant)


def _add_linearize(sub) -> None:
    """The arguments of ``uiofmu linearize``."""
    p = sub.add_parser("linearize", help="linearise a MuJoCo plant folder into a problem file",
                       description="Compute the continuous (A, B, E, C) of a MuJoCo plant (folder with mujoco.toml) "
                                   "from the MJCF's parameters, cross-check them against finite differences of "
                                   "MuJoCo's accelerations, and write a problem file that `uiofmu design` takes.")
    p.add_argument("plant", help="MuJoCo plant folder (with mujoco.toml), e.g. plants/quarter_car")
    p.add_argument("-o", "--output", metavar="PROBLEM.toml", help="problem file (default: FOLDER/problem.toml)")
    p.set_defaults(func=_cmd_linearize)


def _add_cosim(sub) -> None:
    """The arguments of ``uiofmu cosim``."""
    p = sub.add_parser("cosim", help="co-simulate a plant FMU and an observer FMU with aperiodic steps",
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       description="Run the plant and observer FMUs together (fmpy) and write DIR/results.csv "
                                   "(or --format npz, parquet), "
                                   "DIR/metrics.json and DIR/report.png.\n\nstep SPEC:\n"
                                   "  fixed:H              every step H seconds (default: the observer's dt)\n"
                                   "  choice:H1,H2,...     each step drawn uniformly from the list (--seed)\n"
                                   "  uniform:HMIN:HMAX    each step drawn uniformly from [HMIN, HMAX] (--seed)\n"
                                   "  dropout:H:P:MAX      nominal H, each sample lost with probability P, at most "
                                   "MAX in a row (--seed)\n"
                                   "  file:PATH            one step per line\n\n"
                                   "signals are routed by name: each observer input named like a plant output (y) "
                                   "takes it; the plant's inputs and the observer's others (u, d, ...) come from the "
                                   "[signals] of the observer's problem, or from --inputs CSV with a column "
                                   "time and one per element of each of them (u[1],...,d[1],...; an unknown or "
                                   "missing column is an error), each row held from its time.")
    p.add_argument("--plant", required=True, metavar="P.fmu", help="plant FMU (inputs u, d; outputs y, x)")
    p.add_argument("--observer", required=True, metavar="O.fmu", help="observer FMU built by uiofmu")
    p.add_argument("--steps", metavar="SPEC",
                   help="communication steps (see above; default: the observer's dt, or a uniform choice of its "
                        "design intervals)")
    p.add_argument("--t-end", type=_seconds, metavar="T",
                   help="end time in s (default: until the certified bound falls to 1e-3, 50 to 5000 steps)")
    p.add_argument("--seed", type=_count(0), default=0, help="seed of random step kinds (default 0)")
    p.add_argument("--inputs", metavar="CSV", help="input table instead of the problem's [signals]")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--noise", action="append", metavar="SIGNAL=STD[,SEED]",
                   help="white Gaussian noise, seeded (default seed 0): y=STD adds it to the plant's outputs on "
                        "their way to the observer (STD one number, or [S1,S2,...] per output) and runs a "
                        "noise-free twin of the observer alongside, to measure the noise gain against the card's "
                        "noise.gain_y; w=STD (alone) feeds the plant's process-noise input w_noise (a problem "
                        "with [plant] W) and runs a noise-free twin of the whole loop, to measure the gain against "
                        "noise.gain_w. Once per signal")
    p.add_argument("--no-report", action="store_true",
                   help="do not draw DIR/report.png (saves matplotlib's import and the drawing)")
    p.add_argument("--format", default="csv", metavar="FORMAT",
                   help="results table: csv (default, DIR/results.csv), npz (numpy, DIR/results.npz) or parquet "
                        "(DIR/results.parquet, needs pyarrow); binary ones write a long run's table many times faster")
    p.add_argument("--python-loop", action="store_true",
                   help="step the FMUs from Python even where both have native binaries (by default a small C "
                        "loop, built once with the C compiler, makes their calls: the same results, bit for bit)")
    p.set_defaults(func=_cmd_cosim)


def _add_ssp(sub) -> None:
    """The arguments of ``uiofmu ssp``."""
    p = sub.add_parser("ssp", help="bundle plant, observer and a signal source as an SSP 1.0 file",
                       description="Write an SSP 1.0 file (SystemStructure.ssd and resources/*.fmu) with the plant, "
                                   "the observer and a C signal-source FMU that plays the problem's [signals] (at "
                                   "the communication points of the observer's default experiment) or the --inputs "
                                   "table as outputs; connected by name (y from the plant; u, d, mode, theta from "
                                   "the plant or the source), with the observer's default experiment. From a "
                                   "PROBLEM the observer is designed and both FMUs are built with the default "
                                   "backends. libcosim and other SSP importers run it; see docs/ssp.md for the "
                                   "order in which libcosim reads outputs.")
    p.add_argument("problem", nargs="?", help="problem file (TOML) or a plants/NAME folder with problem.toml")
    p.add_argument("-o", "--output", required=True, metavar="LOOP.ssp", help="the SSP file to write")
    p.add_argument("--plant", metavar="P.fmu", help="plant FMU (instead of a PROBLEM; with --observer)")
    p.add_argument("--observer", metavar="O.fmu", help="observer FMU built by uiofmu (instead of a PROBLEM)")
    p.add_argument("--inputs", metavar="CSV",
                   help="input table instead of the problem's [signals] (as uiofmu cosim --inputs: a column time "
                        "and one per element of each input no plant output feeds; each row held from its time)")
    p.set_defaults(func=_cmd_ssp)


def _add_report(sub) -> None:
    """The arguments of ``uiofmu report``."""
    p = sub.add_parser("report", help="draw a run's report.png again from its results.csv and metrics.json",
                       description="Draw RUN_DIR/report.png again from the RUN_DIR/results.csv and "
                                   "RUN_DIR/metrics.json that `uiofmu cosim --out RUN_DIR` wrote (with this "
                                   "version's figure: the numbers computed again from the table, the design's "
                                   "from metrics.json). The figure is replaced only when the new one is complete; "
                                   "a missing or malformed file exits 2 naming it.")
    p.add_argument("run_dir", metavar="RUN_DIR", help="the --out folder of `uiofmu cosim`")
    p.add_argument("--title", metavar="TEXT", help="the figure's title (default: the one in metrics.json)")
    p.set_defaults(func=_cmd_report)


def _add_campaign(sub) -> None:
    """The arguments of ``uiofmu campaign``."""
    p = sub.add_parser("campaign", help="many co-simulations on Dask: sampled scenarios, worst case, quantiles",
                       description="Run a validation campaign (a TOML file: the FMUs or a problem, the runs, "
                                   "the axes to sample; see README, Campaigns) on Dask: a LocalCluster of worker "
                                   "processes or an existing scheduler. Writes DIR/campaign.csv (one row per run), "
                                   "DIR/summary.json and DIR/campaign.png; --replay ROW re-runs one row alone into "
                                   "DIR/row-ROW and checks it against the table.")
    p.add_argument("spec", metavar="SPEC.toml", help="campaign file")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=_count(1), metavar="N",
                       help="worker processes of a new LocalCluster (default: the number of CPUs)")
    where.add_argument("--scheduler", metavar="ADDRESS", help="an existing Dask scheduler (tcp://host:8786)")
    p.add_argument("--replay", type=_count(0), metavar="ROW", help="re-run only this row")
    p.set_defaults(func=_cmd_campaign)


def _add_validate(sub) -> None:
    """The arguments of ``uiofmu validate``."""
    p = sub.add_parser("validate", help="fmpy's validate_fmu plus a self-test against the reference runtime",
                       description="Check an FMU built by uiofmu: fmpy's validate_fmu must report nothing, then "
                                   "the FMU runs side by side with the reference (the runtime for observers, "
                                   "functional ones on random y and theta; the exact discretisation for linear "
                                   "plants, the runtime for switched and LPV ones) on random inputs and steps. Exit "
                                   "2 on any problem.")
    p.add_argument("fmu", help="FMU built by uiofmu")
    p.add_argument("--steps", type=_count(1), default=200, help="length of the random sequence (default 200)")
    p.add_argument("--seed", type=_count(0), default=0, help="seed (default 0)")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.set_defaults(func=_cmd_validate)


def _add_demo(sub) -> None:
    """The arguments of ``uiofmu demo``."""
    p = sub.add_parser("demo", help="the main job: two-room building (seed 004), packet drop-outs",
                       description="Design the observer of the two-room building (seed 004, its problem file) with the "
                                   "largest certified decay, build observer and plant FMUs, co-simulate two days "
                                   "with random packet drop-outs and report measured against certified convergence.")
    p.add_argument("--out", default="out/demo", metavar="DIR", help="output folder (default out/demo)")
    p.set_defaults(func=_cmd_demo)


#: The subcommands' arguments, in the order ``uiofmu --help`` lists them.
_SUBCOMMANDS = (_add_check, _add_design, _add_tradeoff, _add_build, _add_verify, _add_plant, _add_linearize,
                _add_cosim, _add_ssp, _add_report, _add_campaign, _add_validate, _add_demo)


class VersionAction(argparse.Action):
    """``--version``: uiofmu's version, the versions of the numerical libraries its answers come from, and the
    BLAS kernel its commands run on (:func:`uiofmu.threads.reproducible_kernel`): what a report of a
    different answer on another machine needs."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest, nargs=0, default=default,
                         help=help or "show uiofmu's version, its solver's and the BLAS kernel its commands run on")

    def __call__(self, parser, namespace, values, option_string=None):
        from importlib.metadata import PackageNotFoundError, version

        from . import __version__
        from .threads import blas_libraries, reproducible_kernel, start_with_one_thread

        def installed(name):
            try:
                return version(name)
            except PackageNotFoundError:
                return "not installed"

        kernel = reproducible_kernel()
        with start_with_one_thread():
            blas = blas_libraries()
        chosen = (f"OPENBLAS_CORETYPE={kernel} for uiofmu's commands: the same kernel on every machine of "
                  f"this architecture" if kernel else
                  f"OPENBLAS_CORETYPE={os.environ['OPENBLAS_CORETYPE']}, set by the user" if
                  os.environ.get("OPENBLAS_CORETYPE") else "numpy's kernel, loaded before the command" if
                  "numpy" in sys.modules else "no kernel chosen on this architecture")
        lines = [f"uiofmu {__version__}",
                 "  " + ", ".join(f"{name} {installed(name)}" for name in ("numpy", "scipy", "cvxpy", "clarabel")),
                 *(f"  BLAS {b['library']} {b['version']}, kernel {b['kernel']}" for b in blas),
                 f"  ({chosen})"]
        print("\n".join(lines))
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (also used to document the commands)."""
    parser = Parser(
        prog="uiofmu", formatter_class=argparse.RawDescriptionHelpFormatter, epilog=EPILOG,
        description="Design unknown-input observers from a TOML problem file, certify them, and ship them "
                    "as FMI 2.0 Co-Simulation FMUs.")
    parser.add_argument("--version", action=VersionAction)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    parser.commands = sub.choices
    sub.required = True
    for add in _SUBCOMMANDS:
        add(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``uiofmu`` console script."""
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:
        parser.commands[args.command].error(f"unrecognized arguments: {' '.join(extra)[:200]}")
    try:
        from .threads import one_blas_thread, start_with_one_thread

        with warnings.catch_warnings(), start_with_one_thread():    # OpenBLAS starts with one thread
            # numbers that overflow become an exit-2 message of the step that meets them; numpy's
            # warnings on the way there would only add lines to it
            warnings.simplefilter("ignore", RuntimeWarning)
            with one_blas_thread():          # small matrices: a second BLAS thread only costs (uiofmu.threads)
                return args.func(args)
    except KeyboardInterrupt:
        print(f"uiofmu {args.command}: interrupted", file=sys.stderr)
        return 130
    except OSError as exc:
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"uiofmu {args.command}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # noqa: BLE001 - the last line of defence: one line, never a traceback
        if getattr(exc, "user_error", False):   # UserError, also from a runtime copy inside an FMU
            print(f"uiofmu {args.command}: error: {_one_line(exc)}", file=sys.stderr)
            return 2
        if os.environ.get("UIOFMU_TRACEBACK"):
            raise
        print(f"uiofmu {args.command}: internal error: {type(exc).__name__}: {_one_line(exc)} (a bug in uiofmu: "
              "please report it with the command and its input files; UIOFMU_TRACEBACK=1 shows where)",
              file=sys.stderr)
        return 1


def _one_line(exc: BaseException, limit: int = 2000) -> str:
    """An exception's message on one line (control characters shown escaped), at most ``limit`` characters."""
    text = " ".join(str(exc).split())
    text = "".join(ch if ch.isprintable() else ascii(ch)[1:-1] for ch in text)
    return text if len(text) <= limit else text[:limit] + "..."


if __name__ == "__main__":
    sys.exit(main())
