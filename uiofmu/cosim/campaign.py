"""Validation campaigns: many co-simulations of one observer against its plant, on Dask.

A campaign file (TOML, data only) names the FMUs (or a problem that gives them) and the axes a
run's scenario is drawn along: the step SPEC and its seed, an initial estimation error, a scale of
the unknown input, plant parameters. Every scenario is a function of the campaign's seed and the
row index only (:func:`scenario`), made when its batch is submitted (:func:`batches`), so one row
can be re-run alone and gives the same numbers bit for bit (:func:`replay`). The runs go to a
``dask.distributed`` cluster (a ``LocalCluster`` of worker processes, or an existing scheduler,
checked with a deadline first: :func:`probe_scheduler`): each worker receives the FMUs once (their
bytes, so a worker on another machine needs no shared folder), keeps them with the observer's
default inputs in a per-process cache, and runs batches of rows through
:func:`uiofmu.cosim.master.cosimulate`. A bounded window of batches is in flight
(:data:`BATCHES_PER_WORKER`); finished rows go to a file in row order (:class:`RowFile`) and into
compact counters and arrays for the summary (:class:`Tally`), so the memory of the command's process
does not grow with the runs beyond 8 bytes per run and quantile figure. Every output is written
into a staging folder next to the outputs and moved into place only when all of them are complete
(:class:`Staging`). A run an FMU refuses is recorded with its reason; an interrupted campaign writes
the rows that finished.

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
``constant`` (``value``). The random kinds draw every component of a vector independently. Every
number of an axis is at most :data:`AXIS_LIMIT` in magnitude; a plant parameter of type Integer
takes fmi2Integers only (:data:`uiofmu.cosim.fmi.FMI2_INTEGER`; a number or a list, no random draw).
"""

from __future__ import annotations

import atexit
import contextlib
import csv
import hashlib
import json
import math
import os
import re
import shutil
import tempfile
import threading
import time
from array import array
from dataclasses import dataclass, field, replace
from itertools import islice
from pathlib import Path

import numpy as np

from ..runtime.errors import FmuError, ProblemError, UserError
from ..runtime.files import OutputError, atomic_output, check_output_dir, check_output_file, parse_json, \
    parse_toml, read_bytes, read_text, write_atomic
from ..threads import single_blas_thread
from ..table import Table

#: Most runs of one campaign. What grows with the runs in the command's process is 8 bytes per
#: finished run for each of the :data:`QUANTILE_KEYS` (at most 480 MB at this limit): the rows go
#: to a file as they finish (twice its size on disk until the table is written).
MAX_RUNS = 10_000_000
#: Largest magnitude of a number of an axis (a value, mean, std, low, high): draws, their squares
#: and sums of squares (the error norms) stay far from overflow.
AXIS_LIMIT = 1e100
#: Batches in flight per worker: submitted, running, or finished and waiting for an earlier batch
#: to be written (the client holds at most this many batches per worker).
BATCHES_PER_WORKER = 8
#: Seconds to reach a Dask scheduler, hear its handshake and see a worker.
SCHEDULER_TIMEOUT_S = 10.0
#: Kinds of failure reasons (:func:`reason_kind`) counted one by one in the summary (the others are
#: counted together).
MAX_REASONS = 1000
#: The outputs of a campaign, replaced together.
OUTPUTS = ("campaign.csv", "summary.json", "campaign.png")
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

    def entries(self) -> list:
        """``(key, entry)`` of the values the axis lists (a choice's, a constant's; none for a draw)."""
        if self.kind == "choice":
            return [(f"{self.key}[{i}]", v) for i, v in enumerate(self.params["values"])]
        return [(self.key, self.params["value"])] if self.kind == "constant" else []

    def check_size(self, size: int) -> None:
        """Raise unless every listed vector has ``size`` components."""
        for where, v in self.entries():
            if isinstance(v, tuple) and len(v) != size:
                raise ProblemError(f"{where}: expected {size} value(s) (one per component), found {len(v)}")

    def check_integers(self, what: str, low: int, high: int) -> None:
        """Raise unless every value the axis can give is an integer in ``[low, high]``.

        Parameters
        ----------
        what : str
            What takes the values, for messages (``"the plant FMU's seed, an Integer parameter,"``).
        low, high : int
            The accepted range.
        """
        if self.kind in ("normal", "uniform"):
            raise ProblemError(f"{self.key}: {what} takes integers in [{low}, {high}], and a {self.kind} draw "
                               "is not one; give a number or a list of integers")
        for where, v in self.entries():
            for x in v if isinstance(v, tuple) else (v,):
                if not (x.is_integer() and low <= x <= high):
                    shown = int(x) if x.is_integer() and abs(x) < 1e18 else repr(x)
                    raise ProblemError(f"{where}: {what} takes integers in [{low}, {high}], found {shown}")

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



#: Largest campaign seed: a row's generator is seeded with the words ``[seed, row]``, and numpy splits a
#: seed of 2^32 or more into two 32-bit words, so seed 2^32 row 0 (``[0, 1, 0]``) would draw what
#: seed 0 row 1 (``[0, 1]``) draws.
MAX_SEED = 2**32 - 1

