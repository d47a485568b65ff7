"""Validation campaigns: many co-simulations of one observer against its plant, on Dask.

A campaign file (TOML, data only) names the FMUs (or a problem that gives them) and the axes a
run's scenario is drawn along: the step SPEC and its seed, an initial estimation error, a scale of
the unknown input, plant parameters. Every scenario is a function of the campaign's seed and the
row index only (:func:`scenario`), so one row can be re-run alone and gives the same numbers bit
for bit (:func:`replay`). The runs go to a ``dask.distributed`` cluster (a ``LocalCluster`` of
worker processes, or an existing scheduler): each worker receives the FMUs once (their bytes, so
a worker on another machine needs no shared folder), keeps them with the observer's default
inputs in a per-process cache, and runs batches of rows through
:func:`uiofmu.cosim.master.cosimulate`. Results come back as batches finish; a run an FMU refuses
is recorded with its reason; an interrupted campaign writes the rows that finished.

File format (every key is checked; an unknown key is an error naming it)::

    [campaign]
    problem = "plants/two_room_building"   # or observer = "O.fmu" and plant = "P.fmu"
    runs = 200                             # number of runs (with grid = true: a multiple of the grid)
    seed = 1                               # campaign seed (default 0)
    t_end = 172800.0                       # horizon in s (default: the observer's default horizon)
    grid = false                           # true: every combination of the listed axis values
    backend = "c"                          # with problem: FMU backend (default: as `uiofmu build`)
    batch = 16                             # rows per Dask task (default: about 8 tasks per worker)

    [axes]
    steps = ["dropout:600:0.3:11", "choice:600,1200,1800"]  # step SPECs; one per run, a fresh seed
    xhat0_error = {kind = "normal", std = 2.0}               # added to the observer's xhat0
    d_scale = {kind = "uniform", low = 0.5, high = 1.5}      # scales the problem's [signals] d
    plant_parameters = {x0 = {kind = "normal", mean = 22.0, std = 1.0}}   # by the plant FMU's names

An axis value is a number (constant), a list (one entry drawn per run; with ``grid = true`` each
entry is a grid point; for a vector an entry may be a list of its size), or a table with ``kind``:
``normal`` (``std``, ``mean`` = 0), ``uniform`` (``low``, ``high``), ``choice`` (``values``) or
``constant`` (``value``). The random kinds draw every component of a vector independently.
"""

from __future__ import annotations

import atexit
import csv
import hashlib
import io
import json
import math
import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..runtime.errors import FmuError, ProblemError, UserError
from ..runtime.files import atomic_output, check_output_dir, parse_json, parse_toml, read_bytes, read_text, \
    write_atomic
from ..threads import single_blas_thread

#: Most runs of one campaign.
MAX_RUNS = 10_000_000
#: Distribution kinds of an axis.
KINDS = ("constant", "choice", "normal", "uniform")
#: Columns of every campaign table, before the axes.
HEAD = ["row"]
#: Scalar metrics first in the table (others follow in the order they appear).
PREFERRED = ["n_steps", "t_end", "initial_error_norm", "final_error_norm", "max_error_norm", "error_floor",
             "steps_to_1pct", "time_to_1pct", "step_min", "step_max", "bound_respected", "max_bound_ratio",
             "first_bound_violation", "final_bound", "rms_error", "dhat_rms_error", "dhat_rms_error_second_half"]
#: Metrics whose quantiles the summary gives.
QUANTILE_KEYS = ("steps_to_1pct", "time_to_1pct", "final_error_norm", "max_bound_ratio", "dhat_rms_error",
                 "dhat_rms_error_second_half")
#: Keys of the [campaign] and [axes] tables.
CAMPAIGN_KEYS = ("problem", "observer", "plant", "runs", "seed", "t_end", "grid", "backend", "batch")
AXES_KEYS = ("steps", "xhat0_error", "d_scale", "plant_parameters")
QUANTILES = (0.0, 0.05, 0.25, 0.5, 0.75, 0.95, 1.0)


# --------------------------------------------------------------------------------------------
# the campaign file
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Axis:
    """One sampled quantity.

    Attributes
    ----------
    key : str
        Its key path in the campaign file (``axes.d_scale``), for messages.
    kind : str
        One of :data:`KINDS`.
    params : dict
        ``value`` (constant), ``values`` (choice: a tuple of floats or of tuples), ``mean`` and
        ``std`` (normal), ``low`` and ``high`` (uniform).
    """

    key: str
    kind: str
    params: dict

    @property
    def listed(self) -> bool:
        """Whether the axis lists its values (a grid enumerates them)."""
        return self.kind == "choice"

    def check_size(self, size: int) -> None:
        """Raise unless every listed vector has ``size`` components."""
        entries = self.params["values"] if self.kind == "choice" else (self.params.get("value"),)
        for i, v in enumerate(entries):
            if isinstance(v, tuple) and len(v) != size:
                where = f"{self.key}[{i}]" if self.kind == "choice" else self.key
                raise ProblemError(f"{where}: expected {size} value(s) (one per component), found {len(v)}")

    def value(self, entry, size: int) -> np.ndarray:
        """A listed entry as a vector of ``size`` components (a number is repeated)."""
        return np.array(entry, dtype=float) if isinstance(entry, tuple) else np.full(size, float(entry))

    def draw(self, rng: np.random.Generator, size: int) -> np.ndarray:
        """One draw of ``size`` components."""
        p = self.params
        if self.kind == "constant":
            return self.value(p["value"], size)
        if self.kind == "choice":
            return self.value(p["values"][int(rng.integers(len(p["values"])))], size)
        if self.kind == "normal":
            return rng.normal(p["mean"], p["std"], size) if p["std"] > 0 else np.full(size, p["mean"])
        return rng.uniform(p["low"], p["high"], size)

    def describe(self) -> str:
        """The axis in words, for the summary."""
        p = self.params
        if self.kind == "constant":
            return f"{p['value']}"
        if self.kind == "choice":
            return "one of " + ", ".join(map(str, p["values"]))
        if self.kind == "normal":
            return f"normal(mean {p['mean']:g}, std {p['std']:g})"
        return f"uniform({p['low']:g}, {p['high']:g})"


