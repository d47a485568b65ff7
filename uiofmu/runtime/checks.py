"""The value checks of a design card (:mod:`uiofmu.runtime.card`) and its bounds, shared by the card schema
and the kernels' own checks (:mod:`uiofmu.runtime.kernels`). Each check names the card key it refuses."""

from __future__ import annotations

from .errors import CardError
from .matrices import as_array, as_scalar
from .text import check_text

#: Longest output window of a window kernel, and its largest power of a theta value.
MAX_WINDOW, MAX_POWER = 1024, 64
#: Largest dimension a card may declare (states, inputs, outputs, observer states).
MAX_DIM = 1000
#: Most design intervals an interval schedule may list.
MAX_INTERVALS = 256
#: Most modes a mode schedule may have (its card holds N^2 step matrices).
MAX_MODES = 16
#: Longest free text (``bound``, ``generator``, solver names) a card may hold.
MAX_TEXT = 1000


def table(value, key: str) -> dict:
    """``value`` when it is an object; CardError naming ``key`` otherwise."""
    if not isinstance(value, dict):
        raise CardError(f"design card {key}: expected an object, found {kind_of(value)}")
    return value


def kind_of(value) -> str:
    """What ``value`` is, for a message (``the integer 3``, ``a list``, ...)."""
    if isinstance(value, bool):
        return f"the boolean {str(value).lower()}"
    if isinstance(value, str):
        return f"the string {value[:40]!r}" + ("..." if len(value) > 40 else "")
    if value is None:
        return "null"
    return {"list": "a list", "dict": "an object", "int": f"the integer {value}",
            "float": f"the number {value!r}"}.get(type(value).__name__, type(value).__name__)


def integer(value, key: str, low: int, high: int) -> int:
    """An integer (not a boolean) in ``[low, high]``."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise CardError(f"design card {key}: expected an integer, found {kind_of(value)}")
    if not low <= value <= high:
        raise CardError(f"design card {key}: expected an integer in [{low}, {high}], found {value}")
    return value


def number(value, key: str, **bounds) -> float:
    """A finite number within ``bounds`` (:func:`uiofmu.runtime.matrices.as_scalar`)."""
    return as_scalar(value, f"design card {key}", error=CardError, **bounds)


def text(value, key: str, limit: int = MAX_TEXT) -> str:
    """Printable text of at most ``limit`` characters (empty allowed)."""
    return check_text(value, f"design card {key}", CardError, limit, allow_empty=True)


def choice(value, key: str, options: tuple) -> str:
    """One of ``options``."""
    if not isinstance(value, str) or value not in options:
        raise CardError(f"design card {key}: expected one of {', '.join(map(repr, options))}, found {kind_of(value)}")
    return value


def any_array(value, key: str) -> None:
    """A finite numeric array of any shape (nested lists of up to 5 levels)."""
    depth, probe = 0, value
    while isinstance(probe, list) and depth < 5:
        probe, depth = (probe[0] if probe else None), depth + 1
    as_array(value, key, (None,) * depth, CardError)


__all__ = ["MAX_DIM", "MAX_INTERVALS", "MAX_MODES", "MAX_POWER", "MAX_TEXT", "MAX_WINDOW", "any_array", "choice",
           "integer", "kind_of", "number", "table", "text"]
