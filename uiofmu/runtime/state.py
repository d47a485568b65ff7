"""Checking an FMU state before it is restored (numpy only: this runs inside FMUs).

A state handed back by an importer may be truncated, edited or another FMU's. Every
``set_state`` reads it through a :class:`StateReader`, which checks each field (its presence,
type, length, finiteness and range) and names the first one that is wrong, so that nothing
is changed unless the whole state is valid.
"""

from __future__ import annotations

import math

import numpy as np


class StateRejected(ValueError):
    """A state that cannot be restored (the message names the field); nothing changed."""


class StateReader:
    """The fields of one state, checked as they are read.

    Parameters
    ----------
    state : object
        What the importer handed back (a dict from :meth:`get_state`, if it is one).
    keys : tuple of str
        Exactly the fields the state must have.
    what : str
        Whose state it is, for messages (``"observer"``).

    Raises
    ------
    StateRejected
        For a non-dict, or missing or unknown fields.
    """

    def __init__(self, state, keys: tuple, what: str):
        if not isinstance(state, dict):
            raise StateRejected(f"{what} state: expected a dict, found {type(state).__name__}")
        missing = [key for key in keys if key not in state]
        extra = sorted(str(key) for key in state if key not in keys)
        if missing or extra:
            raise StateRejected(f"{what} state: missing fields {missing}, unknown fields {extra}")
        self.state = state
        self.what = what

    def _field(self, key: str) -> str:
        return f"{self.what} state field {key!r}"

    def vector(self, key: str, size: int, finite: bool = True, value=None) -> np.ndarray:
        """A list of ``size`` numbers.

        Parameters
        ----------
        key : str
            The field.
        size : int
            Its length.
        finite : bool
            Refuse NaN and infinities (inputs set through fmi2SetReal may hold them: the step
            refuses them, so a state of such an instance must still round-trip).
        value : object, optional
            Check this instead of ``state[key]`` (an entry of a nested field).

        Returns
        -------
        numpy.ndarray
        """
        value = self.state[key] if value is None else value
        if not isinstance(value, (list, tuple)) or len(value) != size:
            found = f"{len(value)} values" if isinstance(value, (list, tuple)) else type(value).__name__
            raise StateRejected(f"{self._field(key)}: expected a list of {size} numbers, found {found}")
        for i, v in enumerate(value):
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise StateRejected(f"{self._field(key)}[{i}]: expected a number, found {type(v).__name__}")
            if finite and not math.isfinite(v):
                raise StateRejected(f"{self._field(key)}[{i}] = {v!r} is not finite")
        return np.array(value, dtype=float).reshape(size)

    def number(self, key: str, low: float = -math.inf, open_low: bool = False) -> float:
        """A finite number ``>= low`` (``> low`` when ``open_low``).

        Parameters
        ----------
        key : str
            The field.
        low : float
            Its lower bound.
        open_low : bool
            Exclude the bound.

        Returns
        -------
        float
        """
        v = self.state[key]
        bad = isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)
        if bad or (v <= low if open_low else v < low):
            bound = f"> {low:g}" if open_low else f">= {low:g}"
            raise StateRejected(f"{self._field(key)} = {_short(v)}: expected a finite number {bound}")
        return float(v)

    def count(self, key: str) -> int:
        """A non-negative integer of at most 2**53 (a float counts every integer up to there).

        Parameters
        ----------
        key : str
            The field.

        Returns
        -------
        int
        """
        v = self.state[key]
        if type(v) is not int or not 0 <= v <= 2 ** 53:
            raise StateRejected(f"{self._field(key)} = {_short(v)}: expected an integer 0 <= {key} <= 2**53")
        return v

    def integer(self, key: str, low: int, high: int) -> int:
        """An integer from ``low`` to ``high`` (a mode, a seed, a generator's state).

        Parameters
        ----------
        key : str
            The field.
        low, high : int
            Its range, both included.

        Returns
        -------
        int
        """
        v = self.state[key]
        if type(v) is not int or not low <= v <= high:
            raise StateRejected(f"{self._field(key)} = {_short(v)}: expected an integer from {low} to {high}")
        return v


def _short(value, limit: int = 60) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[:limit] + "..."
