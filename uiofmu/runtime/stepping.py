"""What every runtime refuses at a communication step, observers and plants alike (numpy only)."""

from __future__ import annotations

import math

import numpy as np


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
    at = "" if k is None else f" at step k = {k}"
    if not (isinstance(h, (int, float)) and math.isfinite(h) and h > 0):
        raise RuntimeInputError(f"communication step h = {h!r}{at}: expected h > 0")
    for name, vec in inputs.items():
        if not np.all(np.isfinite(vec)):
            i = int(np.flatnonzero(~np.isfinite(vec))[0])
            raise RuntimeInputError(f"input {name}[{i + 1}] = {vec[i]}{at} is not finite")