@dataclass(frozen=True)
class Campaign:
    """A parsed campaign file (see the module docstring).

    Attributes
    ----------
    path : Path
        The campaign file; relative paths in it are relative to its folder.
    problem : Path or None
        A problem file or ``plants/NAME`` folder; else ``observer`` and ``plant`` are FMUs.
    observer, plant : Path or None
    runs : int
    seed : int
    t_end : float or None
    grid : bool
    backend : str or None
    batch : int or None
    steps : tuple of str
        Step SPECs (empty: the observer's default steps).
    xhat0_error, d_scale : Axis or None
    plant_parameters : tuple of (str, Axis)
    text : str
        The file's text (its digest names the built FMUs).
    """

    path: Path
    problem: Path | None
    observer: Path | None
    plant: Path | None
    runs: int
    seed: int
    t_end: float | None
    grid: bool
    backend: str | None
    batch: int | None
    steps: tuple
    xhat0_error: Axis | None
    d_scale: Axis | None
    plant_parameters: tuple = ()
    text: str = ""

    def grid_axes(self) -> list:
        """The axes a grid enumerates, as ``(name, number of values)`` in the order of the file."""
        if not self.grid:
            return []
        out = [("steps", max(1, len(self.steps)))]
        for name, axis in self.named_axes():
            if axis.listed:
                out.append((name, len(axis.params["values"])))
        return out

    def grid_size(self) -> int:
        """Points of the grid (1 without one)."""
        return math.prod(n for _, n in self.grid_axes()) if self.grid else 1

    def named_axes(self) -> list:
        """``(column name, Axis)`` of the numeric axes, in draw order."""
        out = [(name, a) for name, a in (("xhat0_error", self.xhat0_error), ("d_scale", self.d_scale)) if a]
        return out + [(f"plant.{name}", a) for name, a in self.plant_parameters]


def _integer(table, key: str, default, low: int, high: int) -> int:
    value = table.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int):
        raise ProblemError(f"{table.key(key)}: expected an integer, found {value!r}"[:300])
    if not low <= value <= high:
        raise ProblemError(f"{table.key(key)}: expected an integer in [{low}, {high}], found {value}")
    return value


def _number(value, key: str) -> float:
    from ..runtime.matrices import as_scalar

    if isinstance(value, bool):
        raise ProblemError(f"{key}: expected a number, found {value!r}")
    return as_scalar(value, key)


def _entry(value, key: str):
    """A listed value: a number, or a non-empty list of numbers (a vector), as float or tuple."""
    if isinstance(value, list):
        if not value:
            raise ProblemError(f"{key}: expected a number or a non-empty list of numbers, found []")
        return tuple(_number(v, f"{key}[{i}]") for i, v in enumerate(value))
    return _number(value, key)


def parse_axis(value, key: str) -> Axis:
    """An axis value of a campaign file (a number, a list, or a table with ``kind``).

    Parameters
    ----------
    value : object
        The TOML value.
    key : str
        Its key path, for messages.

    Returns
    -------
    Axis

    Raises
    ------
    ProblemError
        Naming the key and what was expected.
    """
    from ..problem import Table

    if isinstance(value, list):
        if not value:
            raise ProblemError(f"{key}: expected a non-empty list of values, found []")
        return Axis(key, "choice", {"values": tuple(_entry(v, f"{key}[{i}]") for i, v in enumerate(value))})
    if not isinstance(value, dict):
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return Axis(key, "constant", {"value": _number(value, key)})
        raise ProblemError(f"{key}: expected a number, a list of values or a table with kind, found "
                           f"{type(value).__name__}")
    table = Table(value, key)
    kind = table.choice("kind", KINDS)
    if kind == "constant":
        params = {"value": _entry(table.get("value"), table.key("value"))}
    elif kind == "choice":
        listed = table.get("values")
        if not isinstance(listed, list) or not listed:
            raise ProblemError(f"{table.key('values')}: expected a non-empty list of values, found {listed!r}"[:300])
        params = {"values": tuple(_entry(v, f"{table.key('values')}[{i}]") for i, v in enumerate(listed))}
    elif kind == "normal":
        params = {"mean": table.scalar("mean", 0.0), "std": table.scalar("std", low=0.0)}
    else:
        params = {"low": table.scalar("low"), "high": table.scalar("high")}
        if params["low"] > params["high"]:
            raise ProblemError(f"{key}: low = {params['low']:g} > high = {params['high']:g}")
    table.done()
    return Axis(key, kind, params)


