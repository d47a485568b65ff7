"""Input signals for co-simulation: each channel is a sum of terms.

A term is a table with a ``kind``:

* ``constant``: ``value``.
* ``sine``: ``amplitude * sin(2 pi frequency_hz t + phase) + offset`` (``omega`` in rad/s
  may replace ``frequency_hz``).
* ``step``: ``initial`` before ``time``, ``value`` from ``time`` on.
* ``random``: a Gaussian value of standard deviation ``std`` (around ``mean``) drawn anew every
  ``hold`` seconds, reproducible from ``seed`` whatever the communication steps.

Every number of a term is finite and at most :data:`MAX_MAGNITUDE` in magnitude (so no sum of terms
overflows), ``seed`` is an integer from 0 to :data:`MAX_EXACT`, ``std`` >= 0 and ``hold`` > 0. A run is
refused (naming the term's key) when it would take a random term past :data:`MAX_EXACT` hold intervals or
a sine past :data:`MAX_EXACT` radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .runtime.errors import ProblemError
from .runtime.matrices import as_scalar
from .table import closest_key

#: Largest magnitude of a number of a term (as :data:`uiofmu.cosim.campaign.AXIS_LIMIT`): inputs of any
#: physical plant are many orders below, and a sum of terms stays far from overflowing.
MAX_MAGNITUDE = 1e100
#: Largest seed, count of hold intervals and sine argument (radians) of a run: 2**53, the integers a float
#: holds exactly. Beyond, a hold interval's index or a seed is rounded (two become one) and neighbouring
#: floats of a sine's argument are more than a radian apart. (A random term draws only at the communication
#: points, so a short hold costs no memory: what it must not do is leave the exact integers.)
MAX_EXACT = 2**53

_FIELDS = {
    "constant": {"value"},
    "sine": {"amplitude", "frequency_hz", "omega", "phase", "offset"},
    "step": {"time", "value", "initial"},
    "random": {"seed", "std", "mean", "hold"},
}

#: What a missing key of a term means, where its name alone does not say.
_HINTS = {("random", "hold"): " (seconds between new draws, e.g. the observer's step to draw anew at every "
                              "step of a periodic run)",
          ("random", "std"): " (the standard deviation of the draws)"}


@dataclass(frozen=True)
class Term:
    """One term of a signal (see the module docstring for the kinds)."""

    kind: str
    params: tuple
    name: str = field(default="", compare=False)      # its key (``signals.u[0][1]``), for messages

    def __post_init__(self):
        # the parameters as a dict, built once (a frozen dataclass: set past its __setattr__)
        object.__setattr__(self, "_p", dict(self.params))

    def check_run(self, t_max: float) -> None:
        """Refuse evaluating the term up to time ``t_max`` (s) when that takes a random term past
        :data:`MAX_EXACT` hold intervals or a sine past :data:`MAX_EXACT` radians.

        Raises
        ------
        ProblemError
            Naming the term's key, its parameter and the numbers.
        """
        p, key = self._p, self.name or f"a {self.kind} term"
        if self.kind == "random" and not t_max / p["hold"] <= MAX_EXACT:
            raise ProblemError(f"{key}.hold = {p['hold']:g} s: the run to t = {t_max:g} s spans "
                               f"{t_max / p['hold']:.3g} hold intervals, more than {MAX_EXACT} (2**53, "
                               "uiofmu.signals.MAX_EXACT); give a longer hold")
        if self.kind == "sine" and not abs(p["omega"]) * t_max + abs(p["phase"]) <= MAX_EXACT:
            raise ProblemError(f"{key}: omega t + phase reaches {abs(p['omega']) * t_max + abs(p['phase']):.3g} "
                               f"rad by t = {t_max:g} s (omega = {p['omega']:g} rad/s), more than {MAX_EXACT} "
                               "(2**53, uiofmu.signals.MAX_EXACT); give a lower frequency or a shorter run")

    def __call__(self, t: float) -> float:
        p = self._p
        self.check_run(abs(t))
        if self.kind == "constant":
            return p["value"]
        if self.kind == "sine":
            return p["amplitude"] * math.sin(p["omega"] * t + p["phase"]) + p["offset"]
        if self.kind == "step":
            return p["value"] if t >= p["time"] else p["initial"]
        index = int(math.floor(t / p["hold"] + 1e-9))
        return p["mean"] + p["std"] * _draw(p["seed"], index)

    def at(self, times: np.ndarray) -> np.ndarray:
        """The term at every time of a float array, bit for bit what :meth:`__call__` gives at each
        (the same IEEE operations elementwise; ``sin`` from :mod:`math`; one draw per hold interval)."""
        times = np.asarray(times, dtype=float)
        p = self._p
        if times.size:
            self.check_run(float(np.abs(times).max()))
        if self.kind == "constant":
            return np.full(times.shape, p["value"], dtype=float)
        if self.kind == "sine":
            phase = p["omega"] * times + p["phase"]
            sines = np.fromiter(map(math.sin, phase.ravel().tolist()), dtype=float, count=phase.size)
            return p["amplitude"] * sines.reshape(times.shape) + p["offset"]
        if self.kind == "step":
            return np.where(times >= p["time"], float(p["value"]), float(p["initial"]))
        index = np.floor(times / p["hold"] + 1e-9)
        keys, inverse = np.unique(index, return_inverse=True)
        draws = np.array([_draw(p["seed"], int(i)) for i in keys.tolist()], dtype=float)
        return p["mean"] + p["std"] * draws[inverse.reshape(times.shape)]


def _draw(seed: float, index: int) -> float:
    """The Gaussian draw of a random term for its hold interval ``index`` (0 before t = 0)."""
    return float(np.random.default_rng([int(seed), max(index, 0)]).standard_normal())


@dataclass(frozen=True)
class Signal:
    """A sum of terms; an empty signal is zero."""

    terms: tuple[Term, ...] = ()

    def __call__(self, t: float) -> float:
        total = 0.0                       # left to right, as sum() does on Python 3.11 and :meth:`at` does
        for term in self.terms:
            total += term(t)
        return float(total)

    def at(self, times) -> np.ndarray:
        """The signal at every time of a float array, bit for bit ``[self(t) for t in times]``
        (the terms summed left to right from zero, as :func:`sum` does)."""
        times = np.asarray(times, dtype=float)
        total = np.zeros(times.shape)
        for term in self.terms:
            total = total + term.at(times)
        return total


def parse_term(table, name: str) -> Term:
    """Parse one term table; errors name ``name`` and the offending field."""
    if not isinstance(table, dict):
        raise ProblemError(f"{name}: expected a table like {{kind=\"sine\", amplitude=1.0, frequency_hz=0.1}}, "
                           f"found {type(table).__name__}")
    kind = table.get("kind")
    if not isinstance(kind, str) or kind not in _FIELDS:
        raise ProblemError(f"{name}.kind: expected one of {sorted(_FIELDS)}, found {repr(kind)[:60]}")
    unknown = sorted(map(str, set(table) - _FIELDS[kind] - {"kind"}))
    if unknown:
        typo = closest_key(unknown[0], _FIELDS[kind])
        raise ProblemError(f"{name}: unknown field(s) {unknown} for kind {kind!r}"[:300]
                           + (f"; did you mean {typo!r}?" if typo else "") + f" (allowed: {sorted(_FIELDS[kind])})")

    def get(key, default=None, low=-MAX_MAGNITUDE, **bounds):
        if key not in table:
            if default is None:
                raise ProblemError(f"{name}.{key}: required for kind {kind!r}" + _HINTS.get((kind, key), ""))
            return default
        return as_scalar(table[key], f"{name}.{key}", low=low, high=MAX_MAGNITUDE, **bounds)

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
        if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_EXACT:
            raise ProblemError(f"{name}.seed: expected a non-negative integer of at most {MAX_EXACT} (2**53), "
                               f"found {repr(seed)[:40]}")
        params = {"seed": float(seed), "std": get("std", low=0.0), "mean": get("mean", 0.0),
                  "hold": get("hold", low=0.0, open_low=True)}
    return Term(kind, tuple(sorted(params.items())), name)


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
