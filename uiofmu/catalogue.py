"""The FMU catalogue ``fmus/``: an observer FMU and its plant FMU for every example of every family.

``make fmus`` (``examples/build_fmus.py``, which calls :func:`main`) designs each example, builds its
observer and plant FMUs with the default backend (C where the C backend has the kernel, which is every
FMU of the catalogue; pythonfmu otherwise), checks every FMU's
``modelDescription.xml`` against the ports and ``<DefaultExperiment>`` its design declares, and runs:

* ``uiofmu validate`` (:func:`uiofmu.cosim.validate.validate`) on every FMU;
* fmpy's ``simulate_fmu`` on every FMU alone, with its ``<DefaultExperiment>``, to its stop time;
* every observer with its plant(s) in our master (:func:`uiofmu.cosim.master.cosimulate`) and in
  ecospy (a native Jacobi engine, when it is importable), over the observer's default experiment
  with the problem's ``[signals]``; ecospy's ``x`` and estimate must equal our master's to 1e-12
  except for the delayed UIO, whose ``ydot`` reaches the observer with the previous ``u`` in
  ecospy (the two loops agree exactly only for a constant ``u``; there ecospy must run to the end);
* every FMU alone in the FMU Compliance Checker and in fmusim (:func:`run_native_importers`), where
  they are found (:mod:`uiofmu.cosim.native_importers`), with no Python variable in their environment:
  0 errors, to the stop time. Their results go to the console only, never to the README, which must
  read the same on a machine without them.

It then writes ``fmus/README.md`` (:func:`render`): one table per family, one row per FMU, all
from the designed cards and the ports and experiments they declare (deterministic, numbers to 4
significant digits), and the checks each FMU passed, as ``make fmus`` ran them (the column
:func:`recorded_checks` reads back). Any failure makes the exit code 1.
"""

from __future__ import annotations

import argparse
import copy
import math
import re
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .certificate import UNDETERMINED, overshoot_text
from .plant_kinds import plant_kind
from .runtime.files import write_atomic
from .runtime.plant_kinds import MUJOCO
from .runtime.registry import FAMILIES as REGISTRY

#: The repository (the folder of ``examples/`` and ``plants/``) of an editable install.
ROOT = Path(__file__).resolve().parents[1]
#: The command that builds one example's row(s), ``--only KEY`` appended.
COMMAND = ".venv/bin/python examples/build_fmus.py"
#: What a default-experiment run of ecospy must match in our master (relative, and absolute
#: against the largest value).
ECOSPY_RTOL = 1e-12
#: The checks, in the order of the README's column.
CHECKS = ("validate", "master", "fmpy", "ecospy")
#: Families in the order of the README's sections, with a line on what each certifies (from the registry).
FAMILIES = {e.name: e.certifies for e in sorted(REGISTRY.values(), key=lambda e: e.section)}


@dataclass(frozen=True)
class Example:
    """One example of the catalogue: a problem file, or a variant of one.

    Attributes
    ----------
    key : str
        The problem's name (the FMUs are ``KEY_observer.fmu``, ``KEY_plant.fmu`` with ``-`` as ``_``);
        ``--only KEY`` builds this example alone.
    source : str
        The problem file, relative to the repository.
    observer : dict, optional
        Replaces the problem's ``[observer]`` table (a variant of the same plant; ``key`` is its name).
    steps : int, optional
        Runs of the plant this many steps long instead of the default experiments (a plant that
        cannot run them), with ``note`` saying why in the rows.
    note : str, optional
    """

    key: str
    source: str
    observer: dict | None = None
    steps: int | None = None
    note: str = ""


#: The LTV observer of the quarter-car, as ``examples/quarter_car.py`` designs it.
QUARTER_CAR_LTV = {"family": "ltv-auid", "dt": 0.01, "alpha": 0.95, "eta": 0.3, "mu": 1.0,
                   "xhat0": [0.0, 0.0, 0.0, 0.0]}

EXAMPLES = (
    Example("seed000-example1", "examples/seed000_example1.toml"),
    Example("accelerometer-feedthrough", "examples/accelerometer_feedthrough.toml"),
    Example("pole-placement", "examples/pole_placement.toml"),
    Example("reduced-order-carts", "examples/reduced_order.toml"),
    Example("functional-uio", "examples/functional_uio.toml"),
    Example("seed000-example1-ltv", "examples/seed000_example1_ltv.toml"),
    Example("two-room-building", "plants/two_room_building/problem.toml"),
    Example("quarter-car", "plants/quarter_car/problem.toml"),
    Example("quarter-car-ltv", "plants/quarter_car/problem.toml", QUARTER_CAR_LTV),
    Example("seed002-setup2", "examples/seed002_setup2.toml"),
    Example("seed002-three-modes", "examples/seed002_three_modes.toml"),
    Example("seed003-example", "examples/seed003_example.toml",
            note="the plant, the nonlinear system (17), is unstable: its problem file's [experiment] steps = 12 "
                 "sets the FMUs' default experiments to 12 steps"),
    Example("seed003-needs-theta", "examples/seed003_needs_theta.toml"),
    Example("fouka-example", "examples/seed001_example.toml"),
)
#: The MuJoCo plant: its folder, its key, and the examples whose observers run with it.
MUJOCO_FOLDER = "plants/quarter_car"
MUJOCO_KEY = "quarter-car-mujoco"
MUJOCO_FILE = "quarter_car_mujoco_plant.fmu"
MUJOCO_OBSERVERS = ("quarter-car", "quarter-car-ltv")


