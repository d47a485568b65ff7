"""Co-simulation inputs: the problem's ``[signals]`` or a CSV file, held between rows (ZOH).

An input source offers named vectors (``sizes``: ``{"u": m, "d": q, ...}``) and their values at
a time (``values(t)``), and names element i of a vector as its user wrote it (``key(name, i)``); the master
routes each to the FMU inputs of the same name. A value for an Integer input (``mode``) must be an
fmi2Integer: integral, from -2**31 to 2**31 - 1 (:func:`uiofmu.cosim.fmi.first_non_integer`). A CSV has a
header ``time,u[1],...,d[1],...`` with one column for every element of every input the master
asks the table for (the plant's inputs and the observer's that no plant output feeds: ``u``,
``d``, ``mode``, ``theta``, ...), no other, and one row per change; each row holds from its time
until the next row's.
"""

from __future__ import annotations

import csv
import io
import math
import re
from pathlib import Path

import numpy as np

from ..runtime.errors import ProblemError
from ..runtime.files import read_text
from ..signals import Signal
from .fmi import first_non_integer, not_an_integer


class SignalInputs:
    """Inputs from signal definitions (sums of terms per channel): the vectors ``u`` and ``d``, and
    ``mode`` (a switched plant driven by its input; each value must be an integer, the master refuses
    another) and ``theta`` (an LPV plant's scheduling input) when given."""

    def __init__(self, u: tuple[Signal, ...], d: tuple[Signal, ...], mode: tuple[Signal, ...] = (),
                 theta: tuple[Signal, ...] = ()):
        self.signals = {"u": u, "d": d, **({"mode": mode} if mode else {}), **({"theta": theta} if theta else {})}
        self.sizes = {name: len(s) for name, s in self.signals.items()}

    def key(self, name: str, i: int) -> str:
        """The problem file's key of channel ``i`` (from 0) of the vector ``name``: ``signals.mode[0]``."""
        return f"signals.{name}[{i}]"

    def values(self, t: float) -> dict:
        """``{"u": u(t), "d": d(t)}`` (and ``"mode"``)."""
        return {name: np.array([s(t) for s in signals]) for name, signals in self.signals.items()}

    def values_at(self, times) -> dict:
        """Every vector at every time at once, ``{name: array (len(times), size)}``; row k is bit for
        bit ``values(times[k])``."""
        times = np.asarray(times, dtype=float)
        return {name: (np.stack([s.at(times) for s in signals], axis=1) if signals else np.zeros((times.size, 0)))
                for name, signals in self.signals.items()}


