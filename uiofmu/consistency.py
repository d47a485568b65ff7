"""What a design card's own problem determines, compared with what the card says.

A card carries the problem it was designed for. The plant's matrices (sampled at the design's
step where the family samples), the schedule the FMU steps by, the plant's dimensions and the
figures the family derives from its certified variables (a decay bound from ``tau2``, a substep
from the gain) are all determined by that problem and those variables; the card's copies of them
are what the FMU runs and what it prints. A certificate re-checked at a copy that is not the
problem's proves convergence for another plant, or prints a bound nobody proved: each family
lists what its problem determines (``determined(problem, card_data)``) and :func:`consistency_checks`
compares the card with it, before the certificate's own checks run.

Numbers are compared relative to the larger of their magnitude and the magnitude of the terms
they are computed from (:class:`Determined`), with :data:`SAME_RTOL`: far above the rounding of the
recomputation under any BLAS kernel (about 1e-15), far below any change that matters to a
certificate. Strings, booleans, integers and ``None`` are compared exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .certificate import Check

#: How the name of a check of :func:`same_check` ends (after the card's path).
DETERMINED = " as the card's problem determines it (relative difference)"
#: Largest relative difference between a card's copy and the value its problem determines.
SAME_RTOL = 1e-9


@dataclass(frozen=True)
class Determined:
    """A value a card's problem determines, with the magnitude of the terms it is computed from
    (a matrix ``P A - T C`` of small norm whose gain ``T`` is large is compared relative to
    ``|P||A| + |T||C|``, since that is the size of its rounding)."""

    value: object
    scale: float = 0.0


def _numbers(value) -> np.ndarray | None:
    """``value`` as a float array, or None when it is not numeric (or ragged)."""
    if isinstance(value, (str, bool, dict)) or value is None:
        return None
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        return None


def same_check(path: str, claimed, expected) -> Check:
    """``claimed`` (the card's) equals ``expected`` (what its problem determines).

    Parameters
    ----------
    path : str
        The card's key, dotted (``matrices.A_sampled``, ``schedule.dt``).
    claimed : object
        The card's value (anything a JSON document holds; missing: ``None``).
    expected : object or Determined
        Numbers (scalars, lists, arrays) are compared by their largest difference relative to
        their magnitude; strings, booleans, integers and ``None`` exactly.

    Returns
    -------
    Check
        Its value is the relative difference (infinite for a different type, shape or text).
    """
    scale = expected.scale if isinstance(expected, Determined) else 0.0
    expected = expected.value if isinstance(expected, Determined) else expected
    name = path + DETERMINED
    if expected is None or isinstance(expected, (str, bool)):
        same = type(claimed) is type(expected) and claimed == expected
        return Check(name, 0.0 if same else math.inf, 0.0)
    if isinstance(expected, (int, np.integer)):
        same = isinstance(claimed, int) and not isinstance(claimed, bool) and claimed == expected
        return Check(name, 0.0 if same else math.inf, 0.0)
    want, got = _numbers(expected), _numbers(claimed)
    if want is None or got is None or got.shape != want.shape or isinstance(claimed, bool):
        return Check(name, math.inf, SAME_RTOL)
    if not want.size:
        return Check(name, 0.0, SAME_RTOL)
    size = max(float(np.abs(want).max()), scale, np.finfo(float).tiny)
    diff = float(np.abs(got - want).max()) / size
    return Check(name, diff if math.isfinite(diff) else math.inf, SAME_RTOL)


def _lookup(data, path: str):
    """The card's value at a dotted path (``None`` where a key is missing)."""
    for key in path.split("."):
        if not isinstance(data, dict) or key not in data:
            return None
        data = data[key]
    return data


def consistency_checks(card_data: dict, expected: dict) -> list:
    """One :func:`same_check` per entry of ``expected`` (dotted card paths to values; a dict value
    is compared key by key, and the card's table must have no other keys).

    Parameters
    ----------
    card_data : dict
        The card's document.
    expected : dict
        What the card's problem determines.

    Returns
    -------
    list of Check
    """
    out = []
    for path, value in expected.items():
        if isinstance(value, dict):
            claimed = _lookup(card_data, path)
            extra = sorted(set(claimed) - set(value)) if isinstance(claimed, dict) else []
            if not isinstance(claimed, dict) or extra:
                out.append(Check(f"{path}" + (f" (with {', '.join(map(str, extra))[:80]})" if extra else "")
                                 + DETERMINED, math.inf, 0.0))
                continue
            out += consistency_checks(card_data, {f"{path}.{k}": v for k, v in value.items()})
        else:
            out.append(same_check(path, _lookup(card_data, path), value))
    return out


def plant_record(problem) -> dict:
    """What every family's card records of its plant: the dimensions, the time base and the
    observer's initial estimate (zero unless the problem gives ``observer.xhat0``)."""
    plant = problem.plant
    xhat0 = getattr(problem.options, "xhat0", None)
    return {"dims.n": plant.n, "dims.m": plant.m, "dims.p": plant.p, "dims.q": plant.q, "time": plant.time,
            "initial.xhat0": np.zeros(plant.n) if xhat0 is None else np.asarray(xhat0, dtype=float)}


__all__ = ["DETERMINED", "SAME_RTOL", "Determined", "consistency_checks", "plant_record", "same_check"]