@dataclass(frozen=True)
class Port:
    """A port as the README shows it: ``name[1..size]`` of one FMI type."""

    name: str
    size: int
    type: str

    def text(self) -> str:
        """```y[1..3]` Real``."""
        index = "1" if self.size == 1 else f"1..{self.size}"
        return f"`{self.name}[{index}]` {self.type}"


@dataclass
class Row:
    """One FMU of the catalogue, everything but the checks from its design (deterministic).

    Attributes
    ----------
    file : str
        The ``.fmu`` file in ``fmus/``.
    role : {"observer", "plant"}
    family : str
        The section: the observer's family (a plant's is its observer's; the MuJoCo plant's ``mujoco``).
    key : str
        The ``--only`` key that builds it.
    backend : str
        ``C``, or ``python`` with the reason.
    partners : list of str
        The FMUs it runs with (plants of an observer, observers of a plant).
    parameters, inputs, outputs : list of Port
        The declared ports with at least one variable.
    steps : str
        The communication steps it accepts.
    experiment : dict or None
        Its ``<DefaultExperiment>`` (``startTime``, ``stopTime``, ``stepSize``).
    certified : str
        The certified bound (or what the family certifies instead).
    connect : str
        For an observer: which of its inputs come from the plant and which the user sets.
    limited : dict
        ``{check: steps}`` for the checks run shorter than the default experiment.
    note : str
        Why (shown with the DefaultExperiment).
    """

    file: str
    role: str
    family: str
    key: str
    backend: str
    partners: list
    parameters: list
    inputs: list
    outputs: list
    steps: str
    experiment: dict | None
    certified: str
    connect: str = ""
    limited: dict = field(default_factory=dict)
    note: str = ""


@dataclass
class Design:
    """An example designed: its problem, card, and the rows of its two FMUs."""

    example: Example
    problem: object
    card: object
    observer: Row
    plant: Row


@dataclass
class Catalogue:
    """The designs of every example (or of those asked for) and the MuJoCo plant's row."""

    designs: list
    mujoco: Row | None = None
    checks: dict = field(default_factory=dict)

    @property
    def rows(self) -> list:
        """Every row, in the README's order: per family, each example's observer then plant."""
        out = []
        for family in [*FAMILIES, MUJOCO.name]:
            for d in self.designs:
                if d.observer.family == family:
                    out += [d.observer, d.plant]
            if family == MUJOCO.name and self.mujoco is not None:
                out.append(self.mujoco)
        return out

    def pairs(self) -> list:
        """``(observer row, plant row)`` of every run of two FMUs."""
        out = [(d.observer, d.plant) for d in self.designs]
        if self.mujoco is not None:
            out += [(d.observer, self.mujoco) for d in self.designs if d.example.key in MUJOCO_OBSERVERS]
        return out


# ------------------------------------------------------------------ numbers and text


def num(x: float) -> str:
    """``x`` to 4 significant digits, shortest form (``600000``, ``1.292``, ``4.449e-05``).

    Parameters
    ----------
    x : float

    Returns
    -------
    str
    """
    x = float(x)
    if x == 0 or not math.isfinite(x):
        return f"{x:g}"
    return f"{float(f'{x:.4g}'):g}"


_DECIMAL = re.compile(r"(?<![\w.])\d+\.\d+(?:e[+-]?\d+)?|(?<![\w.])\d+e[+-]?\d+")


def round_text(text: str) -> str:
    """Every decimal number of ``text`` to 4 significant digits (integers and names stay)."""
    return _DECIMAL.sub(lambda m: num(float(m.group(0))), text)


def cell(text: str) -> str:
    """``text`` for a Markdown table cell: pipes escaped, one line."""
    return " ".join(str(text).split()).replace("|", "\\|")


def file_name(name: str, role: str) -> str:
    """The catalogue's file of an FMU: its model identifier plus ``.fmu``."""
    from .fmu.export import model_identifier

    return model_identifier(name, role) + ".fmu"


# ------------------------------------------------------------------ rows from the designs


def _ports(specs, causality: str) -> list:
    return [Port(s.name, s.size, s.type) for s in specs if s.causality == causality and s.size > 0]