class CsvInputs:
    """Inputs from a CSV table, each row held from its time on.

    Parameters
    ----------
    path : str or Path
        The file.
    sizes : dict of str to int
        The vectors the table must give (one column ``name[i]`` per element): every column of
        the table is one of them, and every one of them has its column.
    owners : dict of str to str, optional
        Which FMU takes each vector (``"plant"``, ``"observer"``), for the messages.
    integers : collection of str, optional
        The vectors an FMU takes as Integer (``mode``): their every value must be an fmi2Integer
        (:func:`~uiofmu.cosim.fmi.first_non_integer`), else the line, column, time and value are named.
    """

    def __init__(self, path, sizes: dict, owners: dict | None = None, integers=()):
        path = Path(path)
        self.path = path
        self.sizes = {k: int(v) for k, v in sizes.items() if v}
        owners = owners or {}
        text = read_text(path, "input table", error=ProblemError)
        try:
            rows = list(csv.reader(io.StringIO(text, newline="")))
        except csv.Error as exc:
            raise ProblemError(f"--inputs {path}: not a CSV table ({exc})") from None
        if not rows or not rows[0] or rows[0][0].strip() != "time":
            raise ProblemError(f"--inputs {path}: the first column must be 'time'")
        header = [h.strip() for h in rows[0]]
        expected = ", ".join(f"{k}[1..{v}]" for k, v in self.sizes.items()) or "none"
        cols = {}
        for j, name in enumerate(header[1:], start=1):
            m_ = re.fullmatch(r"([A-Za-z_][A-Za-z0-9_]{0,63})\[([1-9]\d{0,8})\]", name)
            if not m_ or m_.group(1) not in self.sizes:
                raise ProblemError(f"--inputs {path}: unknown column {name[:60]!r} (the FMUs take {expected})")
            kind, idx = m_.group(1), int(m_.group(2))
            if not 1 <= idx <= self.sizes[kind]:
                raise ProblemError(f"--inputs {path}: column {name} but the {owners.get(kind, 'FMUs')} has "
                                   f"{self.sizes[kind]} {kind} channel(s)")
            if (kind, idx) in cols:
                raise ProblemError(f"--inputs {path}: column {name} appears twice")
            cols[(kind, idx)] = j
        missing = [f"{k}[{i}]" for k, v in self.sizes.items() for i in range(1, v + 1) if (k, i) not in cols]
        if missing:
            raise ProblemError(f"--inputs {path}: missing column(s) {', '.join(missing[:8])}"
                               f"{' ...' if len(missing) > 8 else ''} (the FMUs take {expected})")
        data, lines = [], []
        for i, row in enumerate(rows[1:], start=2):
            if not row or all(not c.strip() for c in row):
                continue
            if len(row) != len(header):
                raise ProblemError(f"--inputs {path}: line {i} has {len(row)} values, the header has {len(header)}")
            try:
                vals = [float(c) for c in row]
            except ValueError:
                raise ProblemError(f"--inputs {path}: line {i} has a non-numeric value") from None
            if not all(math.isfinite(v) for v in vals):
                raise ProblemError(f"--inputs {path}: line {i} has a non-finite value")
            data.append(vals)
            lines.append(i)
        if not data:
            raise ProblemError(f"--inputs {path}: no data rows")
        table = np.array(data)
        if np.any(np.diff(table[:, 0]) < 0):
            raise ProblemError(f"--inputs {path}: times must not decrease")
        self.times = table[:, 0]
        self.tables = {k: np.zeros((len(table), v)) for k, v in self.sizes.items()}
        for (kind, idx), j in cols.items():
            self.tables[kind][:, idx - 1] = table[:, j]
        for kind in sorted(set(integers) & set(self.tables)):
            bad = first_non_integer(self.tables[kind])
            if bad >= 0:
                row, i = divmod(bad, self.sizes[kind])
                raise ProblemError(not_an_integer(f"--inputs {path}: line {lines[row]}, column {kind}[{i + 1}] "
                                                  f"(t = {self.times[row]:g} s)", self.tables[kind][row, i]))

    def key(self, name: str, i: int) -> str:
        """The column of element ``i`` (from 0) of the vector ``name``: ``--inputs PATH: column mode[1]``."""
        return f"--inputs {self.path}: column {name}[{i + 1}]"

    def _row(self, t: float) -> int:
        return max(int(np.searchsorted(self.times, t + 1e-12 * max(1.0, abs(t)), side="right")) - 1, 0)

    def values(self, t: float) -> dict:
        """Every vector of the table at time t."""
        row = self._row(t)
        return {k: v[row].copy() for k, v in self.tables.items()}

    def values_at(self, times) -> dict:
        """Every vector at every time at once (row k is ``values(times[k])``)."""
        times = np.asarray(times, dtype=float)
        rows = np.searchsorted(self.times, times + 1e-12 * np.maximum(1.0, np.abs(times)), side="right") - 1
        rows = np.maximum(rows, 0)
        return {k: v[rows] for k, v in self.tables.items()}


def values_at(inputs, times) -> dict:
    """The vectors of an input source at every time, ``{name: array (len(times), size)}``: its own
    ``values_at`` when it has one, else ``values(t)`` at each time in turn (inputs are functions of
    time: the master evaluates them for all its communication points before it steps)."""
    if hasattr(inputs, "values_at"):
        return inputs.values_at(times)
    rows = [inputs.values(float(t)) for t in times]
    names = rows[0].keys() if rows else inputs.sizes.keys()
    return {name: np.array([np.ravel(np.asarray(r[name], dtype=float)) for r in rows]).reshape(len(rows), -1)
            if rows else np.zeros((0, inputs.sizes[name])) for name in names}