def _integer(table, key: str, default, low: int, high: int) -> int:
    value = table.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int):
        raise ProblemError(f"{table.key(key)}: expected an integer, found {value!r}"[:300])
    if not low <= value <= high:
        raise ProblemError(f"{table.key(key)}: expected an integer in [{low}, {high}], found {value}")
    return value


def _number(value, key: str, low: float = -AXIS_LIMIT) -> float:
    """A finite number of an axis, in ``[low, AXIS_LIMIT]``."""
    from ..runtime.matrices import as_scalar

    if isinstance(value, bool):
        raise ProblemError(f"{key}: expected a number, found {value!r}")
    return as_scalar(value, key, low=low, high=AXIS_LIMIT)


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
        params = {"mean": _number(table.get("mean", 0.0), table.key("mean")),
                  "std": _number(table.get("std"), table.key("std"), low=0.0)}
    else:
        params = {"low": _number(table.get("low"), table.key("low")),
                  "high": _number(table.get("high"), table.key("high"))}
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
    seed = _integer(camp, "seed", 0, 0, MAX_SEED)
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
            _not_a_folder(Path(spec[5:]), f"axes.steps[{i}]", "a step file")
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


def _not_a_folder(path: Path, key: str, what: str) -> None:
    """Refuse a folder where a file is expected, naming ``key`` and the path."""
    if path.is_dir():
        where = key if key == str(path) else f"{key}: {path}"
        raise ProblemError(f"{where}: a folder, not {what}; give a regular file"[:500])


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
    _not_a_folder(path, str(path), "a campaign file")
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
    has_xhat0 : bool
        Whether the observer has an initial estimate ``xhat0``.
    integers : tuple of str
        The plant parameters of the axes that are FMI Integers (their drawn values are ints).
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
    integers: tuple = ()
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
                experiment_steps=problem.experiment_steps, labels=problem.labels)
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
    from .fmi import read_description, vector_sizes
    from .master import default_steps, default_t_end, observer_card

    if campaign.problem is not None:
        if out is None:
            raise ProblemError("campaign.problem: building the FMUs needs an output folder")
        plant, observer = build_fmus(campaign, Path(out) / "fmus", say)
    else:
        plant, observer = campaign.plant, campaign.observer
        for key, path in (("campaign.observer", observer), ("campaign.plant", plant)):
            _not_a_folder(path, key, "an FMU file")
    card = observer_card(observer)
    variables = read_description(plant).modelVariables
    parameters = vector_sizes(variables, "parameter")
    initial = card.data.get("initial", {})
    has_xhat0 = "xhat0" in initial
    n = len(initial["xhat0"]) if has_xhat0 else 0
    if campaign.xhat0_error is not None:
        if not has_xhat0:
            raise ProblemError(f"axes.xhat0_error: the observer ({card.kernel} kernel) has no xhat0")
        campaign.xhat0_error.check_size(n)
    integers = _check_plant_axes(campaign, parameters, _vector_types(variables, "parameter"))
    if campaign.d_scale is not None:
        campaign.d_scale.check_size(1)
    plant_bytes = read_bytes(plant, "plant FMU", error=FmuError)
    observer_bytes = read_bytes(observer, "observer FMU", error=FmuError)
    t_end = campaign.t_end if campaign.t_end is not None else default_t_end(card)
    check_steps_axis(campaign.steps, card, t_end)
    return Setup(plant_bytes, observer_bytes, _digest(plant_bytes, observer_bytes), t_end, n, parameters,
                 default_steps(card), card.name, has_xhat0, integers=integers, plant_path=Path(plant),
                 observer_path=Path(observer))


def _seconds(low: float, high: float) -> str:
    return f"a step of {low:g} s" if low == high else f"steps from {low:g} to {high:g} s"


def check_steps_axis(specs, card, t_end: float) -> None:
    """Refuse a step SPEC of the ``steps`` axis that can give a step the observer does not take.

    Parameters
    ----------
    specs : sequence of str
        The axis' SPECs.
    card : uiofmu.runtime.card.Card
        The observer's card (its schedule decides the steps it takes:
        :func:`uiofmu.runtime.schedules.takes_steps`).
    t_end : float
        The campaign's horizon (a step file's steps past it are not taken).

    Raises
    ------
    ProblemError
        Naming the axis value, a step it can give, the steps the observer takes and a SPEC it takes.
    """
    from ..runtime.schedules import make_schedule, takes_steps
    from .master import default_steps
    from .steps import short_spec, step_ranges

    schedule = make_schedule(card.schedule, card.matrices)
    for i, spec in enumerate(specs):
        bad = next(((lo, hi) for lo, hi in step_ranges(spec, t_end) if not takes_steps(schedule, lo, hi)), None)
        if bad is None:
            continue
        taken = ", ".join(f"{h:g}" for h in schedule.admissible_steps())
        what = "its design period" if len(schedule.admissible_steps()) == 1 else "one of its design intervals"
        raise ProblemError(f"axes.steps[{i}] = {short_spec(spec)!r}: {_seconds(*bad)}, and the observer takes only "
                           f"{what}, {taken} s (within {schedule.step_rtol:g} relative; schedule.step_policy = "
                           f"{schedule.policy!r}); e.g. {default_steps(card)}")