def _observer_steps(card) -> str:
    s = card.schedule
    kind, policy = s["kind"], s.get("step_policy", "error")
    if kind == "interval":
        text = "each step one of " + ", ".join(num(h) for h in s["intervals"]) + " s, in any sequence"
        return text + ("" if policy == "error" else f" (another: the nearest, policy {policy})")
    if kind == "continuous":
        return f"any h > 0 (default {num(s['step'])} s; RK4 substeps of at most {num(s['max_substep'])} s)"
    text = f"h = {num(s['dt'])} s only"
    if kind == "geometric" and policy == "count":
        text = f"any h, each counted as one step of {num(s['dt'])} s"
    if kind == "mode":
        text += f"; the Integer input `mode` 1..{s['modes']} each step"
    return text


def _certified(card) -> str:
    d = card.data
    text = d.get("bound") or ""
    decay, over = d.get("decay_bound"), None
    if decay is not None and d.get("overshoot_bound") is not None:
        # an overshoot the problem does not determine is named, not given: its digits are the solver's point's
        over = "K" if d.get("overshoot_digits") == UNDETERMINED else overshoot_text(d)
        if decay < 1e-9:
            text = text.replace("decay_bound**k", "δ^k").replace("overshoot_bound", over)
            text += " with δ < 1e-9: dead-beat (the error is zero after one step, to rounding)"
        elif "decay_bound" in text:
            text = text.replace("overshoot_bound", over).replace("decay_bound**k", f"{num(decay)}^k")
        else:
            text += f"; decay_bound {num(decay)}, overshoot_bound {over}"
    if over == "K":
        text += "; K from its card (the problem does not determine it)"
    if d.get("formula"):
        text += f"; formula {d['formula']}"
    return round_text(text)


def _plant_steps(plant) -> str:
    if plant.time == "discrete":
        return f"h = {num(plant.dt)} s only"
    return "any h > 0 (exact between points)" if plant_kind(plant).exact else "any h > 0 (RK4 substeps)"


def _connect(observer: Row, plant: Row) -> str:
    plant_out = {p.name for p in plant.outputs}
    plant_in = [p.name for p in plant.inputs]
    fed = [p for p in observer.inputs if p.name in plant_out]
    mine = [p.name for p in observer.inputs if p.name not in plant_out]
    text = "from the plant: " + ", ".join(f"`{p.name}`" for p in fed) if fed else "nothing from the plant"
    sets = [f"`{n}` (both)" for n in mine if n in plant_in] + [f"`{n}` (observer)" for n in mine if n not in plant_in]
    sets += [f"`{n}` (plant)" for n in plant_in if n not in mine and n not in {p.name for p in fed}]
    return text + ("; set by you: " + ", ".join(sets) if sets else "")


def load_example(example: Example, root=ROOT):
    """The problem of an example (its file, with its ``[observer]`` replaced for a variant).

    Parameters
    ----------
    example : Example
    root : str or Path, optional
        The repository.

    Returns
    -------
    Problem
    """
    from .problem import load_problem, problem_from_data

    problem = load_problem(Path(root) / example.source)
    if example.observer is not None:
        doc = copy.deepcopy(problem.data)
        doc["name"], doc["observer"] = example.key, copy.deepcopy(example.observer)
        problem = problem_from_data(doc)
    if problem.name != example.key:
        raise ValueError(f"{example.source}: the problem is named {problem.name!r}, the catalogue expects "
                         f"{example.key!r}")
    return problem


def design_example(example: Example, root=ROOT) -> Design:
    """Design an example and describe its two FMUs (no FMU is built).

    Parameters
    ----------
    example : Example
    root : str or Path, optional

    Returns
    -------
    Design
    """
    from .fmu.c_backend import c_refusal
    from .runtime.fmu_model import make_model
    from .runtime.ports import observer_experiment, plant_experiment
    from .synthesis import design

    problem = load_example(example, root)
    card = design(problem)
    ofile, pfile = file_name(problem.name, "observer"), file_name(problem.name, "plant")
    specs = card.ports
    observer = Row(ofile, "observer", card.family, example.key,
                   "python (no C kernel for this family)" if c_refusal(card) else "C", [pfile],
                   _ports(specs, "parameter"), _ports(specs, "input"), _ports(specs, "output"),
                   _observer_steps(card), observer_experiment(card), _certified(card))
    plant_specs = [p.spec for p in make_model({"kind": "plant", "plant": problem.plant.to_data()}).ports]
    step = problem.options.step or problem.plant.dt
    plant = Row(pfile, "plant", card.family, example.key,
                "python (no C kernel for this plant)" if c_refusal(problem.plant) else "C", [ofile],
                _ports(plant_specs, "parameter"), _ports(plant_specs, "input"), _ports(plant_specs, "output"),
                _plant_steps(problem.plant),
                plant_experiment(step, problem.experiment_steps) if step else None,
                "— (the plant: its `x` is the truth the checks compare with)")
    observer.connect = _connect(observer, plant)
    if example.steps:
        observer.limited = {"master": example.steps, "ecospy": example.steps}
        plant.limited = {**observer.limited, "fmpy": example.steps}
        observer.note = plant.note = example.note
    return Design(example, problem, card, observer, plant)


