"""Problem files (TOML) turned into a typed, immutable :class:`Problem`.

A problem file is data: it is parsed with :mod:`tomllib`, never evaluated. Every malformed
or inconsistent file raises :class:`~uiofmu.runtime.errors.ProblemError` naming the key and what was
expected against what was found.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from pathlib import Path

from .runtime.errors import ProblemError
from .runtime.files import parse_toml, read_text
from .runtime.labels import KEYS as LABEL_KEYS, check_labels
from .plant import Plant
from .plant_kinds import check_family, table_kind
from .runtime.kernels import kernel_named
from .runtime.plant_kinds import MUJOCO
from .runtime.registry import AVAILABLE, FAMILIES, KNOWN
from .signals import Signal, parse_signals
from .runtime.text import MAX_NAME, check_name
from .table import Table

#: Longest default experiment a problem file may ask for, in communication steps.
MAX_STEPS = 100_000


@dataclass(frozen=True)
class Problem:
    """A parsed problem: plant, observer family and options, default signals.

    Attributes
    ----------
    name : str
        Used for FMU model names.
    plant : Plant
    family : str
        One of :data:`uiofmu.runtime.registry.KNOWN`.
    options : object
        The family's frozen options (see the family module).
    u, d : tuple of Signal
        Default co-simulation inputs per channel.
    experiment_steps : int or None
        ``[experiment] steps``: the length of the FMUs' default experiments and of a default
        co-simulation, in communication steps (for plants that cannot run the default length, e.g. an
        unstable nonlinear one); None for the defaults.
    mode : tuple of Signal
        The mode of a switched plant whose rule is ``input`` (one signal, rounded to the nearest
        integer at each communication point), or empty.
    theta : tuple of Signal
        The scheduling parameter of an LPV plant whose theta is an input (one signal per
        component), or empty.
    data : dict
        The problem as data (what the design card records).
    labels : dict
        The names and units ``[plant]`` gives its states, inputs, unknown inputs and outputs
        (``{"states": [...], "state_units": [...], ...}``, the keys given; :mod:`uiofmu.runtime.labels`).
    """

    name: str
    plant: Plant
    family: str
    options: object
    u: tuple[Signal, ...]
    d: tuple[Signal, ...]
    data: dict
    mode: tuple[Signal, ...] = ()
    theta: tuple[Signal, ...] = ()
    experiment_steps: int | None = None
    labels: dict = field(default_factory=dict)


def _model_name(name: str) -> str:
    cleaned = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in name).strip("_")
    return cleaned or "problem"


def problem_from_data(data: dict, default_name: str = "problem") -> Problem:
    """Build a :class:`Problem` from the parsed TOML document.

    Parameters
    ----------
    data : dict
        The document (as :func:`tomllib.loads` returns it).
    default_name : str
        Name when the document has none (the file's stem).

    Returns
    -------
    Problem
    """
    from .families import available_family

    top = Table(data, "")
    name = check_name(top.get("name", _model_name(default_name)[:MAX_NAME]), "name", ProblemError)
    pt = Table(top.get("plant"), "plant")
    pt.choice("time", ("continuous", "discrete"))              # checked first, whatever the kind
    if pt.has("scheduling") and pt.has("modes"):
        raise ProblemError("plant.scheduling: a plant is either switched ([[plant.modes]]) or LPV "
                           "([[plant.scheduling]]), not both")
    kind = table_kind(pt)
    plant = kind.parse(pt)
    labels = check_labels({key: pt.get(key) for key in LABEL_KEYS if pt.has(key)},
                          {"n": plant.n, "m": plant.m, "q": plant.q, "p": plant.p}, "plant", ProblemError)
    pt.done()
    ot = Table(top.get("observer"), "observer")
    family = ot.get("family")
    if not isinstance(family, str):
        raise ProblemError(f"observer.family: expected a family name, found {type(family).__name__} "
                           f"(families: {', '.join(KNOWN)})")
    module = available_family(family)
    check_family(kind, family)
    if getattr(plant, "feedthrough", False) and not FAMILIES[family].feedthrough:
        keys = " and ".join(k for k, on in (("plant.D", plant.feeds_u), ("plant.F", plant.feeds_d)) if on)
        takes = " or ".join(f'"{e.name}"' for e in FAMILIES.values() if e.feedthrough)
        raise ProblemError(f"{keys}: direct feedthrough into y = C x + D u + F d is designed for by observer.family "
                           f"= {takes} only, found {family!r}")
    options = module.parse_options(ot, plant)
    ot.done()
    st = Table(top.get("signals", {}), "signals")
    u = parse_signals(st.get("u", None), "signals.u", plant.m)
    d = parse_signals(st.get("d", None), "signals.d", plant.q)
    mode = ()
    if st.has("mode"):
        if "mode" not in kind.signals(plant):
            raise ProblemError('signals.mode: only a switched plant whose [plant.switching] rule = "input" takes its '
                               "mode from the signals")
        mode = parse_signals(st.get("mode"), "signals.mode", 1)
    theta = ()
    if st.has("theta"):
        if "theta" not in kind.signals(plant):
            raise ProblemError('signals.theta: only an LPV plant whose [plant.theta] kind = "input" takes theta from '
                               "the signals")
        theta = parse_signals(st.get("theta"), "signals.theta", plant.s)
    st.done()
    et = Table(top.get("experiment", {}), "experiment")
    steps = et.get("steps", None)
    if steps is not None and (isinstance(steps, bool) or not isinstance(steps, int) or not 1 <= steps <= MAX_STEPS):
        raise ProblemError(f"experiment.steps: expected an integer from 1 to {MAX_STEPS}, found {repr(steps)[:40]}")
    et.done()
    top.done()
    return Problem(_model_name(name), plant, family, options, u, d, copy.deepcopy(data), mode, theta, steps, labels)


def _available() -> list[str]:
    return sorted(AVAILABLE)


def load_problem(path) -> Problem:
    """Read and check a problem file.

    Parameters
    ----------
    path : str or Path
        A TOML file, or a folder holding ``problem.toml`` (``plants/NAME``); a regular file of
        at most :data:`uiofmu.runtime.files.MAX_INPUT_BYTES`, nested at most
        :data:`uiofmu.runtime.files.MAX_DEPTH` deep.

    Returns
    -------
    Problem

    Raises
    ------
    ProblemError
        For a missing or unreadable file, TOML syntax errors and every malformed key.
    """
    path = Path(path)
    if path.is_dir():
        path = path / "problem.toml"
    data = parse_toml(read_text(path, "problem file", error=ProblemError), str(path), error=ProblemError)
    if MUJOCO.key in data and "plant" not in data:
        raise ProblemError(f"{path} is a MuJoCo plant spec, not a problem file: linearise it first "
                           f"(uiofmu linearize {path.parent} -o problem.toml)")
    stem = path.parent.name if path.name == "problem.toml" else path.stem
    return problem_from_data(data, default_name=stem)


def make_problem(plant: Plant, family: str, name: str = "problem", signals: dict | None = None,
                 labels: dict | None = None, **options) -> Problem:
    """A :class:`Problem` from a :class:`~uiofmu.plant.Plant` given from Python.

    Parameters
    ----------
    plant : Plant
        E.g. from :func:`~uiofmu.plant.plant_from_statespace`.
    family : str
        Observer family.
    name : str
        Model name.
    signals : dict, optional
        The ``[signals]`` table.
    labels : dict, optional
        Names and units, as the ``[plant]`` keys ``states``, ``state_units``, ... of a problem file.
    **options
        The family's parameters, as in the ``[observer]`` table.

    Returns
    -------
    Problem

    Warns
    -----
    UserWarning
        When the plant's ``x0`` and the observer's ``xhat0`` are equal (both zero by default, as
        from :func:`~uiofmu.plant.plant_from_statespace`): the estimation error starts at 0, so a
        co-simulation shows no convergence (give ``x0`` to the plant or ``xhat0=`` here).
    """
    import warnings

    import numpy as np

    data = {"name": name, "plant": {**plant.to_data(), **(labels or {})}, "observer": {"family": family, **options}}
    if signals:
        data["signals"] = signals
    problem = problem_from_data(data, default_name=name)
    x0 = problem.plant.x0
    if kernel_named(FAMILIES[family].kernel).estimates_x:              # the family's options have an xhat0
        xhat0 = problem.options.xhat0
        if np.array_equal(np.zeros_like(x0) if xhat0 is None else xhat0, x0):
            warnings.warn(f"{name}: the plant's x0 and the observer's xhat0 are equal ({np.asarray(x0).tolist()}"[:200]
                          + "): the estimation error starts at 0 and a co-simulation shows no convergence; give the "
                          "plant an x0 (plant_from_statespace(sys, E, x0=...)) or make_problem(..., xhat0=...)",
                          UserWarning, stacklevel=2)
    return problem


def to_toml(doc: dict, header: str = "") -> str:
    """A problem document as TOML text (numbers with full precision)."""
    import json

    def value(v):
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, dict):
            return "{" + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + "}"
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return repr(float(v)) if isinstance(v, float) else repr(v)

    lines = [f"# {line}" for line in header.splitlines()]
    lines += [f"{k} = {value(v)}" for k, v in doc.items() if not isinstance(v, dict)]
    for section, table in doc.items():
        if isinstance(table, dict):
            lines += ["", f"[{section}]"] + [f"{k} = {value(v)}" for k, v in table.items()]
    return "\n".join(lines) + "\n"
