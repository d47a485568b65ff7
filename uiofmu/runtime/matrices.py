"""One normaliser for every matrix and vector that enters uiofmu.

Problem files, design cards and Python callers all hand matrices over as nested lists or
arrays; :func:`as_matrix` and :func:`as_vector` turn them into read-only float arrays and
say exactly which key is wrong and how (ragged rows, non-numeric entries, NaN/Inf, shape).
"""

from __future__ import annotations

import numbers

import numpy as np

from .errors import ProblemError


def _describe(value) -> str:
    if isinstance(value, str):
        return f"the string {value!r}"
    if isinstance(value, bool):
        return f"the boolean {value}"
    return f"a {type(value).__name__}"


def _number(value, name: str, where: str, error) -> float:
    if isinstance(value, bool) or not isinstance(value, (numbers.Real, np.floating, np.integer)):
        raise error(f"{name}{where}: expected a number, found {_describe(value)}")
    try:
        x = float(value)
    except OverflowError:
        raise error(f"{name}{where}: expected a finite number, found an integer of about "
                    f"{int(int(value).bit_length() * 0.30103) + 1} digits, too large for a float") from None
    if not np.isfinite(x):
        raise error(f"{name}{where}: expected a finite number, found {x}")
    return x


def freeze(array: np.ndarray) -> np.ndarray:
    """Return a read-only float64 copy of ``array``."""
    out = np.array(array, dtype=float, copy=True)
    out.setflags(write=False)
    return out


def as_matrix(value, name: str, rows: int | None = None, cols: int | None = None,
              error=ProblemError) -> np.ndarray:
    """Normalise ``value`` to a read-only 2-D float array.

    Parameters
    ----------
    value : list of lists or array_like
        The matrix, row by row. A numpy array is accepted as it is (after the checks).
    name : str
        The key the matrix came from, used in every message (e.g. ``"plant.A"``).
    rows, cols : int, optional
        The expected number of rows and columns; ``None`` accepts any.
    error : type, optional
        The exception class raised (default :class:`~uiofmu.runtime.errors.ProblemError`).

    Returns
    -------
    numpy.ndarray
        A read-only array of shape ``(rows, cols)``.

    Raises
    ------
    ProblemError
        Naming ``name`` and the expected against the found shape, the ragged row, or the
        non-numeric or non-finite entry.

    Examples
    --------
    >>> as_matrix([[1, 2], [3, 4]], "plant.A", rows=2, cols=2).shape
    (2, 2)
    """
    if isinstance(value, np.ndarray):
        if value.ndim != 2:
            raise error(f"{name}: expected a matrix (2-D), found an array with {value.ndim} dimensions")
        if not np.issubdtype(value.dtype, np.number) or np.iscomplexobj(value):
            raise error(f"{name}: expected real numbers, found dtype {value.dtype}")
        bad = np.argwhere(~np.isfinite(value))
        if bad.size:
            i, j = bad[0]
            raise error(f"{name}[{i}][{j}]: expected a finite number, found {value[i, j]}")
        mat = value.astype(float)
    else:
        if not isinstance(value, (list, tuple)):
            raise error(f"{name}: expected a matrix as a list of rows, found {_describe(value)}")
        if len(value) and all(not isinstance(r, (list, tuple)) for r in value):
            raise error(f"{name}: expected a matrix as a list of rows (e.g. [[1, 0]]), found a flat list")
        data = []
        width = None
        for i, row in enumerate(value):
            if not isinstance(row, (list, tuple)):
                raise error(f"{name}[{i}]: expected a row (a list of numbers), found {_describe(row)}")
            if width is None:
                width = len(row)
            elif len(row) != width:
                raise error(f"{name}: ragged matrix, row {i} has {len(row)} entries but row 0 has {width}")
            data.append([_number(x, name, f"[{i}][{j}]", error) for j, x in enumerate(row)])
        mat = np.array(data, dtype=float).reshape(len(data), width or 0)
    if rows is not None and cols is not None and mat.shape != (rows, cols):
        raise error(f"{name}: expected shape {rows}x{cols}, found {mat.shape[0]}x{mat.shape[1]}")
    if rows is not None and mat.shape[0] != rows:
        raise error(f"{name}: expected {rows} rows, found {mat.shape[0]}")
    if cols is not None and mat.shape[1] != cols:
        raise error(f"{name}: expected {cols} columns, found {mat.shape[1]}")
    return freeze(mat)