def campaign_from_data(data: dict, path, text: str = "") -> Campaign:
    """Check a parsed campaign file (see the module docstring).

    Parameters
    ----------
    data : dict
        The TOML document.
    path : str or Path
        Where it came from: relative paths are relative to its folder.
    text : str
        Its text (recorded).

    Returns
    -------
    Campaign

    Raises
    ------
    ProblemError
        For every malformed or unknown key, naming it.
    """
    from ..problem import Table
    from .steps import step_sequence

    path = Path(path)
    top = Table(data, "")
    camp = Table(top.get("campaign"), "campaign")
    axes = Table(top.get("axes", {}), "axes")
    top.done()
    for table, known in ((camp, CAMPAIGN_KEYS), (axes, AXES_KEYS)):
        unknown = sorted(str(k) for k in table.data if k not in known)
        if unknown:
            raise ProblemError(f"{table.key(unknown[0])[:200]}: unknown key (known here: {', '.join(known)})")
    folder = path.parent

    def location(key):
        value = camp.get(key, None)
        if value is None:
            return None
        if not isinstance(value, str) or not value or len(value) > 4096 or "\0" in value:
            raise ProblemError(f"campaign.{key}: expected a path (a non-empty string), found {value!r}"[:300])
        return folder / value

    problem, observer, plant = location("problem"), location("observer"), location("plant")
    if problem is not None and (observer or plant):
        raise ProblemError("campaign.problem: give either problem, or observer and plant, not both")
    if problem is None and (observer is None or plant is None):
        missing = "campaign.observer" if observer is None and plant is not None else (
            "campaign.plant" if plant is None and observer is not None else "campaign.problem")
        raise ProblemError(f"{missing}: required key is missing (give problem, or observer and plant FMUs)")
    seed = _integer(camp, "seed", 0, 0, 2**63 - 1)
    grid = camp.get("grid", False)
    if not isinstance(grid, bool):
        raise ProblemError(f"campaign.grid: expected true or false, found {grid!r}"[:300])
    t_end = camp.get("t_end", None)
    if t_end is not None:
        from ..runtime.matrices import as_scalar

        t_end = as_scalar(t_end, "campaign.t_end", low=0.0, open_low=True)
    backend = camp.choice("backend", ("c", "python"), None) if camp.has("backend") else camp.get("backend", None)
    if backend is not None and problem is None:
        raise ProblemError("campaign.backend: only with campaign.problem (the FMUs given are built already)")
    batch = _integer(camp, "batch", None, 1, 100_000) if camp.has("batch") else camp.get("batch", None)
    runs = _integer(camp, "runs", None, 1, MAX_RUNS) if camp.has("runs") else camp.get("runs", None)
    camp.done()

    steps = axes.get("steps", None)
    if isinstance(steps, str):
        steps = [steps]
    if steps is None:
        steps = []
    if not isinstance(steps, list) or not all(isinstance(s, str) for s in steps) or (not steps and axes.has("steps")):
        raise ProblemError(f"axes.steps: expected a step SPEC or a non-empty list of them, found {steps!r}"[:300])
    for i, spec in enumerate(steps):
        if len(spec) > 4096:
            raise ProblemError(f"axes.steps[{i}]: a step SPEC of {len(spec)} characters")
        if spec.startswith("file:"):
            spec = "file:" + str(folder / spec[5:])
            steps[i] = spec
        try:
            step_sequence(spec, 1e-300, 0)      # the SPEC's syntax (one step suffices)
        except ProblemError as exc:
            raise ProblemError(f"axes.steps[{i}]: {str(exc).removeprefix('--steps').lstrip(': ')}") from None
    xhat0_error = parse_axis(axes.get("xhat0_error"), "axes.xhat0_error") if axes.has("xhat0_error") else None
    d_scale = parse_axis(axes.get("d_scale"), "axes.d_scale") if axes.has("d_scale") else None
    params = axes.get("plant_parameters", {})
    ptable = Table(params, "axes.plant_parameters")
    plant_parameters = []
    for name in ptable.data:
        if not isinstance(name, str) or not name.isidentifier() or len(name) > 64:
            raise ProblemError(f"axes.plant_parameters.{str(name)[:64]}: not a parameter name")
        plant_parameters.append((name, parse_axis(ptable.get(name), ptable.key(name))))
    axes.done()

    campaign = Campaign(path=path, problem=problem, observer=observer, plant=plant, runs=runs or 0, seed=seed,
                        t_end=t_end, grid=grid, backend=backend, batch=batch, steps=tuple(steps),
                        xhat0_error=xhat0_error, d_scale=d_scale, plant_parameters=tuple(plant_parameters),
                        text=text)
    size = campaign.grid_size()
    if grid:
        if runs is None:
            runs = size
        elif runs % size:
            raise ProblemError(f"campaign.runs: with grid = true, a multiple of the grid's {size} points "
                               f"({' x '.join(f'{n} {k}' for k, n in campaign.grid_axes())}), found {runs}")
    elif runs is None:
        raise ProblemError("campaign.runs: required key is missing (or set grid = true)")
    if runs > MAX_RUNS:
        raise ProblemError(f"campaign.runs: {runs} runs, more than {MAX_RUNS}")
    return replace(campaign, runs=runs)


def load_campaign(path) -> Campaign:
    """Read and check a campaign file.

    Parameters
    ----------
    path : str or Path
        A regular TOML file of at most :data:`uiofmu.runtime.files.MAX_INPUT_BYTES`.

    Returns
    -------
    Campaign
        As :func:`campaign_from_data` makes it from the file's table, with the file's text.

    Raises
    ------
    ProblemError
        For an unreadable file, TOML syntax errors and every malformed key.
    """
    path = Path(path)
    text = read_text(path, "campaign file", error=ProblemError)
    data = parse_toml(text, str(path), error=ProblemError)
    return campaign_from_data(data, path, text)