def _vector_types(variables, causality: str) -> dict:
    """The FMI type (``Real``, ``Integer``, ...) of each vector ``name[1..k]`` of one causality."""
    return {v.name[:v.name.index("[")]: v.type for v in variables
            if v.causality == causality and v.name.endswith("]") and "[" in v.name}


def _check_plant_axes(campaign: Campaign, sizes: dict, types: dict) -> tuple:
    """Check the plant-parameter axes against the plant FMU's parameters; the names of the Integer ones.

    Raises
    ------
    ProblemError
        For a parameter the plant lacks, a vector of the wrong size, a non-integer (or out of range)
        value of an Integer parameter, or a parameter neither Real nor Integer.
    """
    from .fmi import FMI2_INTEGER

    integers = []
    for name, axis in campaign.plant_parameters:
        if name not in sizes:
            known = ", ".join(sizes) or "none"
            raise ProblemError(f"axes.plant_parameters.{name}: the plant FMU has no parameter {name} (it has {known})")
        axis.check_size(sizes[name])
        if types[name] == "Integer":
            axis.check_integers(f"the plant FMU's {name}, an Integer parameter,", *FMI2_INTEGER)
            integers.append(name)
        elif types[name] != "Real":
            raise ProblemError(f"axes.plant_parameters.{name}: the plant FMU's {name} is a {types[name]} parameter; "
                               "an axis sets Real and Integer ones")
    return tuple(integers)


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
    integers = {f"plant.{k}" for k in setup.integers}
    for name, axis in campaign.named_axes():
        size = sizes[name]
        value = axis.value(axis.params["values"][picks[name]], size) if name in picks else axis.draw(rng, size)
        kind = int if name in integers else float
        out[name] = float(value[0]) if name == "d_scale" else [kind(v) for v in value]
    return out


def scenarios(campaign: Campaign, setup: Setup, start: int = 0):
    """The scenarios of the rows from ``start`` on, each made when it is asked for (:func:`scenario`).

    Parameters
    ----------
    campaign : Campaign
    setup : Setup
    start : int
        The first row.

    Yields
    ------
    dict
        The scenario of row ``start``, then of the next rows up to ``campaign.runs - 1``.
    """
    for row in range(start, campaign.runs):
        yield scenario(campaign, setup, row)


def batches(campaign: Campaign, setup: Setup, size: int):
    """The scenarios of every row in row order, in lists of ``size`` (the last may be shorter), each
    made when it is asked for: a campaign of any number of runs starts at once.

    Yields
    ------
    list of dict
    """
    rows = scenarios(campaign, setup)
    while batch := list(islice(rows, size)):
        yield batch


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
    uiofmu.cosim.result.CosimResult

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
def _client(workers: int | None, address: str | None):
    """A Dask client: on the scheduler at ``address`` (that :func:`probe_scheduler` has heard), or on
    a new LocalCluster of worker processes."""
    import logging

    from distributed import Client, LocalCluster

    if address is not None:
        try:
            client = Client(address, timeout=f"{SCHEDULER_TIMEOUT_S}s")
        except Exception as exc:  # noqa: BLE001 - whatever the service did, it is not a usable scheduler
            raise SchedulerError(f"--scheduler {address}: {_failure_text(exc)}") from None
        try:
            client.wait_for_workers(1, timeout=SCHEDULER_TIMEOUT_S)
        except Exception:  # noqa: BLE001 - a TimeoutError, or the connection lost meanwhile
            client.close()
            raise SchedulerError(f"--scheduler {address}: no worker joined the scheduler within "
                                 f"{SCHEDULER_TIMEOUT_S:g} s") from None
        return client, None
    n = workers or os.cpu_count() or 1
    with _workers_ignore_interrupts():
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                               silence_logs=logging.ERROR)
    return Client(cluster), cluster