def mujoco_row(root=ROOT) -> Row:
    """The row of the MuJoCo quarter-car plant (its spec loaded, no FMU built).

    Parameters
    ----------
    root : str or Path, optional

    Returns
    -------
    Row
    """
    from .mujoco_plant import load_spec
    from .problem import load_problem
    from .runtime.fmu_model import make_model
    from .runtime.ports import plant_experiment

    spec = load_spec(Path(root) / MUJOCO_FOLDER)
    specs = [p.spec for p in make_model({"kind": MUJOCO.fmu_kind, MUJOCO.key: spec.mujoco}, str(spec.folder)).ports]
    step = load_problem(Path(root) / MUJOCO_FOLDER / "problem.toml").options.step
    return Row(MUJOCO_FILE, "plant", MUJOCO.name, MUJOCO_KEY, "C",
               [file_name(k, "observer") for k in MUJOCO_OBSERVERS],
               _ports(specs, "parameter"), _ports(specs, "input"), _ports(specs, "output"),
               f"any h > 0 (MuJoCo RK4 substeps of {num(spec.mujoco['timestep'])} s)", plant_experiment(step),
               "— (the plant the observers were designed from, by linearisation: a model mismatch floor)")


def describe(root=ROOT, only: str | None = None) -> Catalogue:
    """Design every example (or the one ``only`` names) and describe their FMUs.

    Parameters
    ----------
    root : str or Path, optional
    only : str, optional
        An example's key, or :data:`MUJOCO_KEY` (the MuJoCo plant and the observers it runs with).

    Returns
    -------
    Catalogue
    """
    keys = {e.key for e in EXAMPLES} | {MUJOCO_KEY}
    if only is not None and only not in keys:
        raise ValueError(f"--only: expected one of {', '.join(sorted(keys))}, found {only!r}")
    wanted = [e for e in EXAMPLES if only in (None, e.key) or (only == MUJOCO_KEY and e.key in MUJOCO_OBSERVERS)]
    designs = [design_example(e, root) for e in wanted]
    mujoco = mujoco_row(root) if only in (None, MUJOCO_KEY) else None
    if mujoco is not None:
        for d in designs:
            if d.example.key in MUJOCO_OBSERVERS:
                d.observer.partners.append(MUJOCO_FILE)
    return Catalogue(designs, mujoco)


# ------------------------------------------------------------------ the README


def _experiment(spec: dict | None) -> str:
    if spec is None:
        return "none"
    steps = int(round((spec["stopTime"] - spec["startTime"]) / spec["stepSize"]))
    return f"{num(spec['startTime'])} to {num(spec['stopTime'])} s, step {num(spec['stepSize'])} s ({steps} steps)"


HEADER = ("| FMU | backend | runs with | parameters | inputs | outputs | steps accepted | DefaultExperiment "
          "| certified | checked by `make fmus` | reproduce |")
#: The column of the checks (0-based, after the leading pipe).
CHECK_COLUMN = 9


def _row(row: Row, checks: str) -> str:
    ports = [", ".join(p.text() for p in ports) or "—" for ports in (row.parameters, row.inputs, row.outputs)]
    partners = ", ".join(f"`{p}`" for p in row.partners)
    if row.connect:
        partners += f"; {row.connect}"
    experiment = _experiment(row.experiment) + (f" ({row.note})" if row.note else "")
    cells = [f"`{row.file}` ({row.role})", row.backend, partners, *ports, row.steps, experiment,
             row.certified, checks, f"`{COMMAND} --only {row.key}`"]
    return "| " + " | ".join(cell(c) for c in cells) + " |"


def check_text(results: dict | None, limited: dict | None = None) -> str:
    """The README's check cell of one FMU from ``{check: status}``.

    Statuses: ``ok``; for ecospy ``equal`` (to our master, to 1e-12) or ``ran`` (to the stop time, not
    compared); ``not run`` (ecospy not importable); ``failed``.

    Parameters
    ----------
    results : dict or None
        None: nothing recorded (the cell says so).
    limited : dict, optional
        ``{check: steps}``: the checks run over fewer steps than the default experiment (shown).

    Returns
    -------
    str
    """
    if not results:
        return "not recorded"
    words = []
    for name in CHECKS:
        status = results.get(name)
        if status is None:
            continue
        shown = {"ok": name, "equal": f"{name} (= master)", "ran": f"{name} (ran, not compared)",
                 "not run": f"{name} not run", "failed": f"{name} FAILED"}[status]
        if (limited or {}).get(name) and status != "not run":
            shown += f" over {limited[name]} steps"
        words.append(shown)
    return ", ".join(words)