# --------------------------------------------------------------------------------------------
# FMUs and what every run shares
# --------------------------------------------------------------------------------------------
@dataclass
class Setup:
    """What the runs of a campaign share: the FMUs (as bytes, to ship to workers) and the sizes.

    Attributes
    ----------
    plant_bytes, observer_bytes : bytes
    digest : str
        Of both FMUs (the workers' cache key).
    t_end : float
    n : int
        Observer state size (of ``xhat0``).
    parameters : dict of str to int
        The plant FMU's parameter vectors and sizes.
    default_steps : str
    name : str
        The observer's problem name.
    plant_path, observer_path : Path
        Where the FMUs are on the machine that prepared them.
    """

    plant_bytes: bytes
    observer_bytes: bytes
    digest: str
    t_end: float
    n: int
    parameters: dict
    default_steps: str
    name: str
    has_xhat0: bool
    plant_path: Path = field(default=None, repr=False)
    observer_path: Path = field(default=None, repr=False)

    def __getstate__(self):
        state = dict(self.__dict__)
        state["plant_path"] = state["observer_path"] = None   # paths of the client machine only
        return state


def _digest(*blobs: bytes) -> str:
    h = hashlib.sha256()
    for b in blobs:
        h.update(hashlib.sha256(b).digest())
    return h.hexdigest()


def build_fmus(campaign: Campaign, folder, say=None) -> tuple[Path, Path]:
    """Design the observer of the campaign's problem and build both FMUs into ``folder``.

    The FMUs are reused when ``folder/source.json`` records the same problem file, backend and
    uiofmu version (a replay then runs on the very FMUs the campaign ran on).

    Returns
    -------
    (Path, Path)
        The plant and observer FMUs.
    """
    from .. import __version__
    from ..fmu.export import build_observer, build_plant
    from ..problem import load_problem
    from ..synthesis import design

    folder = Path(folder)
    path = campaign.problem / "problem.toml" if campaign.problem.is_dir() else campaign.problem
    source = {"problem": hashlib.sha256(read_bytes(path, "problem file", error=ProblemError)).hexdigest(),
              "backend": campaign.backend, "uiofmu": __version__}
    plant, observer, record = folder / "plant.fmu", folder / "observer.fmu", folder / "source.json"
    if record.is_file() and plant.is_file() and observer.is_file():
        try:
            if parse_json(read_text(record, "FMU record"), str(record)) == source:
                return plant, observer
        except UserError:
            pass
    problem = load_problem(campaign.problem)
    if say:
        say(f"  design               {problem.name} ({problem.family})")
    card = design(problem)
    card.write(folder / "design.json")
    build_observer(card, observer, campaign.backend)
    build_plant(problem.plant, problem.name, plant, step=problem.options.step, backend=campaign.backend,
                experiment_steps=problem.experiment_steps)
    write_atomic(record, json.dumps(source, indent=2) + "\n", "FMU record")
    return plant, observer


def prepare(campaign: Campaign, out=None, say=None) -> Setup:
    """The FMUs (built into ``out/fmus`` for a problem) and the sizes the scenarios need.

    Raises
    ------
    ProblemError, FmuError
        For an axis the FMUs have no use for (a plant parameter the plant lacks, a vector of the
        wrong size), naming its key.
    """
    from fmpy import read_model_description

    from .fmi import vector_sizes
    from .master import default_steps, default_t_end, observer_card

    if campaign.problem is not None:
        if out is None:
            raise ProblemError("campaign.problem: building the FMUs needs an output folder")
        plant, observer = build_fmus(campaign, Path(out) / "fmus", say)
    else:
        plant, observer = campaign.plant, campaign.observer
    card = observer_card(observer)
    try:
        variables = read_model_description(str(plant)).modelVariables
    except Exception as exc:  # noqa: BLE001 - fmpy raises plain exceptions for broken archives
        raise FmuError(f"{plant}: not a readable FMU ({exc})"[:500]) from None
    parameters = vector_sizes(variables, "parameter")
    initial = card.data.get("initial", {})
    has_xhat0 = "xhat0" in initial
    n = len(initial["xhat0"]) if has_xhat0 else 0
    if campaign.xhat0_error is not None:
        if not has_xhat0:
            raise ProblemError(f"axes.xhat0_error: the observer ({card.kernel} kernel) has no xhat0")
        campaign.xhat0_error.check_size(n)
    for name, axis in campaign.plant_parameters:
        if name not in parameters:
            known = ", ".join(parameters) or "none"
            raise ProblemError(f"axes.plant_parameters.{name}: the plant FMU has no parameter {name} (it has {known})")
        axis.check_size(parameters[name])
    if campaign.d_scale is not None:
        campaign.d_scale.check_size(1)
    plant_bytes = read_bytes(plant, "plant FMU", error=FmuError)
    observer_bytes = read_bytes(observer, "observer FMU", error=FmuError)
    t_end = campaign.t_end if campaign.t_end is not None else default_t_end(card)
    return Setup(plant_bytes, observer_bytes, _digest(plant_bytes, observer_bytes), t_end, n, parameters,
                 default_steps(card), card.name, has_xhat0, Path(plant), Path(observer))