def as_vector(value, name: str, size: int | None = None, error=ProblemError) -> np.ndarray:
    """Normalise ``value`` to a read-only 1-D float array of length ``size``.

    Parameters
    ----------
    value : list or array_like
        The entries.
    name : str
        The key, used in every message.
    size : int, optional
        The expected length.
    error : type, optional
        The exception class raised.

    Returns
    -------
    numpy.ndarray
        A read-only vector.
    """
    if isinstance(value, np.ndarray):
        if value.ndim != 1:
            raise error(f"{name}: expected a vector (1-D), found an array with {value.ndim} dimensions")
        items = list(value)
    elif isinstance(value, (list, tuple)):
        items = list(value)
    else:
        raise error(f"{name}: expected a list of numbers, found {_describe(value)}")
    vec = np.array([_number(x, name, f"[{i}]", error) for i, x in enumerate(items)], dtype=float)
    if size is not None and vec.shape[0] != size:
        raise error(f"{name}: expected {size} entries, found {vec.shape[0]}")
    return freeze(vec)


def as_array(value, name: str, shape: tuple, error=ProblemError) -> np.ndarray:
    """Normalise nested lists to a read-only float array of exactly ``shape``.

    Parameters
    ----------
    value : nested lists of numbers
        The array, outermost axis first.
    name : str
        The key, used in every message (``"matrices.N"``).
    shape : tuple of int
        The expected shape; an entry ``None`` accepts any length on that axis (the same for
        every list on it).
    error : type, optional
        The exception class raised.

    Returns
    -------
    numpy.ndarray

    Raises
    ------
    error
        Naming the first entry (``matrices.N[3][0][1]``) that is not a list of the expected
        length, not a number, or not finite.

    Examples
    --------
    >>> as_array([[[1, 2]], [[3, 4]]], "matrices.Xz", (2, 1, 2)).shape
    (2, 1, 2)
    """
    want = list(shape)
    level = [value]
    for axis in range(len(want)):            # fast path: nested lists of plain JSON numbers
        if not all(type(item) is list for item in level):
            break
        if want[axis] is None and level:
            want[axis] = len(level[0])
        if any(len(item) != want[axis] for item in level):
            break
        level = [x for item in level for x in item]
    else:
        if all(type(x) is float or type(x) is int for x in level):
            try:
                arr = np.array(level, dtype=float)
            except OverflowError:
                arr = None
            if arr is not None and np.isfinite(arr).all():
                arr = arr.reshape(want)          # a new array already: made read-only without freeze's copy
                arr.setflags(write=False)
                return arr
    want = list(shape)
    flat = []
    stack = [(value, 0, "")]
    while stack:
        item, axis, where = stack.pop()
        if axis == len(want):
            flat.append((where, _number(item, name, where, error)))
            continue
        if not isinstance(item, (list, tuple)):
            raise error(f"{name}{where}: expected a list of {want[axis] if want[axis] is not None else 'some'} "
                        f"entries (axis {axis} of an array of shape {tuple(shape)}), found {_describe(item)}")
        if want[axis] is None:
            want[axis] = len(item)
        if len(item) != want[axis]:
            raise error(f"{name}{where}: expected {want[axis]} entries on axis {axis}, found {len(item)}")
        stack.extend((x, axis + 1, f"{where}[{i}]") for i, x in reversed(list(enumerate(item))))
    return freeze(np.array([x for _, x in flat], dtype=float).reshape(want))


def as_scalar(value, name: str, low: float | None = None, high: float | None = None,
              open_low: bool = False, open_high: bool = False, error=ProblemError) -> float:
    """Normalise ``value`` to a finite float within ``[low, high]`` (or open ends).

    Parameters
    ----------
    value : float
        The number.
    name : str
        The key, used in every message.
    low, high : float, optional
        Bounds; ``None`` leaves that side unbounded.
    open_low, open_high : bool, optional
        Exclude the bound itself.
    error : type, optional
        The exception class raised.

    Returns
    -------
    float
    """
    x = _number(value, name, "", error)
    lo_bad = low is not None and (x <= low if open_low else x < low)
    hi_bad = high is not None and (x >= high if open_high else x > high)
    if lo_bad or hi_bad:
        left = "(" if open_low else "["
        right = ")" if open_high else "]"
        lo = "-inf" if low is None else f"{low:g}"
        hi = "inf" if high is None else f"{high:g}"
        raise error(f"{name}: expected a value in {left}{lo}, {hi}{right}, found {x:g}")
    return x
