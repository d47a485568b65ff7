"""Input signals for co-simulation: each channel is a sum of terms.

A term is a table with a ``kind``:

* ``constant``: ``value``.
* ``sine``: ``amplitude * sin(2 pi frequency_hz t + phase) + offset`` (``omega`` in rad/s
  may replace ``frequency_hz``).
* ``step``: ``initial`` before ``time``, ``value`` from ``time`` on.
* ``random``: a Gaussian value of standard deviation ``std`` (around ``mean``) drawn anew every
  ``hold`` seconds, reproducible from ``seed`` whatever the communication steps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .runtime.errors import ProblemError
from .runtime.matrices import as_scalar

_FIELDS = {
    "constant": {"value"},
    "sine": {"amplitude", "frequency_hz", "omega", "phase", "offset"},
    "step": {"time", "value", "initial"},
    "random": {"seed", "std", "mean", "hold"},
}


@dataclass(frozen=True)
class Term:
    """One term of a signal (see the module docstring for the kinds)."""

    kind: str
    params: tuple

    def __call__(self, t: float) -> float:
        p = dict(self.params)
        if self.kind == "constant":
            return p["value"]
        if self.kind == "sine":
            return p["amplitude"] * math.sin(p["omega"] * t + p["phase"]) + p["offset"]
        if self.kind == "step":
            return p["value"] if t >= p["time"] else p["initial"]
        index = int(math.floor(t / p["hold"] + 1e-9))
        draw = np.random.default_rng([int(p["seed"]), max(index, 0)]).standard_normal()
        return p["mean"] + p["std"] * float(draw)


@dataclass(frozen=True)
class Signal:
    """A sum of terms; an empty signal is zero."""

    terms: tuple[Term, ...] = ()

    def __call__(self, t: float) -> float:
        return float(sum(term(t) for term in self.terms))


def parse_term(table, name: str) -> Term:
    """Parse one term table; errors name ``name`` and the offending field."""
    if not isinstance(table, dict):
        raise ProblemError(f"{name}: expected a table like {{kind=\"sine\", amplitude=1.0, frequency_hz=0.1}}, "
                           f"found {type(table).__name__}")
    kind = table.get("kind")
    if not isinstance(kind, str) or kind not in _FIELDS:
        raise ProblemError(f"{name}.kind: expected one of {sorted(_FIELDS)}, found {repr(kind)[:60]}")
    unknown = set(table) - _FIELDS[kind] - {"kind"}
    if unknown:
        raise ProblemError(f"{name}: unknown field(s) {sorted(unknown)} for kind {kind!r} "
                           f"(allowed: {sorted(_FIELDS[kind])})")

    def get(key, default=None, **bounds):
        if key not in table:
            if default is None:
                raise ProblemError(f"{name}.{key}: required for kind {kind!r}")
            return default
        return as_scalar(table[key], f"{name}.{key}", **bounds)

    if kind == "constant":
        params = {"value": get("value")}
    elif kind == "sine":
        if ("frequency_hz" in table) == ("omega" in table):
            raise ProblemError(f"{name}: a sine needs exactly one of frequency_hz (Hz) or omega (rad/s)")
        omega = get("omega") if "omega" in table else 2 * math.pi * get("frequency_hz")
        params = {"amplitude": get("amplitude"), "omega": omega, "phase": get("phase", 0.0),
                  "offset": get("offset", 0.0)}
    elif kind == "step":
        params = {"time": get("time"), "value": get("value"), "initial": get("initial", 0.0)}
    else:
        seed = table.get("seed")
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise ProblemError(f"{name}.seed: expected a non-negative integer, found {seed!r}")
        params = {"seed": float(seed), "std": get("std", low=0.0), "mean": get("mean", 0.0),
                  "hold": get("hold", low=0.0, open_low=True)}
    return Term(kind, tuple(sorted(params.items())))


def parse_signals(value, name: str, channels: int) -> tuple[Signal, ...]:
    """Parse ``[signals].u`` or ``.d``: one list of terms per channel.

    Parameters
    ----------
    value : list of lists of tables, or None
        The channels; ``None`` gives zero signals.
    name : str
        The key (``"signals.u"``), used in messages.
    channels : int
        The expected number of channels (m or q).

    Returns
    -------
    tuple of Signal
    """
    if value is None:
        return tuple(Signal() for _ in range(channels))
    if not isinstance(value, list) or any(not isinstance(ch, list) for ch in value):
        raise ProblemError(f"{name}: expected one list of terms per channel, e.g. "
                           f"[[{{kind=\"constant\", value=1.0}}]]")
    if len(value) != channels:
        raise ProblemError(f"{name}: expected {channels} channel(s), found {len(value)}")
    return tuple(Signal(tuple(parse_term(t, f"{name}[{i}][{j}]") for j, t in enumerate(ch)))
                 for i, ch in enumerate(value))
