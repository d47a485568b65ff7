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

from .checks import (MAX_DIM, MAX_INTERVALS, MAX_MODES, MAX_POWER, MAX_TEXT, MAX_WINDOW, any_array, choice as _choice,
                     integer as _integer, kind_of as _kind, number as _number, table as _table, text as _text)
from .errors import CardError
from .files import parse_json, read_text, write_atomic
from .kernels import CORE, DEFAULT, DHAT, KERNELS, RUNTIME_SHAPES, SCHEDULES, Kernel, card_kernel
from .labels import check_labels
from .matrices import as_vector
from .ports import check_declared
from .registry import KNOWN
from .text import check_name
from .tolerances import NOISE_DIGITS, NOISE_ROOM, STEP_RTOL

FORMAT = "uiofmu.design"
VERSION = 1
REQUIRED = ("format", "version", "family", "name", "dims", "time", "dt", "schedule", "matrices",
            "initial", "certificate", "problem")

#: The types ``to_lists`` returns as they are (exactly these: numpy's float64 is a float too, and is converted).
_PLAIN = frozenset((str, int, float, bool, type(None)))


def to_lists(value):
    """Arrays (and complex numbers) to nested lists of floats, recursively."""
    if type(value) in _PLAIN:                       # most leaves: nothing to convert
        return value
    if isinstance(value, np.ndarray):
        return value.tolist() if value.dtype.kind in "biuf" else to_lists(value.tolist())
    if isinstance(value, dict):                     # plain leaves kept without a call each
        return {k: v if type(v) in _PLAIN else to_lists(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [v if type(v) in _PLAIN else to_lists(v) for v in value]
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
        """``n, m, p, q, nz`` (and ``nf``, the functionals of a functional observer's ``zhat``)."""
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
        """The name of the runtime kernel that steps the observer (:data:`uiofmu.runtime.kernels.KERNELS`)."""
        return self.data.get("kernel", DEFAULT)

    @property
    def stepper(self) -> Kernel:
        """The runtime kernel that steps the observer (:class:`uiofmu.runtime.kernels.Kernel`)."""
        return KERNELS[self.kernel]

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


def _check_schedule(spec, dt) -> dict:
    """The ``schedule`` entry: its kind (:data:`uiofmu.runtime.kernels.SCHEDULES`), its data and their ranges."""
    spec = _table(spec, "schedule")
    kind = SCHEDULES[_choice(spec.get("kind"), "schedule.kind", tuple(SCHEDULES))]
    allowed = kind.keys | {"kind", "step_policy", "step_rtol"}
    unknown = sorted(set(spec) - allowed)
    if unknown:
        raise CardError(f"design card schedule.{unknown[0]}: not a key of a {kind.name} schedule "
                        f"(known: {', '.join(sorted(allowed))})")
    _choice(spec.get("step_policy", "error"), "schedule.step_policy", kind.policies)
    rtol = _number(spec.get("step_rtol", STEP_RTOL), "schedule.step_rtol", low=0.0, high=0.01)
    if kind.periodic:
        if "dt" not in spec:
            raise CardError(f"design card schedule.dt: required for a {kind.name} schedule")
        step = _number(spec["dt"], "schedule.dt", low=0.0, open_low=True)
        if dt is None or step != dt:
            raise CardError(f"design card schedule.dt = {step!r} differs from dt = {dt!r}")
    kind.check(spec, rtol)
    return spec


#: The gains of a card's ``noise`` section (each a finite number >= 0, or null), and the other figures it may hold.
NOISE_GAINS, NOISE_FIGURES = ("gain_y", "gain_w", "gain_dhat_y"), ("peak_to_peak_y", "initial_term")
#: Longest ``noise.reason``.
MAX_REASON = 500


def _check_noise(value) -> None:
    """A card's ``noise`` section (:mod:`uiofmu.noise`): ``norm`` "l2", each gain a finite number >= 0 or null,
    ``reason`` a short text (required when every gain is null), ``covers`` (optional) a short text, a
    certificate's ``X`` a finite array."""
    noise = _table(value, "noise")
    if noise.get("norm") != "l2":
        raise CardError(f'design card noise.norm: expected "l2", found {_kind(noise.get("norm"))}')
    for key in NOISE_GAINS + NOISE_FIGURES:
        if key not in noise and key in NOISE_GAINS:
            raise CardError(f"design card noise.{key}: required (a gain, or null)")
        if noise.get(key) is not None:
            _number(noise[key], f"noise.{key}", low=0.0)
    for key in ("reason", "covers"):                # covers: what a gain bounds, where a family states it
        if noise.get(key) is not None:
            _text(noise[key], f"noise.{key}", MAX_REASON)
    if all(noise[key] is None for key in NOISE_GAINS) and not noise.get("reason"):
        raise CardError("design card noise: every gain is null and noise.reason does not say why")
    for key, gain in zip(("certificate", "certificate_w", "certificate_dhat_y"), NOISE_GAINS):
        if key in noise:
            cert = _table(noise[key], f"noise.{key}")
            if "X" in cert:
                any_array(cert["X"], f"design card noise.{key}.X")
            if "determined" in cert:
                _check_determined(noise.get(gain), cert, f"noise.{key}.determined")


#: Where a noise certificate keeps the figure its gain is rounded up from: the H-infinity norm, the solver's least
#: gain, or the least gain of a storage's scale (:mod:`uiofmu.noise`).
NOISE_BASES = ("hinf_norm", "lmi_gamma", "least_gamma")


def _room(check: dict) -> float:
    """A stored check's ``value`` over its ``bound`` (what the rounding of its evaluation can move it); nan where
    they are not two finite numbers with a positive bound, or the check is not ``value >= bound``."""
    if check.get("relation", ">=") != ">=":
        return math.nan
    try:
        value, bound = float(check["value"]), float(check["bound"])
    except (KeyError, TypeError, ValueError):
        return math.nan
    return value / bound if math.isfinite(value) and math.isfinite(bound) and bound > 0.0 else math.nan


def noise_determined(gain, cert) -> bool:
    """Whether a certified noise gain is the problem's to :data:`~uiofmu.runtime.tolerances.NOISE_DIGITS` digits, read
    off its certificate ``cert`` (as a card stores it: the base figure, ``margin``, ``checks``).

    It is when it is the first figure tried (the base times ``1 + margin`` rounded up: within one unit of its last
    digit above) and every check of its lemma holds with :data:`~uiofmu.runtime.tolerances.NOISE_ROOM` times the
    rounding of its evaluation: then no kernel's rounding of the storage ``X`` decides it. A gain certified only
    at a larger figure (the re-check refused the first), or with less room, is the design's: another kernel's
    rounding of the same design certifies another figure (31800 against 35000 on a plant next to the edge).
    """
    return _undetermined_because(gain, cert) is None


def _undetermined_because(gain, cert) -> str | None:
    """Why :func:`noise_determined` finds a gain not the problem's, with the figures that say so; None where it is."""
    if not isinstance(cert, dict) or not isinstance(cert.get("checks"), dict) or not cert["checks"]:
        return "the certificate has no checks"
    try:
        base = next(float(cert[k]) for k in NOISE_BASES if cert.get(k) is not None)
        margin, gain = float(cert["margin"]), float(gain)
    except (StopIteration, KeyError, TypeError, ValueError):
        return f"the certificate has no base figure ({', '.join(NOISE_BASES)}) and margin, or the gain is not a number"
    first = base * (1.0 + margin)
    if not (math.isfinite(first) and first > 0.0 and gain <= first * (1.0 + 10.0 ** (1 - NOISE_DIGITS))):
        return (f"the gain {gain:.6g} is not the first figure tried, the base {base:.6g} times 1 + margin "
                f"({margin:.3g}) rounded up to {NOISE_DIGITS} digits")
    for name, check in cert["checks"].items():
        room = _room(check) if isinstance(check, dict) else math.nan
        if not room >= NOISE_ROOM:
            return f"check {name} holds with {room:.3g} times its bound, where {NOISE_ROOM:g} times are needed"
    return None


def _check_determined(gain, cert: dict, where: str) -> None:
    """A noise certificate's ``determined``: true or false, and true only where :func:`noise_determined` reads it
    off the certificate's own figures."""
    flag = cert["determined"]
    if not isinstance(flag, bool):
        raise CardError(f"design card {where}: expected true or false, found {_kind(flag)}")
    because = _undetermined_because(gain, cert) if flag else None
    if because is not None:
        raise CardError(f"design card {where}: true, but {because}")


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
    if "nf" in dims:                    # a functional observer's zhat: nf functionals Lf x
        _integer(dims["nf"], "dims.nf", 1, MAX_DIM)
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
    if "noise" in data:
        _check_noise(data["noise"])
    kernel = KERNELS[_choice(data.get("kernel", DEFAULT), "kernel", tuple(KERNELS))]
    if not kernel.steps(schedule["kind"]):
        raise CardError(f"design card kernel {kernel.name!r} does not step a {schedule['kind']!r} schedule")
    matrices = kernel.check_matrices(data["matrices"], dims, schedule)
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
    """The ports the card's kernel implements for its dims, schedule and matrices (:attr:`Kernel.declare`)."""
    return card_kernel(data).declare(data, matrices)


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


__all__ = ["CORE", "DHAT", "FORMAT", "MAX_DIM", "MAX_INTERVALS", "MAX_MODES", "MAX_POWER", "MAX_TEXT", "MAX_WINDOW",
           "RUNTIME_SHAPES", "REQUIRED", "VERSION", "Card", "card_from_data", "check_card", "declared_ports",
           "plant_labels", "read_card", "to_lists"]
