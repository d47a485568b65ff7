"""Co-simulation inputs: the problem's ``[signals]`` or a CSV file, held between rows (ZOH).

A CSV has a header ``time,u[1],...,d[1],...`` (any subset of the plant's ``u`` and ``d``
channels; a missing channel is zero) and one row per change; each row holds from its time
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


class SignalInputs:
    """Inputs from signal definitions (sums of terms per channel)."""

    def __init__(self, u: tuple[Signal, ...], d: tuple[Signal, ...]):
        self.u_signals, self.d_signals = u, d

    def u(self, t: float) -> np.ndarray:
        """Known inputs at time t."""
        return np.array([s(t) for s in self.u_signals])

    def d(self, t: float) -> np.ndarray:
        """Unknown inputs at time t."""
        return np.array([s(t) for s in self.d_signals])


class CsvInputs:
    """Inputs from a CSV table, each row held from its time on.

    Parameters
    ----------
    path : str or Path
        The file.
    m, q : int
        Numbers of known and unknown inputs of the plant.
    """

    def __init__(self, path, m: int, q: int):
        path = Path(path)
        text = read_text(path, "input table", error=ProblemError)
        try:
            rows = list(csv.reader(io.StringIO(text, newline="")))
        except csv.Error as exc:
            raise ProblemError(f"--inputs {path}: not a CSV table ({exc})") from None
        if not rows or not rows[0] or rows[0][0].strip() != "time":
            raise ProblemError(f"--inputs {path}: the first column must be 'time'")
        header = [h.strip() for h in rows[0]]
        cols = {}
        for j, name in enumerate(header[1:], start=1):
            m_ = re.fullmatch(r"(u|d|mode|theta)\[([1-9]\d{0,8})\]|(mode)", name)
            if not m_:
                raise ProblemError(f"--inputs {path}: unknown column {name[:60]!r} "
                                   "(expected u[i], d[i], mode, theta[i])")
            kind, idx = (m_.group(1), int(m_.group(2))) if m_.group(1) else ("mode", 1)
            limit = {"u": m, "d": q}.get(kind)
            if limit is not None and not 1 <= idx <= limit:
                raise ProblemError(f"--inputs {path}: column {name} but the plant has {limit} {kind} channel(s)")
            if (kind, idx) in cols:
                raise ProblemError(f"--inputs {path}: column {name} appears twice")
            cols[(kind, idx)] = j
        data = []
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
        if not data:
            raise ProblemError(f"--inputs {path}: no data rows")
        table = np.array(data)
        if np.any(np.diff(table[:, 0]) < 0):
            raise ProblemError(f"--inputs {path}: times must not decrease")
        self.times = table[:, 0]
        self.u_table = np.zeros((len(table), m))
        self.d_table = np.zeros((len(table), q))
        for (kind, idx), j in cols.items():
            if kind == "u":
                self.u_table[:, idx - 1] = table[:, j]
            elif kind == "d":
                self.d_table[:, idx - 1] = table[:, j]

    def _row(self, t: float) -> int:
        return max(int(np.searchsorted(self.times, t + 1e-12 * max(1.0, abs(t)), side="right")) - 1, 0)

    def u(self, t: float) -> np.ndarray:
        """Known inputs at time t."""
        return self.u_table[self._row(t)].copy()

    def d(self, t: float) -> np.ndarray:
        """Unknown inputs at time t."""
        return self.d_table[self._row(t)].copy()