USE = """\
## Use it in your tool

Every FMU is FMI 2.0 Co-Simulation; the C ones need nothing but the `.fmu` (its `sources/` rebuild it
elsewhere: `fmpy compile`; the MuJoCo plant ships MuJoCo's `libmujoco.so` next to its binary instead, so
it runs on linux64 only), the python ones (pythonfmu) need a Python with numpy where they run. Step at
the observer's DefaultExperiment `stepSize` (or one of the steps its row accepts): any other step is
refused with fmi2Discard and a log line. At every communication point set the observer's inputs, then
step both FMUs from t_k to t_k+1.

Which output goes to which input:

| observer input | from | families |
|---|---|---|
| `y[i]` | the plant's output `y[i]` | every family |
| `u[i]` | the same known input you set on the plant's `u[i]` | all but the dead-beat functional |
| `mode[1]` (Integer) | the plant's output `mode[1]`, or the mode you set on its input `mode[1]` | switched |
| `theta[1..s]` | the value you set on the plant's input `theta` (or its output `theta`) | dead-beat, theta |
| `ydot[i]` | the plant's output `ydot[i]` (or a measured derivative of `y`) | delayed UIO |

The plant's `d` is the unknown input: the observer never sees it. The observer's outputs: `xhat` (state
estimate), `r` (residual y - C xhat), `dhat` (unknown-input estimate, where the family has it), `gx` and
the Integer `gx_valid` (dead-beat functional: G x, exact once `gx_valid` = 1), `thetahat`, `sigma_min`
and the Integer `valid` (delayed UIO: the estimates hold while `valid` = 1). Its parameter `xhat0` is
the initial estimate (`h_prev0`, `mode_prev0`: the step and mode assumed before the first one).

- **fmpy**: `fmpy.simulate_fmu("fmus/seed000_example1_observer.fmu")` runs one FMU with its
  DefaultExperiment; for the loop of two, our master drives both through fmpy:
  `uiofmu cosim --plant fmus/seed000_example1_plant.fmu --observer fmus/seed000_example1_observer.fmu
  --out out/run` (the observer's steps and the problem's signals by default).
- **ecospy** (pip `ecospy`; its library's `libtbb.so.12` comes from the pip wheel `tbb`):
  `EcosSimulationStructure.add_model("plant", ...)`, `add_model("observer", ...)`,
  `make_real_connection("plant::y[1]", "observer::y[1]")` for each `y[i]`
  (and `ydot[i]`), `make_int_connection("plant::mode[1]", "observer::mode[1]")`; then
  `EcosSimulation(structure=ss, step_size=h)`, `sim.init(0.0)`, `sim.step(K)`; set `u` and `d` with
  `sim.set_real("plant::u[1]", v)` (and on the observer's `u`) from a pre-step listener.
  Python FMUs run only through its Python API (in the Python process), not its `ecos` tool.
- **libcosimpy** (pip `libcosimpy`): `CosimExecution.from_step_size(step_size=h_in_ns)`, `add_local_slave`
  for each FMU, `connect_real_variables(plant, vr("y[i]"), observer, vr("y[i]"))` with the value
  references of `modelDescription.xml` (`connect_integer_variables` for `mode[1]`), `real_initial_value`
  for `u`, `d`, `xhat0`.
- **any FMI 2.0 importer** (OMSimulator, Simulink's FMU block, an SSP tool): connect the variables named
  above one element at a time, fix the communication step, and read `xhat` (or `gx`) from the observer.
  Every output declares in `<ModelStructure>` the inputs it depends on at the same point (`xhat` on `y`
  where the kernel feeds `y` through; the plant's `y` on none), so no algebraic loop arises.
"""


def render(catalogue: Catalogue, checks: dict) -> str:
    """The text of ``fmus/README.md``.

    Parameters
    ----------
    catalogue : Catalogue
        From :func:`describe` (every example).
    checks : dict
        ``{file: check cell text}`` (:func:`check_text` of :func:`run_checks`, or
        :func:`recorded_checks` of a README).

    Returns
    -------
    str
    """
    lines = [
        "# fmus/: the catalogue of ready FMUs",
        "",
        "Generated by `make fmus` (`examples/build_fmus.py`, `uiofmu/catalogue.py`) from the design cards and the "
        "ports and DefaultExperiments they declare; do not edit by hand. `make fmus` builds every FMU below into "
        "this folder (the `.fmu` files and their `NAME.design.json` cards are not in git), with the default "
        "backend: C where the C backend has the kernel (a C compiler needed), python (pythonfmu) otherwise. "
        "It checks each FMU's `modelDescription.xml` against its row, and runs `uiofmu validate` on each, fmpy's "
        "`simulate_fmu` on each alone with its DefaultExperiment, and each observer with its plant(s) over the "
        "observer's DefaultExperiment, with its problem's `[signals]`, in our co-simulation master "
        "(`uiofmu cosim`) and in ecospy (which must give the master's `x` and estimate to 1e-12, except where "
        "the row says it was not compared); the column `checked by make fmus` records what passed. Where the FMU "
        "Compliance Checker and Reference-FMUs' `fmusim` are found (`../shared/importers/`, or `$UIOFMU_FMUCHECK` "
        "and `$UIOFMU_FMUSIM`), it also runs every FMU alone in both, at its DefaultExperiment's step to its stop "
        "time, with no Python variable in their environment (`PATH` only): 0 errors, and an output row at "
        "the stop time; where they are not found it says so and goes on. Their results are printed, not recorded "
        "here, so this file is the same on every machine. It exits non-zero if anything fails. "
        "`tests/test_fmus_catalogue.py` fails when this file is stale.",
        "",
        "Numbers have 4 significant digits. `y[1..3]` is the FMI variables `y[1]`, `y[2]`, `y[3]`.",
        "",
    ]
    for family in [*FAMILIES, MUJOCO.name]:
        rows = [r for r in catalogue.rows if r.family == family]
        if not rows:
            continue
        if family == MUJOCO.name:
            lines += ["## MuJoCo plant", "", "The quarter-car of `plants/quarter_car` simulated by MuJoCo: the "
                      "plant the quarter-car observers were designed from (by linearisation).", ""]
        else:
            lines += [f"## {family}", "", FAMILIES[family][0].upper() + FAMILIES[family][1:] + ".", ""]
        sources = [f"`{d.example.source}`" + (" with the LTV observer of `examples/quarter_car.py`"
                                              if d.example.observer else "")
                   for d in catalogue.designs if d.observer.family == family]
        if sources:
            lines += ["Problems: " + ", ".join(sources) + ".", ""]
        lines += [HEADER, "|" + "---|" * HEADER.count(" | ") + "---|"]
        lines += [_row(r, checks.get(r.file, "not recorded")) for r in rows]
        lines.append("")
    return "\n".join(lines) + "\n" + USE