@contextlib.contextmanager
def _workers_ignore_interrupts():
    """Start worker processes with SIGINT ignored (a disposition a child keeps, and Python keeps at its start):
    Ctrl-C in a terminal reaches the whole process group, and only this process should answer it (it
    cancels the runs and writes the outputs); workers stopped by it printed tracebacks instead. Nothing
    changes off the main thread, where no handler can be set."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, before)


class SchedulerError(UserError):
    """A ``--scheduler`` address that is malformed, or where no Dask scheduler answers in time."""


_HOST_LABEL = re.compile(r"[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?\Z")


def _host_problem(host: str) -> str | None:
    """What is wrong with a host name or IP address (None when nothing is)."""
    import ipaddress

    if host.startswith("[") and host.endswith("]"):
        try:
            ipaddress.IPv6Address(host[1:-1])
        except ValueError:
            return "not an IPv6 address in brackets"
        return None
    if not host:
        return "no host"
    if len(host) > 253:
        return f"a host of {len(host)} characters, more than 253"
    if not all(_HOST_LABEL.match(label) for label in host.removesuffix(".").split(".")):
        return "not a host name (letters, digits and hyphens, in dot-separated labels of 1 to 63) or IP address"
    return None


def _split_address(value: str) -> tuple:
    """``(scheme, host, port)`` of an address (scheme tcp when none is given, port None without one)."""
    scheme, sep, rest = value.partition("://")
    if not sep:
        scheme, rest = "tcp", value
    host, colon, port = rest.rpartition(":")
    return (scheme, host, port) if colon else (scheme, rest, None)


def _address_problem(value) -> str | None:
    """What is wrong with a ``--scheduler`` value (None when nothing is)."""
    if not isinstance(value, str) or not value.strip():
        return "an empty address" if isinstance(value, str) else "not a string"
    scheme, host, port = _split_address(value)
    if scheme != "tcp":
        return f"the protocol {scheme[:20]!r} is not supported"
    if port is None:
        return "no port"
    if not (port.isascii() and port.isdigit() and len(port) <= 5 and 1 <= int(port) <= 65535):
        return f"the port {port[:20]!r} is not a number from 1 to 65535"
    return _host_problem(host)


def scheduler_address(value: str) -> str:
    """The address of ``--scheduler``: ``tcp://HOST:PORT``, or ``HOST:PORT`` (meaning tcp).

    Parameters
    ----------
    value : str
        As given.

    Returns
    -------
    str
        ``tcp://HOST:PORT``.

    Raises
    ------
    SchedulerError
        Naming the value, what is wrong with it and what is accepted.
    """
    problem = _address_problem(value)
    if problem:
        shown = repr(value[:80]) + ("..." if len(value) > 80 else "") if isinstance(value, str) else repr(value)[:80]
        raise SchedulerError(f"--scheduler {shown}: {problem}; expected tcp://HOST:PORT or HOST:PORT (a host "
                             "name or IP address, a port from 1 to 65535)")
    _, host, port = _split_address(value)
    return f"tcp://{host}:{int(port)}"


def _failure_text(exc: BaseException) -> str:
    """An exception in a few words, on one line."""
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}"[:300] if text else type(exc).__name__


async def _identity(address: str, timeout: float):
    """The scheduler's answer to ``identity`` (after the comm handshake), within ``timeout`` seconds."""
    import asyncio

    from distributed.comm import connect

    async def ask():
        comm = await connect(address, timeout=timeout / 2)
        try:
            await comm.write({"op": "identity", "reply": True})
            return await comm.read()
        finally:
            comm.abort()

    return await asyncio.wait_for(ask(), timeout)


def probe_scheduler(address: str, timeout: float | None = None) -> dict:
    """Check that a Dask scheduler answers at ``address``, all within ``timeout`` seconds.

    Connecting, the protocol's handshake and an ``identity`` request run on their own event loop in
    a daemon thread that is given up after the deadline: a service that accepts connections and then
    says nothing, or answers in another protocol (HTTP, whose first bytes read as a frame length
    of exabytes), is refused in bounded time.

    Parameters
    ----------
    address : str
        ``tcp://HOST:PORT`` (:func:`scheduler_address`).
    timeout : float, optional
        Seconds (default :data:`SCHEDULER_TIMEOUT_S`).

    Returns
    -------
    dict
        The scheduler's identity (``type``, ``address``, ``workers``, ...).

    Raises
    ------
    SchedulerError
        One line naming the address and what happened.
    """
    import asyncio

    timeout = SCHEDULER_TIMEOUT_S if timeout is None else timeout
    box: dict = {}

    def work() -> None:
        try:
            box["reply"] = asyncio.run(_identity(address, timeout))
        except BaseException as exc:  # noqa: BLE001 - handed to the caller's thread
            box["error"] = exc

    thread = threading.Thread(target=work, name="uiofmu-scheduler-probe", daemon=True)
    thread.start()
    thread.join(timeout + 1.0)
    error = box.get("error")
    if thread.is_alive() or isinstance(error, TimeoutError):
        raise SchedulerError(f"--scheduler {address}: no answer of a Dask scheduler within {timeout:g} s (the "
                             "service there accepts connections but does not speak Dask's protocol?)")
    if isinstance(error, OSError):
        raise SchedulerError(f"--scheduler {address}: no Dask scheduler reachable there ({_failure_text(error)})")
    if isinstance(error, MemoryError):    # a length prefix of exabytes: the first bytes of another protocol
        raise SchedulerError(f"--scheduler {address}: the service there answers in another protocol than Dask's "
                             "(its first bytes announce a message too large to hold)")
    if error is not None:
        raise SchedulerError(f"--scheduler {address}: the service there does not answer as a Dask scheduler "
                             f"({_failure_text(error)})")
    reply = box["reply"]
    if not isinstance(reply, dict) or reply.get("type") != "Scheduler":
        kind = reply.get("type") if isinstance(reply, dict) else type(reply).__name__
        raise SchedulerError(f"--scheduler {address}: the service there answers, but as a {str(kind)[:40]}, "
                             "not as a Dask scheduler")
    return reply


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


def read_table(path) -> list:
    """A campaign table as a list of dicts of strings (the CSV cells)."""
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


#: Cells of a row that are not metrics.
_NOT_METRICS = ("status", "reason", "wall_s")


