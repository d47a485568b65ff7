"""The design card: one JSON document that carries a design from ``design`` to ``build``,
``validate`` and ``cosim``.

Floats are written with :func:`repr` (shortest text that reads back bit-identical), so a
card round-trips exactly. The card is data only: no pickle, no code.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import CardError
from .files import parse_json, read_text, write_atomic
from .labels import check_labels
from .matrices import as_array, as_scalar, as_vector
from .ports import check_declared, delayed_ports, observer_ports, window_ports
from .registry import KNOWN
from .schedules import AXES
from .text import check_name, check_text
from .tolerances import STEP_RTOL

FORMAT = "uiofmu.design"
VERSION = 1
REQUIRED = ("format", "version", "family", "name", "dims", "time", "dt", "schedule", "matrices",
            "initial", "certificate", "problem")

#: Matrices of the runtime and their shapes in terms of the dims (before any schedule axes).
RUNTIME_SHAPES = {
    "N": ("nz", "nz"), "L": ("nz", "p"), "G": ("nz", "m"), "c": ("nz",),
    "Xz": ("n", "nz"), "Xy": ("n", "p"), "C": ("p", "n"),
    "Dy": ("q", "p"), "Yx": ("p", "n"), "Yu": ("p", "m"), "Yc": ("p",),
}
#: Matrices every card has; the ``Dy, Yx, Yu, Yc`` group is present when ``dhat`` is estimated.
CORE = ("N", "L", "G", "c", "Xz", "Xy", "C")
DHAT = ("Dy", "Yx", "Yu", "Yc")


def to_lists(value):
    """Arrays (and complex numbers) to nested lists of floats, recursively."""
    if isinstance(value, np.ndarray):
        return value.tolist() if value.dtype.kind in "biuf" else to_lists(value.tolist())
    if isinstance(value, dict):
        return {k: to_lists(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_lists(v) for v in value]
    if isinstance(value, (np.floating,)):
        return float(value)
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def _dump(value, indent: int) -> str:
    """JSON with numeric rows on one line (readable matrices); floats via repr."""
    pad = " " * indent
    if isinstance(value, dict):
        if not value:
            return "{}"
        if len(value) <= 6 and all(isinstance(v, (int, float, bool, str)) or v is None for v in value.values()):
            return "{" + ", ".join(f"{json.dumps(str(k))}: {_dump(v, 0)}" for k, v in value.items()) + "}"
        items = [f'{pad} {json.dumps(str(k))}: {_dump(v, indent + 1)}' for k, v in value.items()]
        return "{\n" + ",\n".join(items) + f"\n{pad}}}"
    if isinstance(value, list):
        if all(isinstance(v, (int, float, bool, str)) or v is None for v in value):
            return "[" + ", ".join(_dump(v, 0) for v in value) + "]"
        return "[\n" + ",\n".join(f"{pad} {_dump(v, indent + 1)}" for v in value) + f"\n{pad}]"
    if isinstance(value, float):
        if not math.isfinite(value):
            raise CardError(f"a design card cannot hold the non-finite number {value}")
        return repr(value)
    return json.dumps(value)


@dataclass(frozen=True)
class Card:
    """A checked design card.

    Attributes
    ----------
    data : dict
        The whole JSON document.
    matrices : dict of str to numpy.ndarray
        The runtime matrices, read-only (with leading schedule axes where the schedule has them).
    """

    data: dict
    matrices: dict

    @property
    def family(self) -> str:
        """The observer family."""
        return self.data["family"]

    @property
    def name(self) -> str:
        """Model name."""
        return self.data["name"]

    @property
    def dims(self) -> dict:
        """``n, m, p, q, nz``."""
        return self.data["dims"]

    @property
    def dt(self) -> float | None:
        """Design period (None when the schedule follows the communication step)."""
        return self.data["dt"]

    @property
    def schedule(self) -> dict:
        """How the runtime picks matrices (``kind`` and its data)."""
        return self.data["schedule"]

    @property
    def has_dhat(self) -> bool:
        """Whether the card estimates the unknown input."""
        return all(k in self.matrices for k in DHAT)

    @property
    def kernel(self) -> str:
        """The runtime kernel that steps the observer (:data:`KERNELS`)."""
        return self.data.get("kernel", "affine")

    @property
    def labels(self) -> dict:
        """The names and units its problem's ``[plant]`` gives (:func:`plant_labels`)."""
        return plant_labels(self.data)

    @property
    def ports(self) -> list:
        """The observer's ports (:mod:`uiofmu.runtime.ports`), from its kernel, dims and schedule."""
        return declared_ports(self.data, self.matrices)

    def to_json(self) -> str:
        """The card as text."""
        return _dump(self.data, 0) + "\n"

    def write(self, path) -> Path:
        """Write the card to ``path`` atomically (parents created; an existing file is replaced
        only once the new one is complete)."""
        return write_atomic(path, self.to_json(), "design card")