def _split(line: str) -> list:
    return [c.strip() for c in re.split(r"(?<!\\)\|", line.strip())[1:-1]]


def recorded_checks(text: str) -> dict:
    """The check column of a README :func:`render` wrote: ``{file: cell}``.

    Parameters
    ----------
    text : str

    Returns
    -------
    dict of str to str
    """
    out = {}
    for line in text.splitlines():
        m = re.match(r"\| `([^`]+\.fmu)` \((observer|plant)\) \|", line)
        if m:
            out[m.group(1)] = _split(line)[CHECK_COLUMN]
    return out


# ------------------------------------------------------------------ building and checking


def build(catalogue: Catalogue, out, root=ROOT) -> dict:
    """Build every FMU of the catalogue into ``out`` (and each card as ``KEY.design.json``).

    Parameters
    ----------
    catalogue : Catalogue
    out : str or Path
    root : str or Path, optional

    Returns
    -------
    dict of str to Path
        ``{file: path}``.
    """
    from .fmu.export import build_observer, build_plant

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = {}
    for d in catalogue.designs:
        d.card.write(out / f"{d.example.key}.design.json")
        paths[d.observer.file] = build_observer(d.card, out / d.observer.file)
        step = d.plant.experiment["stepSize"] if d.plant.experiment else None
        paths[d.plant.file] = build_plant(d.problem.plant, d.problem.name, out / d.plant.file, step=step,
                                          experiment_steps=d.problem.experiment_steps, labels=d.problem.labels)
        print(f"{d.example.key}: built {d.observer.file}, {d.plant.file}", flush=True)
    if catalogue.mujoco is not None:
        from .mujoco_plant import build_mujoco_plant, load_spec

        step = catalogue.mujoco.experiment["stepSize"]
        paths[MUJOCO_FILE] = build_mujoco_plant(load_spec(Path(root) / MUJOCO_FOLDER), out / MUJOCO_FILE, step=step)
        print(f"{MUJOCO_KEY}: built {MUJOCO_FILE}", flush=True)
    return paths


def description_problems(row: Row, path) -> list:
    """Where an FMU's ``modelDescription.xml`` differs from its row (ports, types, experiment, backend).

    Parameters
    ----------
    row : Row
    path : str or Path

    Returns
    -------
    list of str
        Empty when they agree.
    """
    from fmpy import read_model_description

    md = read_model_description(str(path))
    found: dict = {}
    for v in md.modelVariables:
        m = re.fullmatch(r"([A-Za-z_]\w*)\[([1-9]\d*)\]", v.name)
        if not m:
            return [f"variable {v.name!r} is not named NAME[i]"]
        entry = found.setdefault((v.causality, m.group(1)), [v.type, 0])
        entry[1] = max(entry[1], int(m.group(2)))
        if entry[0] != v.type:
            return [f"{v.name}: mixed types"]
    declared = {(c, p.name): [p.type, p.size] for c, ports in
                (("parameter", row.parameters), ("input", row.inputs), ("output", row.outputs)) for p in ports}
    problems = [f"{c} {n}: declared {declared.get((c, n))}, found {found.get((c, n))}"
                for c, n in sorted(set(found) | set(declared)) if found.get((c, n)) != declared.get((c, n))]
    de = md.defaultExperiment
    have = None if de is None or de.stepSize is None else \
        {"startTime": float(de.startTime or 0.0), "stopTime": float(de.stopTime), "stepSize": float(de.stepSize)}
    if have != row.experiment:
        problems.append(f"DefaultExperiment: declared {row.experiment}, found {have}")
    c_built = (md.generationTool or "").startswith("uiofmu")
    if c_built != (row.backend == "C"):
        problems.append(f"backend: the row says {row.backend}, the FMU was made by {md.generationTool!r}"
                        + (" (no C compiler found?)" if not c_built else ""))
    return problems