# --------------------------------------------------------------------------------------------
# scenarios
# --------------------------------------------------------------------------------------------
def scenario(campaign: Campaign, setup: Setup, row: int) -> dict:
    """The scenario of one row: a function of the campaign seed and the row index only.

    Parameters
    ----------
    campaign : Campaign
    setup : Setup
        Gives the vector sizes and the default steps.
    row : int
        0 <= row < campaign.runs.

    Returns
    -------
    dict
        ``row``, ``steps`` (a SPEC), ``steps_seed``, and per axis its drawn value: ``xhat0_error``
        (a list), ``d_scale`` (a float), ``plant.NAME`` (lists).
    """
    if not 0 <= row < campaign.runs:
        raise ProblemError(f"--replay: row {row} is not a row of the campaign (0 to {campaign.runs - 1})")
    rng = np.random.default_rng([campaign.seed, row])
    specs = campaign.steps or (setup.default_steps,)
    picks = {}
    if campaign.grid:
        index = row % campaign.grid_size()
        for name, count in reversed(campaign.grid_axes()):
            index, picks[name] = divmod(index, count)
    spec = specs[picks["steps"]] if "steps" in picks else specs[int(rng.integers(len(specs)))]
    out = {"row": row, "steps": spec, "steps_seed": int(rng.integers(2**32))}
    sizes = {"xhat0_error": setup.n, "d_scale": 1, **{f"plant.{k}": v for k, v in setup.parameters.items()}}
    for name, axis in campaign.named_axes():
        size = sizes[name]
        value = axis.value(axis.params["values"][picks[name]], size) if name in picks else axis.draw(rng, size)
        out[name] = float(value[0]) if name == "d_scale" else [float(v) for v in value]
    return out


def scaled_inputs(inputs, scale: float):
    """The input source with its ``d`` signals scaled by ``scale`` (every term's level and amplitude).

    Parameters
    ----------
    inputs : uiofmu.cosim.inputs.SignalInputs
    scale : float

    Returns
    -------
    uiofmu.cosim.inputs.SignalInputs
    """
    from ..signals import Signal, Term
    from .inputs import SignalInputs

    levels = {"constant": ("value",), "sine": ("amplitude", "offset"), "step": ("value", "initial"),
              "random": ("mean", "std")}

    def term(t: Term) -> Term:
        return Term(t.kind, tuple((k, v * scale if k in levels[t.kind] else v) for k, v in t.params))

    signals = inputs.signals
    d = tuple(Signal(tuple(term(t) for t in s.terms)) for s in signals["d"])
    return SignalInputs(signals["u"], d, signals.get("mode", ()), signals.get("theta", ()))


@dataclass
class Loaded:
    """The FMUs of a campaign in one process: paths, the observer's card, inputs and initial estimate,
    and the two FMU instances, loaded once and reset before each run."""

    plant: Path
    observer: Path
    inputs: object
    xhat0: np.ndarray | None
    t_end: float
    card: object = None
    instances: tuple | None = None

    def fmus(self) -> tuple:
        """The plant and observer instances of this process (loaded on first use)."""
        if self.instances is None:
            from .fmi import Fmu

            self.instances = (Fmu(self.plant, "plant"), Fmu(self.observer, "observer"))
        return self.instances


_LOADED: dict = {}
_FOLDERS: list = []


@atexit.register
def _clean() -> None:
    for loaded in _LOADED.values():
        for fmu in loaded.instances or ():
            fmu.close()
    for folder in _FOLDERS:
        shutil.rmtree(folder, ignore_errors=True)


def load(setup: Setup) -> Loaded:
    """The campaign's FMUs in this process, cached by their digest: written once to a local folder
    (unless the paths of the preparing machine are at hand), with the observer's card read once."""
    hit = _LOADED.get((setup.digest, setup.t_end))
    if hit is not None:
        return hit
    from .master import default_inputs, observer_card

    if setup.plant_path is not None and setup.observer_path is not None:
        plant, observer = setup.plant_path, setup.observer_path
    else:
        folder = Path(tempfile.mkdtemp(prefix="uiofmu_campaign_"))
        _FOLDERS.append(folder)
        plant, observer = folder / "plant.fmu", folder / "observer.fmu"
        plant.write_bytes(setup.plant_bytes)
        observer.write_bytes(setup.observer_bytes)
    card = observer_card(observer)
    xhat0 = np.asarray(card.data["initial"]["xhat0"], dtype=float) if setup.has_xhat0 else None
    loaded = Loaded(plant, observer, default_inputs(card), xhat0, setup.t_end, card)
    _LOADED[(setup.digest, setup.t_end)] = loaded
    return loaded


def run_scenario(setup: Setup, sc: dict):
    """Co-simulate one scenario (:func:`uiofmu.cosim.master.cosimulate`).

    Returns
    -------
    uiofmu.cosim.master.CosimResult

    Raises
    ------
    FmuError
        When an FMU refuses a call.
    """
    from .master import cosimulate
    from .steps import step_sequence

    loaded = load(setup)
    steps = step_sequence(sc["steps"], loaded.t_end, seed=sc["steps_seed"])
    inputs = scaled_inputs(loaded.inputs, sc["d_scale"]) if "d_scale" in sc else loaded.inputs
    xhat0 = loaded.xhat0 + np.asarray(sc["xhat0_error"]) if "xhat0_error" in sc else None
    params = {k[6:]: v for k, v in sc.items() if k.startswith("plant.")}
    return cosimulate(loaded.plant, loaded.observer, steps, inputs, xhat0=xhat0, plant_parameters=params or None,
                      show_progress=False, instances=loaded.fmus(), card=loaded.card)


