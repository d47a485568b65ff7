"""What every runtime refuses at a communication step, observers and plants alike (numpy only)."""

from __future__ import annotations

import math

import numpy as np


#: Vectors up to this many floats are checked element by element with :func:`math.isfinite`.
_SMALL = 16


class RuntimeInputError(Exception):
    """An input or call the observer cannot take (the FMU turns it into fmi2Error)."""


def check_step(h, inputs: dict, k: int | None = None) -> None:
    """Refuse a step ``h <= 0`` (or not finite) and non-finite inputs, naming them.

    Parameters
    ----------
    h : float
        The communication step.
    inputs : dict of str to numpy.ndarray
        The input vectors by name (``{"y": y, "u": u}``).
    k : int, optional
        The step counter, for the message.

    Raises
    ------
    RuntimeInputError
    """
    if not (isinstance(h, (int, float)) and math.isfinite(h) and h > 0):
        raise RuntimeInputError(f"communication step h = {h!r}{_at(k)}: expected h > 0")
    for name, vec in inputs.items():
        if type(vec) is np.ndarray and vec.ndim == 1 and vec.dtype.kind == "f" and vec.size <= _SMALL:
            if all(map(math.isfinite, vec.tolist())):   # a few floats: math.isfinite beats two ufunc calls
                continue
        elif np.all(np.isfinite(vec)):
            continue
        i = int(np.flatnonzero(~np.isfinite(vec))[0])
        raise RuntimeInputError(f"input {name}[{i + 1}] = {vec[i]}{_at(k)} is not finite")


def _at(k) -> str:
    return "" if k is None else f" at step k = {k}"