class RowFile:
    """The rows of a campaign as they finish, in row order, in a file (one CSV line a row): the row and
    axis cells, ``status``, ``reason``, ``wall_s``, then the metric cells in the order their keys first
    appeared (a later key adds a cell at the end). :meth:`write_table` writes the table from it.

    Parameters
    ----------
    path : Path
        The file (in the staging folder).
    campaign : Campaign
    setup : Setup
    """

    def __init__(self, path: Path, campaign: Campaign, setup: Setup):
        self.path = path
        self.head = HEAD + axis_columns(campaign, setup) + ["status", "reason"]
        self.keys: dict = {}
        self.file = open(path, "w", newline="", encoding="utf-8")
        self.writer = csv.writer(self.file, lineterminator="\n")

    def add(self, sc: dict, result: dict) -> None:
        """Append the row of scenario ``sc`` and its ``result`` (status, reason, metrics)."""
        values = {**_flat(sc), **result}
        metrics = [k for k in result if k not in _NOT_METRICS]
        for key in metrics:
            self.keys.setdefault(key, len(self.keys))
        cells = [""] * len(self.keys)
        for key in metrics:
            cells[self.keys[key]] = _cell(result[key])
        self.writer.writerow([_cell(values.get(c)) for c in self.head] + [_cell(result.get("wall_s"))] + cells)

    def columns(self) -> list:
        """The table's columns: the head, the metrics (:data:`PREFERRED` first) and ``wall_s``."""
        metrics = [k for k in PREFERRED if k in self.keys] + [k for k in self.keys if k not in PREFERRED]
        return self.head + metrics + ["wall_s"]

    def write_table(self, path: Path) -> Path:
        """Write ``campaign.csv`` of the rows so far to ``path``, atomically, reading the file once."""
        self.file.flush()
        n = len(self.head)
        where = [n + 1 + self.keys[k] for k in self.columns()[n:-1]]
        with atomic_output(path, "campaign table") as part, open(self.path, newline="", encoding="utf-8") as src, \
                open(part, "w", newline="", encoding="utf-8") as dst:
            writer = csv.writer(dst, lineterminator="\n")
            writer.writerow(self.columns())
            for cells in csv.reader(src):
                writer.writerow(cells[:n] + [cells[i] if i < len(cells) else "" for i in where] + [cells[n]])
            dst.flush()
            os.fsync(dst.fileno())
        return path

    def close(self) -> None:
        """Close the file."""
        self.file.close()


_NUMBER = re.compile(r"(?<![\w.])[-+]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][-+]?\d+)?(?!\w)")


def reason_kind(reason: str) -> str:
    """A failure reason with its numbers masked as ``#`` (not the digits inside a name such as
    ``fmi2Discard``): the reasons of one kind of failure, whatever its step, time or value.

    Examples
    --------
    >>> reason_kind("refused step 12 (t = 1.2 s): h = 1.5e-3 s is not dt = 0.1 s (fmi2Discard)")
    'refused step # (t = # s): h = # s is not dt = # s (fmi2Discard)'
    """
    return _NUMBER.sub("#", reason)


class Tally:
    """What the summary and the figure need of the finished rows, kept compact: counters, the failure
    reasons grouped by kind (:func:`reason_kind`; at most :data:`MAX_REASONS` kinds, each with its count,
    one example and its first rows), the worst bound ratio and its row (and how many runs have their
    largest ratio at k = 1), and per :data:`QUANTILE_KEYS` figure an array of doubles of its values.
    Rows must come in row order (the worst ratio's row is then the first of equal ratios)."""

    def __init__(self):
        self.finished = self.ok = self.violations = self.other_reasons = self.ratios = self.ratios_at_start = 0
        self.reasons: dict = {}
        self.worst: tuple | None = None
        self.values = {key: array("d") for key in QUANTILE_KEYS}
        self.present = dict.fromkeys(QUANTILE_KEYS, 0)

    def add(self, row: int, result: dict) -> None:
        """Count the ``result`` of ``row``."""
        self.finished += 1
        if result["status"] != "ok":
            self._failure(row, result)
            return
        self.ok += 1
        for key in QUANTILE_KEYS:
            if key in result:
                self.present[key] += 1
                if result[key] is not None:
                    self.values[key].append(result[key])
        ratio = result.get("max_bound_ratio")
        if ratio is not None and not math.isnan(ratio):
            self.ratios += 1
            self.ratios_at_start += result.get("max_bound_ratio_step") == 1
            if self.worst is None or ratio > self.worst[0]:
                self.worst = (ratio, row, result.get("bound_respected"), result.get("max_bound_ratio_step"))
        self.violations += result.get("bound_respected") is False

    def _failure(self, row: int, result: dict) -> None:
        kind = (result["status"], reason_kind(result["reason"]))
        entry = self.reasons.get(kind)
        if entry is None:
            if len(self.reasons) >= MAX_REASONS:
                self.other_reasons += 1
                return
            entry = self.reasons[kind] = {"kind": kind[1], "status": result["status"], "count": 0,
                                          "example": result["reason"], "rows": []}
        entry["count"] += 1
        if len(entry["rows"]) < 20:
            entry["rows"].append(row)

    def quantiles(self) -> dict:
        """Per figure: its count, the runs without it (``never`` reached 1 %, or ``missing``), and the
        quantiles and mean of its finite values (``non_finite`` counts the others, when there are)."""
        out = {}
        for key in QUANTILE_KEYS:
            if not self.present[key]:
                continue
            values = np.frombuffer(self.values[key], dtype=float)
            finite = values[np.isfinite(values)]
            entry = {"count": len(values), "never" if key in ("steps_to_1pct", "time_to_1pct") else "missing":
                     self.present[key] - len(values)}
            if len(finite) < len(values):
                entry["non_finite"] = len(values) - len(finite)
            if finite.size:
                entry.update({f"q{int(round(q * 100)):02d}": float(np.quantile(finite, q)) for q in QUANTILES})
                entry["mean"] = float(np.mean(finite))
            out[key] = entry
        return out