def _master(observer: Row, plant: Row, paths: dict, card):
    """Our master on one pair, over the observer's default experiment with the problem's signals."""
    from .cosim.kernels import cosim_kernel
    from .cosim.master import cosimulate, default_inputs

    spec = observer.experiment
    K = observer.limited.get("master") or int(round(spec["stopTime"] / spec["stepSize"]))
    ours = cosimulate(paths[plant.file], paths[observer.file], np.full(K, spec["stepSize"]), default_inputs(card),
                      show_progress=False)
    mine = cosim_kernel(card).estimate_of(ours)
    if not (np.all(np.isfinite(ours.x)) and np.all(np.isfinite(mine))):
        raise RuntimeError("x or the estimate is not finite")
    return ours


def feeds_through(card) -> bool:
    """Whether the plant of ``card`` feeds its inputs straight to ``y`` (a nonzero ``D`` or ``F`` in its problem's
    ``[plant]``).

    ecospy reads the plant's outputs after each step and sets the next inputs before the next, so the observer
    gets ``y_k`` with the previous ``u`` and ``d`` where they feed through (and ``ydot`` with the previous ``u``
    for a delayed observer, :attr:`uiofmu.cosim.kernels.CosimKernel.ecospy_exact`): the run is not our master's
    and is recorded as ``ran``, not compared.
    """
    plant = (card.data.get("problem") or {}).get("plant") or {}
    return any(np.any(np.asarray(plant.get(key, 0.0), dtype=float)) for key in ("D", "F"))


def _ecospy(observer: Row, plant: Row, paths: dict, card, ours) -> str:
    """ecospy on one pair, compared with our master's run ``ours``: ``equal``, ``ran`` or ``not run``."""
    from .cosim.importers import import_ecospy, run_ecospy
    from .cosim.kernels import cosim_kernel
    from .cosim.master import default_inputs

    if import_ecospy() is None:
        return "not run"
    spec = observer.experiment
    K = observer.limited.get("ecospy") or int(round(spec["stopTime"] / spec["stepSize"]))
    kernel = cosim_kernel(card)
    Lf = card.matrices.get("Lf")                  # a functional observer's zhat estimates Lf x
    estimate = kernel.estimate if Lf is None else "zhat"
    run = run_ecospy(paths[plant.file], paths[observer.file], spec["stepSize"], K, default_inputs(card),
                     estimate=estimate)
    T, X, E = run.times, run.x if Lf is None else run.x @ np.asarray(Lf, dtype=float).T, run.xhat
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(E)) and np.ptp(E) > 0):
        raise RuntimeError("the estimate is not finite or never moved")
    if T.shape != ours.times.shape or not np.allclose(T, ours.times, rtol=1e-12, atol=0.0):
        raise RuntimeError(f"its clock differs from our master's (last point {T[-1]!r}, ours {ours.times[-1]!r})")
    if not (kernel.ecospy_exact and not feeds_through(card)):
        return "ran"
    mine = kernel.estimate_of(ours)
    for name, a, b in (("x", X, ours.x), (estimate, E, mine)):
        scale = max(float(np.max(np.abs(b))), 1e-300)
        if not np.allclose(a, b, rtol=ECOSPY_RTOL, atol=ECOSPY_RTOL * scale):
            raise RuntimeError(f"{name} differs from our master's by {float(np.max(np.abs(a - b))):.3g} "
                               f"(scale {scale:.3g})")
    return "equal"


_ORDER = ("ok", "equal", "ran", "not run", "failed")


def _note(results: dict, file: str, check: str, status: str) -> None:
    entry = results.setdefault(file, {})
    old = entry.get(check)
    entry[check] = status if old is None or _ORDER.index(status) > _ORDER.index(old) else old


def run_checks(catalogue: Catalogue, paths: dict) -> tuple[dict, list]:
    """Check every built FMU and run every pair (see the module's docstring).

    Parameters
    ----------
    catalogue : Catalogue
    paths : dict
        ``{file: path}`` from :func:`build`.

    Returns
    -------
    results : dict
        ``{file: {check: status}}``.
    failures : list of str
        One line per failed check.
    """
    from .cosim.importers import run_fmpy_default
    from .cosim.validate import validate

    results: dict = {}
    failures: list = []

    def attempt(files, check, fn):
        t0 = time.perf_counter()
        try:
            status = fn()
        except Exception as exc:  # noqa: BLE001 - every failure is reported, the run goes on
            failures.append(f"{' + '.join(files)}: {check}: {type(exc).__name__}: {exc}")
            status = ("failed",) * len(files)
        status = status if isinstance(status, tuple) else (status,) * len(files)
        for f, s in zip(files, status):
            _note(results, f, check, s)
        print(f"  {' + '.join(files)}: {check} {'/'.join(dict.fromkeys(status))} "
              f"({time.perf_counter() - t0:.1f} s)", flush=True)

    def static(row):
        problems = description_problems(row, paths[row.file])
        report = validate(paths[row.file])
        if problems or not report.ok:
            raise RuntimeError("; ".join(problems + report.problems) or
                               f"differs from its reference by {report.max_rel_diff:.3g} relative "
                               f"(tolerance {report.tolerance:g})")
        return "ok"

    cards = {d.observer.file: d.card for d in catalogue.designs}
    for row in catalogue.rows:
        attempt([row.file], "validate", lambda row=row: static(row))
        attempt([row.file], "fmpy",
                lambda row=row: (run_fmpy_default(paths[row.file], steps=row.limited.get("fmpy")), "ok")[1])
    for observer, plant in catalogue.pairs():
        files, card, runs = [observer.file, plant.file], cards[observer.file], []
        attempt(files, "master", lambda: (runs.append(_master(observer, plant, paths, card)), "ok")[1])
        if runs:
            attempt(files, "ecospy", lambda: _ecospy(observer, plant, paths, card, runs[0]))
        else:
            attempt(files, "ecospy", lambda: "not run")
    return results, failures