def scalar_metrics(metrics: dict) -> dict:
    """The metrics of one run that fit a table cell: numbers, booleans, None; a list (per state or
    channel) becomes its Euclidean norm."""
    out = {}
    for key, value in metrics.items():
        key = "n_steps" if key == "steps" else key      # "steps" is the axis column
        if isinstance(value, bool) or value is None or isinstance(value, (int, float)):
            out[key] = value
        elif isinstance(value, list) and value and all(isinstance(v, (int, float)) for v in value):
            out[key] = float(np.linalg.norm(value))
    return out


@single_blas_thread
def run_row(setup: Setup, sc: dict) -> dict:
    """One row of the table: the scenario's status (``ok``, ``failed``: an FMU refused or an input was
    bad; ``crashed``: anything else), its reason and its scalar metrics."""
    t0 = time.perf_counter()
    try:
        result = run_scenario(setup, sc)
    except UserError as exc:
        return {"status": "failed", "reason": " ".join(str(exc).split())[:500], "wall_s": time.perf_counter() - t0}
    except Exception as exc:  # noqa: BLE001 - a run's bug must not stop the campaign: it is recorded
        return {"status": "crashed", "reason": f"{type(exc).__name__}: {' '.join(str(exc).split())}"[:500],
                "wall_s": time.perf_counter() - t0}
    return {"status": "ok", "reason": "", "wall_s": time.perf_counter() - t0, **scalar_metrics(result.metrics)}


@single_blas_thread
def run_batch(setup: Setup, scenarios: list) -> list:
    """A Dask task: the rows of a batch of scenarios, run one after the other in this worker."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return [(sc["row"], run_row(setup, sc)) for sc in scenarios]


# --------------------------------------------------------------------------------------------
# running a campaign
# --------------------------------------------------------------------------------------------
def _client(workers: int | None, scheduler: str | None):
    """A Dask client: on an existing scheduler, or on a new LocalCluster of worker processes."""
    import logging

    from distributed import Client, LocalCluster

    if scheduler:
        try:
            return Client(scheduler, timeout="10s"), None
        except (OSError, TimeoutError) as exc:
            raise FmuError(f"--scheduler {scheduler}: cannot reach the Dask scheduler ({exc})"[:500]) from None
    n = workers or os.cpu_count() or 1
    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                           silence_logs=logging.ERROR)
    return Client(cluster), cluster


def _cell(value) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return "" if math.isnan(value) else repr(value)
    return str(value)


def axis_columns(campaign: Campaign, setup: Setup) -> list:
    """The axis columns of the table: ``steps``, ``steps_seed``, then one per component."""
    cols = ["steps", "steps_seed"]
    sizes = {"xhat0_error": setup.n, **{f"plant.{k}": v for k, v in setup.parameters.items()}}
    for name, _ in campaign.named_axes():
        cols += [name] if name == "d_scale" else [f"{name}[{i + 1}]" for i in range(sizes[name])]
    return cols


def _flat(sc: dict) -> dict:
    out = {}
    for key, value in sc.items():
        if isinstance(value, list):
            out.update({f"{key}[{i + 1}]": v for i, v in enumerate(value)})
        else:
            out[key] = value
    return out


def table_text(campaign: Campaign, setup: Setup, scenarios: dict, rows: dict) -> str:
    """The campaign table (CSV) of the finished rows, in row order."""
    metric_cols = [k for k in PREFERRED if any(k in r for r in rows.values())]
    for r in rows.values():
        metric_cols += [k for k in r if k not in metric_cols and k not in ("status", "reason", "wall_s")]
    cols = HEAD + axis_columns(campaign, setup) + ["status", "reason"] + metric_cols + ["wall_s"]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for row in sorted(rows):
        values = {**_flat(scenarios[row]), **rows[row]}
        w.writerow([_cell(values.get(c)) for c in cols])
    return buf.getvalue()


def read_table(path) -> list:
    """A campaign table as a list of dicts of strings (the CSV cells)."""
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def summary(campaign: Campaign, setup: Setup, scenarios: dict, rows: dict, cancelled: bool = False,
            elapsed: float | None = None, workers: int | None = None, startup_s: float | None = None) -> dict:
    """``summary.json``: runs, failures and their reasons, the worst bound ratio with its row and
    scenario, quantiles of the convergence figures; ``elapsed_s`` and ``runs_per_s`` count from the
    cluster's start (``cluster_startup_s`` before it) to the last row."""
    ok = {r: m for r, m in rows.items() if m["status"] == "ok"}
    failed = {r: m for r, m in rows.items() if m["status"] != "ok"}
    reasons: dict = {}
    for r in sorted(failed):
        entry = reasons.setdefault(failed[r]["reason"], {"reason": failed[r]["reason"], "status": failed[r]["status"],
                                                         "count": 0, "rows": []})
        entry["count"] += 1
        if len(entry["rows"]) < 20:
            entry["rows"].append(r)
    ranked = sorted(reasons.values(), key=lambda e: -e["count"])
    out = {"campaign": str(campaign.path), "observer": setup.name, "runs": campaign.runs, "finished": len(rows),
           "ok": len(ok), "failures": len(failed), "failure_reasons": ranked[:50],
           "cancelled": cancelled, "seed": campaign.seed, "t_end": setup.t_end}
    ratios = {r: m["max_bound_ratio"] for r, m in ok.items() if m.get("max_bound_ratio") is not None}
    if ratios:
        worst = max(sorted(ratios), key=lambda r: ratios[r])
        out["worst_max_bound_ratio"] = {"value": ratios[worst], "row": worst, "scenario": scenarios[worst],
                                        "bound_respected": ok[worst].get("bound_respected")}
        out["bound_violations"] = sum(1 for m in ok.values() if m.get("bound_respected") is False)
    else:
        out["worst_max_bound_ratio"] = None
    quant = {}
    for key in QUANTILE_KEYS:
        values = [m.get(key) for m in ok.values() if key in m]
        if not values:
            continue
        finite = np.array([v for v in values if v is not None], dtype=float)
        entry = {"count": len(finite), "never" if key in ("steps_to_1pct", "time_to_1pct") else "missing":
                 len(values) - len(finite)}
        if finite.size:
            entry.update({f"q{int(round(q * 100)):02d}": float(np.quantile(finite, q)) for q in QUANTILES})
            entry["mean"] = float(np.mean(finite))
        quant[key] = entry
    out["quantiles"] = quant
    if elapsed is not None:
        out["elapsed_s"] = elapsed
        out["runs_per_s"] = len(rows) / elapsed if elapsed > 0 else None
    if startup_s is not None:
        out["cluster_startup_s"] = startup_s
    if workers is not None:
        out["workers"] = workers
    out["axes"] = {"steps": list(campaign.steps or (setup.default_steps,)),
                   **{name: axis.describe() for name, axis in campaign.named_axes()}}
    return out