def summary(campaign: Campaign, setup: Setup, tally: Tally, cancelled: bool = False,
            elapsed: float | None = None, workers: int | None = None, startup_s: float | None = None) -> dict:
    """``summary.json``: runs, failures and their reasons by kind, the worst bound ratio with its row,
    step and scenario (``every_run_at_bound_start``: every run's largest ratio is at k = 1, the first
    step it is measured at, so the worst row stands out by that step alone), quantiles of the
    convergence figures; ``elapsed_s`` and ``runs_per_s`` count from the
    cluster's start (``cluster_startup_s`` before it) to the last row."""
    ranked = sorted(tally.reasons.values(), key=lambda e: -e["count"])
    out = {"campaign": str(campaign.path), "observer": setup.name, "runs": campaign.runs,
           "finished": tally.finished, "ok": tally.ok, "failures": tally.finished - tally.ok,
           "failure_reasons": ranked[:50], "cancelled": cancelled, "seed": campaign.seed, "t_end": setup.t_end}
    if tally.other_reasons:
        out["failures_of_other_reasons"] = tally.other_reasons
    if tally.worst is not None:
        value, row, respected, step = tally.worst
        out["worst_max_bound_ratio"] = {"value": value, "row": row, "step": step,
                                        "scenario": scenario(campaign, setup, row), "bound_respected": respected,
                                        "every_run_at_bound_start": tally.ratios_at_start == tally.ratios}
        out["bound_violations"] = tally.violations
    else:
        out["worst_max_bound_ratio"] = None
    out["quantiles"] = tally.quantiles()
    if elapsed is not None:
        out["elapsed_s"] = elapsed
        out["runs_per_s"] = tally.finished / elapsed if elapsed > 0 else None
    if startup_s is not None:
        out["cluster_startup_s"] = startup_s
    if workers is not None:
        out["workers"] = workers
    out["axes"] = {"steps": list(campaign.steps or (setup.default_steps,)),
                   **{name: axis.describe() for name, axis in campaign.named_axes()}}
    return out


class Staging:
    """A folder ``campaign.partial-*`` in the output folder that receives every output of a campaign
    (and its checkpoints); :meth:`install` moves them into place together, so the outputs of the
    folder are all of one campaign. On failure the folder is removed, unless it holds a checkpoint
    (the rows of a campaign that did not finish).

    Parameters
    ----------
    out : Path
        The output folder (created).
    """

    def __init__(self, out: Path):
        for name in OUTPUTS:
            check_output_file(out / name, "campaign output")
        try:
            out.mkdir(parents=True, exist_ok=True)
            self.folder = Path(tempfile.mkdtemp(prefix="campaign.partial-", dir=out))
        except OSError as exc:
            raise OutputError(f"{out}: cannot write the campaign outputs there ({exc.strerror or exc})") from None
        self.out = out
        self.checkpointed = False

    def path(self, name: str) -> Path:
        """Where the output ``name`` is written before it is installed."""
        return self.folder / name

    def install(self) -> None:
        """Move every output into the output folder (each rename atomic), then remove the staging folder."""
        try:
            for name in OUTPUTS:
                os.replace(self.folder / name, self.out / name)
        except OSError as exc:
            raise OutputError(f"{self.out}: cannot put the campaign outputs in place ({exc.strerror or exc})") \
                from None
        self.checkpointed = False

    def close(self) -> None:
        """Remove the staging folder (kept when it holds the checkpoint of a campaign that failed)."""
        if not self.checkpointed:
            shutil.rmtree(self.folder, ignore_errors=True)


