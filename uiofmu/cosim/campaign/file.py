"""The campaign file: a TOML file (data only) that names the FMUs (or a problem that gives them)
and the axes a run's scenario is drawn along (:mod:`uiofmu.cosim.campaign`).

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
    noise_y = [0.0, 0.01, 0.05]                              # sensor noise std per output (cosim --noise)
    quantization = [0.0, 0.1]                                # output quantum (0: none)
    plant_mismatch = [0.0, 0.01, 0.05]                       # relative perturbation of A, B, E (0: none)
    noise_w = [0.0, 0.1]                                     # process noise std per column of [plant] W

An axis value is a number (constant), a list (one entry drawn per run; with ``grid = true`` each
entry is a grid point; for a vector an entry may be a list of its size), or a table with ``kind``:
``normal`` (``std``, ``mean`` = 0), ``uniform`` (``low``, ``high``), ``choice`` (``values``) or
``constant`` (``value``). The random kinds draw every component of a vector independently. Every
number of an axis is at most :data:`AXIS_LIMIT` in magnitude; a plant parameter of type Integer
takes fmi2Integers only (:data:`uiofmu.cosim.fmi.FMI2_INTEGER`; a number or a list, no random draw).
``noise_y`` is the std of white sensor noise per output (a number for all, or one per output; 0: none),
so at least 0: a constant, a choice or a uniform draw with ``low >= 0``; each row's noise has its own seed
(the column ``noise_seed``), and the run measures its noise gain (:mod:`uiofmu.cosim.noise`).
``quantization`` is an output quantum Q >= 0 (0: none): the observer receives ``y`` rounded to multiples
of Q, after the noise, and the run measures the noise gain on what it received.
``plant_mismatch`` is a relative standard deviation >= 0 (0: the design model) the plant FMU perturbs its
``A``, ``B``, ``E`` by (its parameters ``mismatch`` and ``mismatch_seed``, :mod:`uiofmu.runtime.mismatch`;
plants of matrices only): each row draws its own plant (the column ``mismatch_seed``), and its bound may be
broken by the mismatch it asked for.
``noise_w`` is the std of white process noise per column of the problem's ``[plant] W`` (the plant FMU's
input ``w_noise``; a plant without it exits 2), as ``uiofmu cosim --noise w=STD`` adds it, each row with its
own seed (the column ``noise_w_seed``); it is measured alone (not with ``noise_y`` or ``quantization``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ...runtime.errors import ProblemError
from ...runtime.files import parse_toml, read_text
from ...table import Table

#: Most runs of one campaign. What grows with the runs in the command's process is 8 bytes per
#: finished run for each of the :data:`QUANTILE_KEYS` (at most 800 MB at this limit): the rows go
#: to a file as they finish (twice its size on disk until the table is written).
MAX_RUNS = 10_000_000
#: Largest magnitude of a number of an axis (a value, mean, std, low, high): draws, their squares
#: and sums of squares (the error norms) stay far from overflow.
AXIS_LIMIT = 1e100
#: Distribution kinds of an axis.
KINDS = ("constant", "choice", "normal", "uniform")
#: Keys of the [campaign] and [axes] tables.
CAMPAIGN_KEYS = ("problem", "observer", "plant", "runs", "seed", "t_end", "grid", "backend", "batch")
AXES_KEYS = ("steps", "xhat0_error", "d_scale", "plant_parameters", "noise_y", "quantization", "plant_mismatch",
             "noise_w")


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
    noise_y : Axis or None
        The std of the sensor noise per output.
    quantization : Axis or None
        The output quantum.
    plant_mismatch : Axis or None
        The relative standard deviation of the plant's perturbation.
    noise_w : Axis or None
        The std of the process noise per column of ``W``.
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
    noise_y: Axis | None = None
    quantization: Axis | None = None
    plant_mismatch: Axis | None = None
    noise_w: Axis | None = None

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
        out += [(f"plant.{name}", a) for name, a in self.plant_parameters]
        return out + [(name, a) for name, a in (("noise_y", self.noise_y), ("quantization", self.quantization),
                                                ("plant_mismatch", self.plant_mismatch), ("noise_w", self.noise_w))
                      if a]



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
    from ...runtime.matrices import as_scalar

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
    path = Path(path)
    camp, axes = _tables(data)
    problem, observer, plant = _sources(camp, path.parent)
    settings = _settings(camp, problem)
    steps = _steps_axis(axes, path.parent)
    xhat0_error = parse_axis(axes.get("xhat0_error"), "axes.xhat0_error") if axes.has("xhat0_error") else None
    d_scale = parse_axis(axes.get("d_scale"), "axes.d_scale") if axes.has("d_scale") else None
    plant_parameters = _plant_axes(axes)
    noise_y, quantization, plant_mismatch, noise_w = (
        _std_axis(parse_axis(axes.get(key), f"axes.{key}")) if axes.has(key) else None
        for key in ("noise_y", "quantization", "plant_mismatch", "noise_w"))
    axes.done()

    runs = settings.pop("runs")
    campaign = Campaign(path=path, problem=problem, observer=observer, plant=plant, runs=runs or 0,
                        steps=tuple(steps), xhat0_error=xhat0_error, d_scale=d_scale,
                        plant_parameters=tuple(plant_parameters), text=text, noise_y=noise_y,
                        quantization=quantization, plant_mismatch=plant_mismatch, noise_w=noise_w, **settings)
    return replace(campaign, runs=_runs(campaign, runs))


def _tables(data: dict) -> tuple:
    """The ``[campaign]`` and ``[axes]`` tables, refusing any other table and any unknown key."""
    top = Table(data, "")
    camp = Table(top.get("campaign"), "campaign")
    axes = Table(top.get("axes", {}), "axes")
    top.done()
    for table, known in ((camp, CAMPAIGN_KEYS), (axes, AXES_KEYS)):
        unknown = sorted(str(k) for k in table.data if k not in known)
        if unknown:
            raise ProblemError(f"{table.key(unknown[0])[:200]}: unknown key (known here: {', '.join(known)})")
    return camp, axes


def _sources(camp: Table, folder: Path) -> tuple:
    """``(problem, observer, plant)`` paths of the ``[campaign]`` table: a problem, or both FMUs."""

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
    return problem, observer, plant


def _settings(camp: Table, problem: Path | None) -> dict:
    """``seed``, ``grid``, ``t_end``, ``backend``, ``batch`` and ``runs`` (None when not given) of the
    ``[campaign]`` table, the last of its keys read."""
    seed = _integer(camp, "seed", 0, 0, MAX_SEED)
    grid = camp.get("grid", False)
    if not isinstance(grid, bool):
        raise ProblemError(f"campaign.grid: expected true or false, found {grid!r}"[:300])
    t_end = camp.get("t_end", None)
    if t_end is not None:
        from ...runtime.matrices import as_scalar

        t_end = as_scalar(t_end, "campaign.t_end", low=0.0, open_low=True)
    backend = camp.choice("backend", ("c", "python"), None) if camp.has("backend") else camp.get("backend", None)
    if backend is not None and problem is None:
        raise ProblemError("campaign.backend: only with campaign.problem (the FMUs given are built already)")
    batch = _integer(camp, "batch", None, 1, 100_000) if camp.has("batch") else camp.get("batch", None)
    runs = _integer(camp, "runs", None, 1, MAX_RUNS) if camp.has("runs") else camp.get("runs", None)
    camp.done()
    return {"seed": seed, "grid": grid, "t_end": t_end, "backend": backend, "batch": batch, "runs": runs}


def _steps_axis(axes: Table, folder: Path) -> list:
    """The step SPECs of ``axes.steps`` (a step file's path made relative to ``folder``), each
    checked for its syntax."""
    from ..steps import step_sequence

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
            not_a_folder(Path(spec[5:]), f"axes.steps[{i}]", "a step file")
        try:
            step_sequence(spec, 1e-300, 0)      # the SPEC's syntax (one step suffices)
        except ProblemError as exc:
            raise ProblemError(f"axes.steps[{i}]: {str(exc).removeprefix('--steps').lstrip(': ')}") from None
    return steps


def _plant_axes(axes: Table) -> list:
    """``(name, Axis)`` of ``axes.plant_parameters``, in the order of the file."""
    params = axes.get("plant_parameters", {})
    ptable = Table(params, "axes.plant_parameters")
    plant_parameters = []
    for name in ptable.data:
        if not isinstance(name, str) or not name.isidentifier() or len(name) > 64:
            raise ProblemError(f"axes.plant_parameters.{str(name)[:64]}: not a parameter name")
        plant_parameters.append((name, parse_axis(ptable.get(name), ptable.key(name))))
    return plant_parameters


def _std_axis(axis: Axis) -> Axis:
    """A standard deviation's (or a quantum's) axis: every value it can give at least 0 (no normal draw)."""
    if axis.kind == "normal":
        raise ProblemError(f"{axis.key}: a standard deviation is >= 0, and a normal draw is not always; give a "
                           "number, a list or a uniform draw with low >= 0")
    if axis.kind == "uniform" and axis.params["low"] < 0:
        raise ProblemError(f"{axis.key}: a standard deviation is >= 0, found low = {axis.params['low']:g}")
    for where, v in axis.entries():
        for x in v if isinstance(v, tuple) else (v,):
            if x < 0:
                raise ProblemError(f"{where}: a standard deviation is >= 0, found {x:g}")
    return axis


def _runs(campaign: Campaign, runs: int | None) -> int:
    """The number of runs: as given, or the grid's points (a multiple of them with a grid)."""
    size = campaign.grid_size()
    if campaign.grid:
        if runs is None:
            runs = size
        elif runs % size:
            raise ProblemError(f"campaign.runs: with grid = true, a multiple of the grid's {size} points "
                               f"({' x '.join(f'{n} {k}' for k, n in campaign.grid_axes())}), found {runs}")
    elif runs is None:
        raise ProblemError("campaign.runs: required key is missing (or set grid = true)")
    if runs > MAX_RUNS:
        raise ProblemError(f"campaign.runs: {runs} runs, more than {MAX_RUNS}")
    return runs


def not_a_folder(path: Path, key: str, what: str) -> None:
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
    not_a_folder(path, str(path), "a campaign file")
    text = read_text(path, "campaign file", error=ProblemError)
    data = parse_toml(text, str(path), error=ProblemError)
    return campaign_from_data(data, path, text)


__all__ = ["AXES_KEYS", "AXIS_LIMIT", "Axis", "CAMPAIGN_KEYS", "Campaign", "KINDS", "MAX_RUNS", "MAX_SEED",
           "campaign_from_data", "load_campaign", "not_a_folder", "parse_axis"]