#: Runtime kernels: how an observer steps. ``affine``: ``z+ = N z + L y + G u + c``,
#: ``xhat = Xz z + Xy y`` with the matrices its schedule picks (:mod:`uiofmu.runtime.observer`).
#: ``window``: ``gx = sum_t w_t(theta) F_t [y window]`` on the last outputs (:mod:`uiofmu.runtime.window`).
#: ``delayed``: a continuous-time delayed UIO integrated inside the FMU (:mod:`uiofmu.runtime.delayed`).
KERNELS = ("affine", "window", "delayed")
#: The schedule kind of each kernel that has its own (the affine kernel takes every other kind).
KERNEL_SCHEDULE = {"window": "window", "delayed": "continuous"}
#: Longest output window of a window kernel, and its largest power of a theta value.
MAX_WINDOW, MAX_POWER = 1024, 64
#: Largest dimension a card may declare (states, inputs, outputs, observer states).
MAX_DIM = 1000
#: Most design intervals an interval schedule may list.
MAX_INTERVALS = 256
#: Keys a schedule may hold, per kind (``step_policy`` and ``step_rtol`` for all).
SCHEDULE_KEYS = {"constant": {"dt"}, "interval": {"intervals", "h_prev0"}, "geometric": {"alpha", "dt"},
                 "mode": {"dt", "modes", "mode_prev0"}, "window": {"dt", "length", "delay", "theta", "uses_theta"},
                 "continuous": {"delays", "max_substep", "sigma_bound", "step", "valid_from", "gamma_bound"}}
#: Most modes a mode schedule may have (its card holds N^2 step matrices).
MAX_MODES = 16
#: The step policies each schedule kind accepts (see :mod:`uiofmu.runtime.schedules`).
KIND_POLICIES = {"constant": ("error",), "interval": ("error", "nearest"), "geometric": ("error", "count"),
                 "mode": ("error",), "window": ("error",), "continuous": ("error",)}
#: Longest free text (``bound``, ``generator``, solver names) a card may hold.
MAX_TEXT = 1000


def _table(value, key: str) -> dict:
    if not isinstance(value, dict):
        raise CardError(f"design card {key}: expected an object, found {_kind(value)}")
    return value


def _kind(value) -> str:
    if isinstance(value, bool):
        return f"the boolean {str(value).lower()}"
    if isinstance(value, str):
        return f"the string {value[:40]!r}" + ("..." if len(value) > 40 else "")
    if value is None:
        return "null"
    return {"list": "a list", "dict": "an object", "int": f"the integer {value}",
            "float": f"the number {value!r}"}.get(type(value).__name__, type(value).__name__)