def _batch_size(campaign: Campaign, workers: int) -> int:
    if campaign.batch:
        return campaign.batch
    return int(min(64, max(1, campaign.runs // (8 * max(1, workers)))))


def write_results(out: Path, campaign: Campaign, setup: Setup, scenarios: dict, rows: dict, **info) -> dict:
    """Write ``campaign.csv`` and ``summary.json`` atomically; returns the summary."""
    write_atomic(out / "campaign.csv", table_text(campaign, setup, scenarios, rows), "campaign table")
    data = summary(campaign, setup, scenarios, rows, **info)
    write_atomic(out / "summary.json", json.dumps(data, indent=2) + "\n", "campaign summary")
    return data


def run_campaign(campaign: Campaign, out, workers: int | None = None, scheduler: str | None = None,
                 show_progress: bool | None = None, say=None, checkpoint_s: float = 30.0) -> dict:
    """Run every row of a campaign on Dask and write ``campaign.csv``, ``summary.json``, ``campaign.png``.

    Parameters
    ----------
    campaign : Campaign
    out : str or Path
        Output folder.
    workers : int, optional
        Worker processes of the LocalCluster (default: ``os.cpu_count()``).
    scheduler : str, optional
        Address of an existing Dask scheduler instead (``tcp://host:8786``).
    show_progress : bool, optional
        Progress bar (default: when stderr is a terminal).
    say : callable, optional
        Where progress lines go.
    checkpoint_s : float
        The table is rewritten (atomically) at most this often while rows come in.

    Returns
    -------
    dict
        The summary.

    Raises
    ------
    KeyboardInterrupt
        After writing the rows that finished (``summary["cancelled"]`` is true).
    """
    from distributed import as_completed

    from ..progress import progress

    out = check_output_dir(out, "--out folder")
    setup = prepare(campaign, out, say)
    scenarios = {row: scenario(campaign, setup, row) for row in range(campaign.runs)}
    rows: dict = {}
    t_start = time.perf_counter()
    client, cluster = _client(workers, scheduler)
    t0 = time.perf_counter()
    futures = []
    try:
        n_workers = len(client.scheduler_info(n_workers=-1)["workers"]) or (workers or 1)
        if say:
            where = f"scheduler {scheduler}" if scheduler else "a LocalCluster"
            say(f"  runs                 {campaign.runs} on {n_workers} worker(s) of {where}")
        shared = client.scatter(setup, broadcast=True)
        size = _batch_size(campaign, n_workers)
        order = list(range(campaign.runs))
        futures = [client.submit(run_batch, shared, [scenarios[r] for r in order[i:i + size]], pure=False)
                   for i in range(0, len(order), size)]
        batches = {f.key: order[i * size:(i + 1) * size] for i, f in enumerate(futures)}
        last = time.perf_counter()
        with progress(total=campaign.runs, desc="campaign", unit="run", enabled=show_progress) as bar:
            for fut in as_completed(futures):
                try:
                    results = fut.result()
                except Exception as exc:  # noqa: BLE001 - a worker died (a crash inside an FMU) or was lost
                    reason = f"worker lost: {type(exc).__name__}: {' '.join(str(exc).split())}"[:500]
                    results = [(r, {"status": "crashed", "reason": reason}) for r in batches[fut.key]]
                rows.update(results)
                bar.update(len(results))
                fut.release()
                if time.perf_counter() - last > checkpoint_s:
                    write_results(out, campaign, setup, scenarios, rows, cancelled=True, workers=n_workers,
                                  elapsed=time.perf_counter() - t0)
                    last = time.perf_counter()
    except KeyboardInterrupt:
        client.cancel(futures)
        write_results(out, campaign, setup, scenarios, rows, cancelled=True, elapsed=time.perf_counter() - t0)
        if say:
            say(f"  interrupted          {len(rows)} of {campaign.runs} runs kept in {out / 'campaign.csv'}")
        raise
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    elapsed = time.perf_counter() - t0
    data = write_results(out, campaign, setup, scenarios, rows, elapsed=elapsed, workers=n_workers,
                         startup_s=t0 - t_start)
    worst = data.get("worst_max_bound_ratio")
    if worst is not None:
        result = run_scenario(setup, scenarios[worst["row"]])
        plot_campaign(rows, result, worst, out / "campaign.png", f"{setup.name}: {campaign.runs} runs")
    else:
        plot_campaign(rows, None, None, out / "campaign.png", f"{setup.name}: {campaign.runs} runs")
    return data


@single_blas_thread
def replay(campaign: Campaign, out, row: int) -> dict:
    """Re-run one row alone and write its ``results.csv``, ``metrics.json``, ``report.png`` and
    ``scenario.json`` into ``out/row-ROW``.

    Returns
    -------
    dict
        ``scenario``, ``metrics`` (of the run, or None when it failed), ``status``, ``reason``,
        ``paths`` and ``matches`` (whether the row of ``out/campaign.csv``, when there is one, has the
        very same numbers; None without one).
    """
    from .master import write_outputs

    out = check_output_dir(out, "--out folder")
    setup = prepare(campaign, out)
    sc = scenario(campaign, setup, row)
    folder = out / f"row-{row}"
    write_atomic(folder / "scenario.json", json.dumps(sc, indent=2) + "\n", "scenario")
    try:
        result = run_scenario(setup, sc)
    except UserError as exc:
        result, status, reason = None, "failed", " ".join(str(exc).split())[:500]
    else:
        status, reason = "ok", ""
    paths = {"scenario": folder / "scenario.json"}
    if result is not None:
        paths.update(write_outputs(result, folder, title=f"{setup.name}: campaign row {row}, steps {sc['steps']}"))
    matches = None
    table = out / "campaign.csv"
    if table.is_file():
        recorded = {r["row"]: r for r in read_table(table)}.get(str(row))
        if recorded is not None:
            mine = {**_flat(sc), "status": status, "reason": reason,
                    **(scalar_metrics(result.metrics) if result is not None else {})}
            matches = all(_cell(mine.get(k)) == v for k, v in recorded.items() if k != "wall_s")
    return {"scenario": sc, "metrics": None if result is None else result.metrics, "status": status,
            "reason": reason, "paths": paths, "matches": matches}


# --------------------------------------------------------------------------------------------
# the figure
# --------------------------------------------------------------------------------------------
def _hist(ax, values, color) -> None:
    """A histogram that copes with values all (nearly) equal."""
    values = np.asarray(values, dtype=float)
    lo, hi = float(values.min()), float(values.max())
    pad = max(abs(hi) * 1e-6, 1e-12)
    if hi - lo < pad:
        ax.hist(values, bins=1, range=(lo - pad, hi + pad), color=color)
        return
    ax.hist(values, bins=min(40, max(5, len(values) // 5)), range=(lo, hi), color=color)


def plot_campaign(rows: dict, worst_result, worst: dict | None, path, title: str = "") -> Path:
    """``campaign.png``: distributions of the convergence time and of the bound ratio, and the worst
    run's error against its certified bound."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = [m for m in rows.values() if m["status"] == "ok"]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    conv = [m["time_to_1pct"] for m in ok if m.get("time_to_1pct") is not None]
    never = sum(1 for m in ok if "time_to_1pct" in m and m["time_to_1pct"] is None)
    ax = axes[0]
    if conv:
        _hist(ax, conv, "tab:blue")
    ax.set_xlabel("time to 1 % of the initial error [s]")
    ax.set_ylabel("runs")
    ax.set_title(f"convergence ({len(conv)} runs" + (f", {never} never" if never else "") + ")")
    ratios = [m["max_bound_ratio"] for m in ok if m.get("max_bound_ratio") is not None]
    ax = axes[1]
    if ratios:
        _hist(ax, ratios, "tab:green")
        ax.axvline(1.0, color="tab:red", linestyle="--", label="bound")
        ax.legend()
    ax.set_xlabel("max_k ||e_k|| / certified bound_k")
    ax.set_title(f"bound ratio ({len(rows) - len(ok)} failed run(s))")
    ax = axes[2]
    if worst_result is not None:
        err = np.linalg.norm(worst_result.x - worst_result.xhat, axis=1)
        ax.semilogy(worst_result.times, np.maximum(err, 1e-300), label="||e_k||")
        if worst_result.bound is not None:
            ax.semilogy(worst_result.times, np.maximum(worst_result.bound, 1e-300), "--", label="certified bound")
        ax.legend()
        ax.set_title(f"worst run: row {worst['row']} (ratio {worst['value']:.4g})")
    else:
        ax.set_title("worst run: none with a bound")
    ax.set_xlabel("time [s]")
    fig.suptitle(title)
    fig.tight_layout()
    with atomic_output(path, "campaign figure") as part:
        fig.savefig(part, format="png", dpi=90)
    plt.close(fig)
    return Path(path)


__all__ = ["Axis", "Campaign", "Setup", "campaign_from_data", "load_campaign", "parse_axis", "plot_campaign",
           "prepare", "read_table", "replay", "run_campaign", "run_row", "run_scenario", "scaled_inputs",
           "scenario", "summary"]