def _span(row: Row):
    """``(step, stop)`` of an FMU's run alone: its DefaultExperiment, shortened as its fmpy run is."""
    spec = row.experiment
    steps = row.limited.get("fmpy")
    return spec["stepSize"], steps * spec["stepSize"] if steps else spec["stopTime"]


def run_native_importers(catalogue: Catalogue, paths: dict) -> list:
    """Run every built FMU alone in the FMU Compliance Checker and in fmusim, printing what each found.

    Each FMU runs at its DefaultExperiment's step to its stop time
    (:func:`uiofmu.cosim.native_importers.run_compliance_checker`, :func:`~uiofmu.cosim.native_importers.run_fmusim`).
    An importer that is not found or cannot start is named once on the console and left out; nothing of
    this reaches the README.

    Parameters
    ----------
    catalogue : Catalogue
    paths : dict
        ``{file: path}`` from :func:`build`.

    Returns
    -------
    list of str
        One line per FMU and importer that reported an error or stopped before the stop time, naming the
        FMU and the importer's first error line.
    """
    from .cosim.native_importers import run_compliance_checker, run_fmusim

    failures = []
    print("native importers (alone, no Python variable in the environment):", flush=True)
    for name, run in (("fmuCheck", run_compliance_checker), ("fmusim", run_fmusim)):
        for row in catalogue.rows:
            if row.experiment is None:
                print(f"  {row.file}: {name} not run (no DefaultExperiment)", flush=True)
                continue
            t0 = time.perf_counter()
            found = run(paths[row.file], *_span(row))
            if not found.ran:
                print(f"  {name} not run: {found.unavailable}", flush=True)
                break
            seconds = f"({time.perf_counter() - t0:.1f} s)"
            if not found.ok:
                failures.append(f"{row.file}: {name}: {found.problem()}")
                print(f"  {row.file}: {name} FAILED {seconds}", flush=True)
                continue
            warned = "; ".join(dict.fromkeys(re.sub(r"^(\[[^\]]*\])+\s*", "", w) for w in found.warnings))
            past = f" and one step past it, to {found.last_time!r}" if found.past_stop else ""
            warned = f", warned: {warned}" if warned else ""
            print(f"  {row.file}: {name} ok to t = {found.stop_time!r}{past}{warned} {seconds}", flush=True)
    return failures


def main(argv=None, root=ROOT) -> int:
    """``make fmus``: build, check, and write ``OUT/README.md``.

    Parameters
    ----------
    argv : list of str, optional
        ``--out DIR`` (default ``ROOT/fmus``), ``--only KEY`` (one example: built and checked, the
        README not written).
    root : str or Path, optional
        The repository.

    Returns
    -------
    int
        0 when every check passed, 1 otherwise.
    """
    parser = argparse.ArgumentParser(prog="build_fmus.py", description="Build, check and document the FMU "
                                     "catalogue (fmus/README.md).")
    parser.add_argument("--out", default=str(Path(root) / "fmus"), help="the folder (default: fmus/)")
    parser.add_argument("--only", help="one example's key (see fmus/README.md); the README is not written")
    args = parser.parse_args(argv)
    out = Path(args.out)
    catalogue = describe(root, args.only)
    paths = build(catalogue, out, root)
    print("checks:", flush=True)
    results, failures = run_checks(catalogue, paths)
    failures += run_native_importers(catalogue, paths)
    if args.only is None:
        text = render(catalogue, {r.file: check_text(results.get(r.file), r.limited) for r in catalogue.rows})
        write_atomic(out / "README.md", text, "catalogue")
        print(f"wrote {out / 'README.md'}")
    else:
        for row in catalogue.rows:
            print(f"{row.file}: {check_text(results.get(row.file), row.limited)}")
    for line in failures:
        print(f"FAILED {line}", file=sys.stderr)
    print(f"{len(catalogue.rows)} FMUs, {len(catalogue.pairs())} pairs: "
          + ("every check passed" if not failures else f"{len(failures)} failure(s)"))
    return 1 if failures else 0