def _integer(value, key: str, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise CardError(f"design card {key}: expected an integer, found {_kind(value)}")
    if not low <= value <= high:
        raise CardError(f"design card {key}: expected an integer in [{low}, {high}], found {value}")
    return value


def _number(value, key: str, **bounds) -> float:
    return as_scalar(value, f"design card {key}", error=CardError, **bounds)


def _text(value, key: str, limit: int = MAX_TEXT) -> str:
    return check_text(value, f"design card {key}", CardError, limit, allow_empty=True)


def _choice(value, key: str, options: tuple) -> str:
    if not isinstance(value, str) or value not in options:
        raise CardError(f"design card {key}: expected one of {', '.join(map(repr, options))}, found {_kind(value)}")
    return value


def _check_schedule(spec, dt) -> dict:
    """The ``schedule`` entry: its kind, its data and their ranges."""
    spec = _table(spec, "schedule")
    kind = _choice(spec.get("kind"), "schedule.kind", tuple(SCHEDULE_KEYS))
    unknown = sorted(set(spec) - SCHEDULE_KEYS[kind] - {"kind", "step_policy", "step_rtol"})
    if unknown:
        raise CardError(f"design card schedule.{unknown[0]}: not a key of a {kind} schedule "
                        f"(known: {', '.join(sorted(SCHEDULE_KEYS[kind] | {'kind', 'step_policy', 'step_rtol'}))})")
    _choice(spec.get("step_policy", "error"), "schedule.step_policy", KIND_POLICIES[kind])
    rtol = _number(spec.get("step_rtol", STEP_RTOL), "schedule.step_rtol", low=0.0, high=0.01)
    if kind in ("constant", "geometric", "mode", "window"):
        if "dt" not in spec:
            raise CardError(f"design card schedule.dt: required for a {kind} schedule")
        step = _number(spec["dt"], "schedule.dt", low=0.0, open_low=True)
        if dt is None or step != dt:
            raise CardError(f"design card schedule.dt = {step!r} differs from dt = {dt!r}")
    if kind == "geometric":
        if "alpha" not in spec:
            raise CardError("design card schedule.alpha: required for a geometric schedule")
        _number(spec["alpha"], "schedule.alpha", low=0.0, high=1.0, open_low=True, open_high=True)
    if kind == "continuous":
        delays = spec.get("delays")
        if not isinstance(delays, list) or not 1 <= len(delays) <= 16:
            raise CardError(f"design card schedule.delays: expected a list of 1 to 16 delays, found {_kind(delays)}")
        values = [_number(t, f"schedule.delays[{i}]", low=0.0, open_low=True) for i, t in enumerate(delays)]
        if any(b <= a for a, b in zip(values, values[1:])):
            raise CardError(f"design card schedule.delays: expected increasing delays, found {values}")
        for key in ("max_substep", "step"):
            _number(spec.get(key), f"schedule.{key}", low=0.0, open_low=True)
        _number(spec.get("sigma_bound"), "schedule.sigma_bound", low=0.0)
        for key in ("valid_from", "gamma_bound"):            # from the premise's start, and its largest Gamma
            if key in spec:
                _number(spec[key], f"schedule.{key}", low=0.0, open_low=key == "gamma_bound")
    if kind == "window":
        length = _integer(spec.get("length"), "schedule.length", 1, MAX_WINDOW)
        _integer(spec.get("delay"), "schedule.delay", 0, length - 1)
        _integer(spec.get("theta"), "schedule.theta", 0, MAX_DIM)
        if not isinstance(spec.get("uses_theta"), bool):
            raise CardError("design card schedule.uses_theta: expected true or false, found "
                            f"{_kind(spec.get('uses_theta'))}")
    if kind == "mode":
        modes = _integer(spec.get("modes"), "schedule.modes", 1, MAX_MODES)
        _integer(spec.get("mode_prev0", 1), "schedule.mode_prev0", 1, modes)
    if kind == "interval":
        if "intervals" not in spec:
            raise CardError("design card schedule.intervals: required for an interval schedule")
        values = spec["intervals"]
        if not isinstance(values, list) or not 1 <= len(values) <= MAX_INTERVALS:
            raise CardError(f"design card schedule.intervals: expected a list of 1 to {MAX_INTERVALS} steps, "
                            f"found {_kind(values)}" + (f" of {len(values)}" if isinstance(values, list) else ""))
        hs = [_number(h, f"schedule.intervals[{i}]", low=0.0, open_low=True) for i, h in enumerate(values)]
        ordered = sorted(hs)
        for a, b in zip(ordered, ordered[1:]):
            if b - a <= 2 * rtol * b:
                raise CardError(f"design card schedule.intervals: {a!r} and {b!r} s are not distinct steps "
                                f"(step_rtol = {rtol:g})")
        h0 = _number(spec.get("h_prev0", hs[0]), "schedule.h_prev0", low=0.0, open_low=True)
        if not any(abs(h0 - h) <= rtol * h for h in hs):
            raise CardError(f"design card schedule.h_prev0 = {h0!r} s is not one of the design intervals")
    return spec


def _any_array(value, key: str) -> None:
    """A finite numeric array of any shape (nested lists of up to 5 levels)."""
    depth, probe = 0, value
    while isinstance(probe, list) and depth < 5:
        probe, depth = (probe[0] if probe else None), depth + 1
    as_array(value, key, (None,) * depth, CardError)


def _check_window(mats: dict, dims: dict, schedule: dict) -> dict:
    """The window kernel's ``F`` (terms, d, p L) and ``Fexp`` (terms, L, s; integer powers 0..MAX_POWER)."""
    L, s = schedule["length"], schedule["theta"]
    for name in ("F", "Fexp"):
        if name not in mats:
            raise CardError(f"design card matrices.{name}: required by the window kernel")
    F = as_array(mats["F"], "design card matrices.F", (None, None, dims["p"] * L), CardError)
    if F.shape[0] == 0 or F.shape[1] == 0:
        raise CardError(f"design card matrices.F: expected at least one term and one row, found shape {F.shape}")
    exps = as_array(mats["Fexp"], "design card matrices.Fexp", (F.shape[0], L, s), CardError)
    if np.any(exps < 0) or np.any(exps > MAX_POWER) or np.any(exps != np.round(exps)):
        raise CardError(f"design card matrices.Fexp: expected integer powers from 0 to {MAX_POWER}")
    if not schedule["uses_theta"] and np.any(exps):
        raise CardError("design card matrices.Fexp: the formula uses theta but schedule.uses_theta is false")
    return {"F": F, "Fexp": exps}


def _check_delayed(mats: dict, dims: dict, schedule: dict) -> dict:
    """The delayed kernel's matrices: the plant's ``Abar, Bbar, Cbar, D0, Dy`` and the gain ``K`` of the
    augmented system (``len(delays) + 1`` copies)."""
    n, m, p = dims["n"], dims["m"], dims["p"]
    c = len(schedule["delays"]) + 1
    if dims["nz"] != n * c:
        raise CardError(f"design card dims.nz = {dims['nz']}: the delayed kernel has n (len(delays) + 1) = {n * c}")
    for name in ("Abar", "Bbar", "Cbar", "D0", "Dy", "K"):
        if name not in mats:
            raise CardError(f"design card matrices.{name}: required by the delayed kernel")
    D0 = as_array(mats["D0"], "design card matrices.D0", (n, None), CardError)
    shapes = {"Abar": (n, n), "Bbar": (n, m), "Cbar": (p, n), "D0": (n, D0.shape[1]),
              "Dy": (p, n, D0.shape[1]), "K": (n * c, p * c)}
    return {name: as_array(mats[name], f"design card matrices.{name}", shape, CardError)
            for name, shape in shapes.items()}


#: The matrices each kernel with its own checks reads (every other matrix: any finite array).
KERNEL_MATRICES = {"window": (("F", "Fexp"), _check_window), "delayed": (("Abar", "Bbar", "Cbar", "D0", "Dy", "K"),
                                                                        _check_delayed)}


def _check_matrices(mats, dims: dict, kind: str, schedule: dict) -> dict:
    """Runtime matrices with their exact shapes; every other matrix a finite numeric array."""
    mats = _table(mats, "matrices")
    own = {"window": "window", "continuous": "delayed"}.get(kind)
    if own:
        names, check = KERNEL_MATRICES[own]
        for name, value in mats.items():
            _text(name, "matrices key", 64)
            if name not in names:
                _any_array(value, f"design card matrices.{name}")
        return check(mats, dims, schedule)
    axes = AXES[kind]
    count = {"interval": len(schedule.get("intervals", ())), "mode": schedule.get("modes")}.get(kind)
    out = {}
    for name, value in mats.items():
        key = f"design card matrices.{name}"
        _text(name, "matrices key", 64)
        if name in RUNTIME_SHAPES:
            lead = (count,) * axes.get(name, 0)
            shape = lead + tuple(dims[d] for d in RUNTIME_SHAPES[name])
            arr = as_array(value, key, shape, CardError)
            if kind == "geometric" and name in axes and arr.shape[0] == 0:
                raise CardError(f"{key}: a geometric schedule needs at least one coefficient")
            out[name] = arr
        else:
            _any_array(value, key)
    absent = [k for k in CORE if k not in out]
    if absent:
        raise CardError(f"design card matrices: missing {', '.join(absent)}")
    partial = [k for k in DHAT if k in out]
    if partial and len(partial) != len(DHAT):
        raise CardError(f"design card matrices: dhat needs all of {', '.join(DHAT)}, found only {', '.join(partial)}")
    return out


def check_card(data, require_verified: bool = True) -> dict:
    """Check a design card document against the card schema, before anything uses it.

    The card is data from someone else: every key a command, the runtime or an FMU reads is
    checked for its type, its shape against ``dims``, finiteness and its range, and the
    schedule for the values the runtime will index with. Free text (``name``, ``bound``) must
    be printable and bounded; it never reaches generated code.

    Parameters
    ----------
    data : object
        The parsed JSON.
    require_verified : bool
        Also require ``certificate.verified`` to be the boolean ``true``.

    Returns
    -------
    dict of str to numpy.ndarray
        The runtime matrices, read-only.

    Raises
    ------
    CardError
        Naming the first key that is missing, of the wrong type or shape, or out of range.
    """
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise CardError(f'not a uiofmu design card: "format" must be "{FORMAT}"')
    missing = [k for k in REQUIRED if k not in data]
    if missing:
        raise CardError(f"design card: missing key(s) {', '.join(missing)}")
    version = data["version"]
    if isinstance(version, bool) or not isinstance(version, int) or version != VERSION:
        raise CardError(f"design card version {repr(version)[:40]} is not supported "
                        f"(this uiofmu reads version {VERSION})")
    _choice(data["family"], "family", KNOWN)
    check_name(data["name"], "design card name", CardError)
    dims = _table(data["dims"], "dims")
    for d in ("n", "m", "p", "q", "nz"):
        if d not in dims:
            raise CardError(f"design card dims.{d}: required")
        _integer(dims[d], f"dims.{d}", 1 if d in ("n", "p") else 0, MAX_DIM)
    time = _choice(data["time"], "time", ("continuous", "discrete"))
    dt = data["dt"]
    if dt is not None:
        dt = _number(dt, "dt", low=0.0, open_low=True)
    elif time == "discrete":
        raise CardError("design card dt: a discrete design needs its period")
    schedule = _check_schedule(data["schedule"], dt)
    initial = _table(data["initial"], "initial")
    if "xhat0" not in initial:
        raise CardError("design card initial.xhat0: required (the initial estimate)")
    as_vector(initial["xhat0"], "design card initial.xhat0", dims["n"], CardError)
    cert = _table(data["certificate"], "certificate")
    verified = cert.get("verified")
    if not isinstance(verified, bool):
        raise CardError(f"design card certificate.verified: expected true or false, found {_kind(verified)}")
    if require_verified and verified is not True:
        raise CardError("design card: its certificate is not verified (certificate.verified is false); "
                        "it cannot be built or run")
    for key in ("solver", "status"):
        if key in cert:
            _text(cert[key], f"certificate.{key}", 100)
    observer = _table(data["problem"], "problem").get("observer")
    plant_labels(data)
    if isinstance(observer, dict) and observer.get("family", data["family"]) != data["family"]:
        raise CardError(f"design card family {data['family']!r} is not its problem's observer.family "
                        f"{str(observer.get('family'))[:40]!r}: the card was edited after the design")
    for key in ("decay_bound", "overshoot_bound"):
        if data.get(key) is not None:
            value = _number(data[key], key, low=0.0)
            if key == "decay_bound" and value >= 1.0:
                raise CardError(f"design card decay_bound = {value!r}: a bound of 1 or more certifies no convergence")
    if data.get("overshoot_digits") is not None:
        _integer(data["overshoot_digits"], "overshoot_digits", 0, 17)
    if (data.get("decay_bound") is None) != (data.get("overshoot_bound") is None):
        raise CardError("design card: decay_bound and overshoot_bound come together (one of them is missing)")
    for key in ("bound", "generator"):
        if key in data:
            _text(data[key], key)
    kernel = _choice(data.get("kernel", "affine"), "kernel", KERNELS)
    if KERNEL_SCHEDULE.get(kernel) not in (None, schedule["kind"]) or (
            schedule["kind"] in KERNEL_SCHEDULE.values() and KERNEL_SCHEDULE.get(kernel) != schedule["kind"]):
        raise CardError(f"design card kernel {kernel!r} does not step a {schedule['kind']!r} schedule")
    matrices = _check_matrices(data["matrices"], dims, schedule["kind"], schedule)
    if "ports" in data:
        check_declared(data["ports"], declared_ports(data, matrices))
    return matrices



def plant_labels(data: dict) -> dict:
    """The names and units of a card's problem (``problem.plant.states``, ...; :mod:`uiofmu.runtime.labels`),
    checked against its dims: free text that reaches ``modelDescription.xml`` and the figures.

    Raises
    ------
    CardError
        Naming the key, as :func:`uiofmu.runtime.labels.check_labels` does.
    """
    plant = data["problem"].get("plant")
    return check_labels(plant, data["dims"], "design card problem.plant", CardError) if isinstance(plant, dict) else {}


def declared_ports(data: dict, matrices: dict) -> list:
    """The ports the card's kernel implements for its dims, schedule and matrices."""
    if data.get("kernel", "affine") == "window":
        spec = data["schedule"]
        return window_ports(data["dims"]["p"], matrices["F"].shape[1], spec["theta"] if spec["uses_theta"] else 0)
    if data.get("kernel", "affine") == "delayed":
        d = data["dims"]
        return delayed_ports(d["n"], d["m"], d["p"], matrices["D0"].shape[1])
    feeds_y = bool(np.any(np.asarray(matrices["Xy"]) != 0))
    return observer_ports(data["dims"], data["schedule"]["kind"], "Dy" in matrices, feeds_y)


def card_from_data(data: dict, require_verified: bool = True) -> Card:
    """Check a card document (:func:`check_card`) and build a :class:`Card`.

    Parameters
    ----------
    data : dict
        The parsed JSON.
    require_verified : bool
        Refuse a card whose certificate was not verified (default).

    Returns
    -------
    Card

    Raises
    ------
    CardError
        Naming the missing or malformed key.
    """
    return Card(data, check_card(data, require_verified))


def read_card(path, require_verified: bool = True) -> Card:
    """Read and check a design card file.

    Parameters
    ----------
    path : str or Path
        A regular file of at most :data:`uiofmu.runtime.files.MAX_INPUT_BYTES`.
    require_verified : bool
        Refuse an unverified certificate (default).

    Returns
    -------
    Card
    """
    text = read_text(path, "design card", error=CardError)
    return card_from_data(parse_json(text, f"{path}", error=CardError), require_verified)
