"""What every runtime refuses at a communication step, observers and plants alike (numpy only)."""

from __future__ import annotations

import math

import numpy as np

from .refusals import refusal


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
        raise RuntimeInputError(refusal("input_not_finite", name=name, index=i + 1, value=vec[i], at=_at(k)))


def substeps(h: float, longest: float, limit: int, what: str) -> int:
    """The substeps of at most ``longest`` seconds that cover a communication step ``h`` (> 0).

    Parameters
    ----------
    h : float
        The communication step.
    longest : float
        The longest substep.
    limit : int
        The most substeps a step may take (each runtime's ``MAX_SUBSTEPS``, from what one costs).
    what : str
        Whose substeps, for the message (``"RK4 substeps of the observer"``).

    Returns
    -------
    int
        ``ceil(h / longest)``, at least 1.

    Raises
    ------
    StepRejected
        When more than ``limit`` would be needed: naming ``h``, the substep and the longest step
        accepted (nothing has changed; the caller may take shorter steps).
    """
    from .schedules import StepRejected

    count = h / longest - 1e-9
    if not count <= limit:
        raise StepRejected(f"communication step h = {h:.6g} s needs {count + 1e-9:.3g} {what} (at most "
                           f"{longest:.3g} s each), more than the {limit} a step may take: take steps of at most "
                           f"{limit * longest:.6g} s")
    return max(1, int(math.ceil(count)))


def _at(k) -> str:
    return "" if k is None else f" at step k = {k}"