def _batch_size(campaign: Campaign, workers: int) -> int:
    if campaign.batch:
        return campaign.batch
    return int(min(64, max(1, campaign.runs // (8 * max(1, workers)))))


class _Run:
    """One campaign on a Dask client: a bounded window of batches in flight, their rows written in
    row order to a :class:`RowFile` and counted in a :class:`Tally`, checkpoints and outputs in a
    :class:`Staging` folder."""

    def __init__(self, campaign: Campaign, setup: Setup, client, stage: Staging, workers: int,
                 checkpoint_s: float):
        self.campaign, self.setup, self.client, self.stage, self.workers = campaign, setup, client, stage, workers
        self.rows = RowFile(stage.path("rows.part"), campaign, setup)
        self.tally = Tally()
        self.inflight: dict = {}      # future key -> (batch index, future, scenarios)
        self.waiting: dict = {}       # batch index -> (scenarios, results), finished before an earlier batch
        self.next = 0                 # the next batch to write
        self.t0 = time.perf_counter()
        self.checkpoint_s, self.last_checkpoint = checkpoint_s, time.perf_counter()

    def drive(self, bar) -> None:
        """Submit the batches, at most :data:`BATCHES_PER_WORKER` per worker in flight, and take their
        rows as they finish."""
        from distributed import as_completed

        shared = self.client.scatter(self.setup, broadcast=True)
        source = enumerate(batches(self.campaign, self.setup, _batch_size(self.campaign, self.workers)))
        window = BATCHES_PER_WORKER * max(1, self.workers)
        finished = as_completed()
        self._fill(source, window, shared, finished)
        for fut in finished:
            index, _, scs = self.inflight.pop(fut.key)
            self.waiting[index] = (scs, self._results(fut, scs))
            fut.release()
            bar.update(len(scs))
            self._write_ready()
            self._checkpoint()
            self._fill(source, window, shared, finished)

    def _fill(self, source, window: int, shared, finished) -> None:
        while len(self.inflight) + len(self.waiting) < window:
            item = next(source, None)
            if item is None:
                return
            index, scs = item
            fut = self.client.submit(run_batch, shared, scs, pure=False)
            self.inflight[fut.key] = (index, fut, scs)
            finished.add(fut)

    @staticmethod
    def _results(fut, scs: list) -> list:
        try:
            return fut.result()
        except Exception as exc:  # noqa: BLE001 - a worker died (a crash inside an FMU) or was lost
            reason = f"worker lost: {type(exc).__name__}: {' '.join(str(exc).split())}"[:500]
            return [(sc["row"], {"status": "crashed", "reason": reason}) for sc in scs]

    def _write_ready(self, everything: bool = False) -> None:
        """Write the finished batches that follow the rows written (``everything``: all of them, in order)."""
        for index in sorted(self.waiting) if everything else ():
            self._write(self.waiting.pop(index))
        while self.next in self.waiting:
            self._write(self.waiting.pop(self.next))
            self.next += 1

    def _write(self, batch) -> None:
        scs, results = batch
        for sc, (row, result) in zip(scs, results):
            self.rows.add(sc, result)
            self.tally.add(row, result)

    def _checkpoint(self) -> None:
        """Rewrite the table and summary in the staging folder, at most every ``checkpoint_s`` and at
        most a tenth of the time (the table is rewritten whole)."""
        if time.perf_counter() - self.last_checkpoint <= self.checkpoint_s:
            return
        t = time.perf_counter()
        self.write(cancelled=True)
        self.stage.checkpointed = True
        took = time.perf_counter() - t
        self.checkpoint_s = max(self.checkpoint_s, 10 * took)
        self.last_checkpoint = time.perf_counter()

    def cancel(self) -> None:
        """Cancel what is in flight and take the rows that finished."""
        self.client.cancel([fut for _, fut, _ in self.inflight.values()])
        self.inflight.clear()
        self._write_ready(everything=True)

    def write(self, cancelled: bool, **info) -> dict:
        """Write ``campaign.csv`` and ``summary.json`` of the rows so far into the staging folder."""
        self.rows.write_table(self.stage.path("campaign.csv"))
        data = summary(self.campaign, self.setup, self.tally, cancelled=cancelled, workers=self.workers,
                       elapsed=time.perf_counter() - self.t0, **info)
        write_atomic(self.stage.path("summary.json"), json.dumps(data, indent=2) + "\n", "campaign summary")
        return data

    def finish(self, cancelled: bool, **info) -> dict:
        """Write every output into the staging folder (the figure re-runs the worst row), then install them."""
        data = self.write(cancelled, **info)
        worst = data.get("worst_max_bound_ratio")
        result = run_scenario(self.setup, worst["scenario"]) if worst is not None else None
        plot_campaign(self.tally, result, worst, self.stage.path("campaign.png"),
                      f"{self.setup.name}: {self.campaign.runs} runs")
        self.rows.close()
        self.stage.install()
        return data


def run_campaign(campaign: Campaign, out, workers: int | None = None, scheduler: str | None = None,
                 show_progress: bool | None = None, say=None, checkpoint_s: float = 30.0) -> dict:
    """Run every row of a campaign on Dask and write ``campaign.csv``, ``summary.json``, ``campaign.png``.

    The outputs are replaced together (:class:`Staging`): a campaign that fails leaves the old ones
    as they were; while it runs, ``out/campaign.partial-*/`` holds a checkpoint of the table and
    summary (kept if the campaign fails after writing one).

    Parameters
    ----------
    campaign : Campaign
    out : str or Path
        Output folder.
    workers : int, optional
        Worker processes of the LocalCluster (default: ``os.cpu_count()``).
    scheduler : str, optional
        Address of an existing Dask scheduler instead (``tcp://host:8786``, :func:`scheduler_address`).
    show_progress : bool, optional
        Progress bar (default: when stderr is a terminal).
    say : callable, optional
        Where progress lines go.
    checkpoint_s : float
        The checkpoint is rewritten (atomically) at most this often while rows come in (and at most
        a tenth of the time).

    Returns
    -------
    dict
        The summary.

    Raises
    ------
    SchedulerError
        For a malformed scheduler address, or none that answers within :data:`SCHEDULER_TIMEOUT_S`.
    KeyboardInterrupt
        After writing the outputs of the rows that finished (``summary["cancelled"]`` is true).
    """
    from ..progress import progress

    out = check_output_dir(out, "--out folder")
    address = scheduler_address(scheduler) if scheduler is not None else None
    if address is not None:
        probe_scheduler(address)
    stage = Staging(out)
    client = cluster = None
    try:
        setup = prepare(campaign, out, say)
        t_start = time.perf_counter()
        client, cluster = _client(workers, address)
        n_workers = len(client.scheduler_info(n_workers=-1)["workers"]) or (workers or 1)
        if say:
            where = f"scheduler {address}" if address else "a LocalCluster"
            say(f"  runs                 {campaign.runs} on {n_workers} worker(s) of {where}")
        run = _Run(campaign, setup, client, stage, n_workers, checkpoint_s)
        startup_s = run.t0 - t_start
        try:
            with progress(total=campaign.runs, desc="campaign", unit="run", enabled=show_progress) as bar:
                run.drive(bar)
        except KeyboardInterrupt:
            run.cancel()
            run.finish(cancelled=True, startup_s=startup_s)
            if say:
                say(f"  interrupted          {run.tally.finished} of {campaign.runs} runs kept in "
                    f"{out / 'campaign.csv'}")
            raise
        return run.finish(cancelled=False, startup_s=startup_s)
    finally:
        stage.close()
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()


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
    from .steps import short_spec

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
        title = f"{setup.name}: campaign row {row}, steps {short_spec(sc['steps'])}"
        paths.update(write_outputs(result, folder, title=title))
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
def _hist(ax, values, color, marks: tuple = ()) -> int:
    """A histogram of the finite values, its axis in plain numbers (no offset such as ``1e-6+1``); values
    all (nearly) equal give one bar, wide enough to see beside the ``marks`` (x positions the caller
    draws), ticked at its value and annotated with the spread. How many values it drew."""
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    if not values.size:
        return 0
    lo, hi = float(values.min()), float(values.max())
    pad = max(abs(hi) * 1e-6, 1e-12)
    if hi - lo < pad:
        far = [m for m in marks if abs(m - lo) > pad]
        pad = max([pad] + [0.02 * abs(m - lo) for m in far])
        ax.hist(values, bins=1, range=(lo - pad, hi + pad), color=color)
        ax.set_xticks([lo, *far])
        ax.set_xticklabels([f"{x:.6g}" for x in (lo, *far)])
        same = f"all {values.size} at {lo:.10g}" if lo == hi else \
            f"all {values.size} within {hi - lo:.1e} of {lo:.10g}"
        ax.annotate(same, (0.5, 0.5), xycoords="axes fraction", ha="center", color="black",
                    bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none"})
    else:
        ax.hist(values, bins=min(40, max(5, len(values) // 5)), range=(lo, hi), color=color)
        ax.ticklabel_format(axis="x", style="plain", useOffset=False)
    return values.size


def plot_campaign(tally: Tally, worst_result, worst: dict | None, path, title: str = "") -> Path:
    """``campaign.png``: distributions of the convergence time and of the bound ratio (their finite
    values), and the worst run's error against its certified bound.

    Parameters
    ----------
    tally : Tally
        The finished rows.
    worst_result : uiofmu.cosim.result.CosimResult or None
        The worst run, re-run.
    worst : dict or None
        The summary's ``worst_max_bound_ratio``.
    path : str or Path
        The PNG file (written atomically).
    title : str

    Returns
    -------
    Path
    """
    from .report import pyplot

    plt = pyplot()[0]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    conv = tally.values["time_to_1pct"]
    never = tally.present["time_to_1pct"] - len(conv)
    ax = axes[0]
    drawn = _hist(ax, conv, "tab:blue")
    ax.set_xlabel("time to 1 % of the initial error [s]")
    ax.set_ylabel("runs")
    ax.set_title(f"convergence: {drawn} run(s) under 1 %" + (f", {never} not within the run" if never else ""))
    ax = axes[1]
    if _hist(ax, tally.values["max_bound_ratio"], "tab:green", marks=(1.0,)):
        ax.axvline(1.0, color="tab:red", linestyle="--", label="bound")
        ax.legend()
    ax.set_xlabel("max over k >= 1 of ||e_k|| / certified bound_k")
    ax.set_title(f"bound ratio ({tally.finished - tally.ok} failed run(s))")
    ax = axes[2]
    if worst_result is not None:
        err = np.linalg.norm(worst_result.x - worst_result.xhat, axis=1)
        ax.semilogy(worst_result.times, np.maximum(err, 1e-300), label="||e_k||")
        if worst_result.bound is not None:
            ax.semilogy(worst_result.times, np.maximum(worst_result.bound, 1e-300), "--", label="certified bound")
        ax.legend()
        if worst.get("every_run_at_bound_start"):
            ax.set_title(f"every run nearest its bound at k = 1 (ratio up to {worst['value']:.4g}); row {worst['row']}",
                         fontsize=10)
        else:
            ax.set_title(f"worst run: row {worst['row']} (ratio {worst['value']:.4g} at k = {worst['step']})")
    else:
        ax.set_title("worst run: none with a bound")
    ax.set_xlabel("time [s]")
    fig.suptitle(title)
    fig.tight_layout()
    try:
        with atomic_output(path, "campaign figure") as part:
            fig.savefig(part, format="png", dpi=90)
    finally:
        plt.close(fig)
    return Path(path)


__all__ = ["Axis", "Campaign", "RowFile", "SchedulerError", "Setup", "Staging", "Tally", "batches",
           "campaign_from_data", "load_campaign", "parse_axis", "plot_campaign", "prepare",
           "probe_scheduler", "read_table", "replay", "run_campaign", "run_row", "run_scenario", "scaled_inputs",
           "scenario", "scenarios", "scheduler_address", "summary"]
