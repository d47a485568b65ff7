"""The signal-source FMU: a table of inputs played as outputs, in C (no Python in the importer).

An FMI importer binds only constant values to inputs (SSP, a master's start values); the time-varying
``u``, ``d``, ``theta`` and ``mode`` of a co-simulation then come from a third FMU whose outputs are
connected to them. Its kernel (``c/kernel_source.c``) holds each row of a :class:`SignalTable` from its
time until the next row's, as :class:`uiofmu.cosim.inputs.CsvInputs` holds a CSV's rows; the table
travels as data in ``resources/signals.bin`` (little-endian doubles after a header: the layout is in
``c/kernel_source.h``), read and checked at ``fmi2Instantiate``, never written into its sources. Its
``design_data.c`` holds the sizes of its ports only.
"""

from __future__ import annotations

import hashlib
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import __version__
from ..runtime.errors import ProblemError
from ..runtime.files import check_output_file
from ..runtime.ports import KERNEL_PORTS, source_ports
from ..runtime.step_rules import StepRule
from .c_backend import CKernel, _check_platform, description_xml, fmu_table, guid_of, pack_c_fmu, table_rows

#: The kernel of signal sources.
SOURCE_KERNEL = CKernel("kernel_source.c", "kernel_source.h", "UIOFMU_KERNEL_SOURCE", "source")
#: The table's file in the FMU's ``resources/`` (``UIOFMU_SOURCE_TABLE_FILE`` in ``c/kernel_source.h``).
TABLE_FILE = "signals.bin"
#: The first 8 bytes of the table file.
TABLE_MAGIC = b"UIOSIG01"
#: Most rows of a table (the C kernel's bound).
MAX_ROWS = 2 ** 26
#: The vectors a source plays, in the order of its ports and its table's columns.
VECTORS = tuple(port.key for port in KERNEL_PORTS["source"])


@dataclass(frozen=True)
class SignalTable:
    """Inputs as a table: row k holds from ``times[k]`` until ``times[k + 1]`` (the last for ever).

    Attributes
    ----------
    times : numpy.ndarray
        Row times (s), finite and not decreasing; at least one row.
    values : dict of str to numpy.ndarray
        ``{name: array (rows, size)}`` for names among :data:`VECTORS`; finite, and ``mode`` (one column)
        integral from -2**31 to 2**31 - 1.
    where : str
        Where the table comes from, for messages (``"signals"``, ``"--inputs PATH"``).

    Raises
    ------
    ProblemError
        For a table that breaks one of these rules, naming the row and the column.
    """

    times: np.ndarray
    values: dict
    where: str = "signal table"

    def __post_init__(self):
        times = np.array(self.times, dtype=float).ravel()
        if not 1 <= times.size <= MAX_ROWS:
            raise ProblemError(f"{self.where}: {times.size} rows, expected 1 to {MAX_ROWS}")
        if not np.all(np.isfinite(times)) or np.any(np.diff(times) < 0):
            raise ProblemError(f"{self.where}: times must be finite and must not decrease")
        unknown = sorted(set(self.values) - set(VECTORS))
        if unknown:
            raise ProblemError(f"{self.where}: a signal source plays {', '.join(VECTORS)}, not {', '.join(unknown)}")
        values = {}
        for name in VECTORS:
            if name not in self.values:
                continue
            arr = np.array(self.values[name], dtype=float).reshape(times.size, -1)
            bad = np.argwhere(~np.isfinite(arr))
            if bad.size:
                row, col = bad[0]
                raise ProblemError(f"{self.where}: {name}[{col + 1}] at t = {times[row]:g} s is not finite")
            if name == "mode":
                if arr.shape[1] != 1:
                    raise ProblemError(f"{self.where}: one mode column, found {arr.shape[1]}")
                off = np.argwhere((arr != np.floor(arr)) | (arr < -2 ** 31) | (arr > 2 ** 31 - 1))
                if off.size:
                    row = off[0][0]
                    raise ProblemError(f"{self.where}: mode[1] = {float(arr[row, 0])!r} at t = {times[row]:g} s is "
                                       "not an fmi2Integer")
            arr.setflags(write=False)
            values[name] = arr
        times.setflags(write=False)
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "values", values)

    @property
    def sizes(self) -> dict:
        """``{name: elements}`` of the vectors it plays, in the order of its columns."""
        return {name: arr.shape[1] for name, arr in self.values.items() if arr.shape[1]}

    def at(self, t: float) -> dict:
        """Every vector at time ``t``: the row the C kernel holds there (the last whose time is at most
        ``t + 1e-12 max(1, |t|)``, row 0 before the first)."""
        limit = t + 1e-12 * max(1.0, abs(t))
        row = max(int(np.searchsorted(self.times, limit, side="right")) - 1, 0)
        return {name: arr[row].copy() for name, arr in self.values.items()}

    def to_bytes(self) -> bytes:
        """The table file (layout in ``c/kernel_source.h``)."""
        columns = [self.values[name] for name in self.sizes]
        body = np.column_stack([self.times, *columns]) if columns else self.times.reshape(-1, 1)
        head = TABLE_MAGIC + struct.pack("<QQ", body.shape[0], body.shape[1] - 1)
        return head + np.ascontiguousarray(body, dtype="<f8").tobytes()


def source_data(table: SignalTable) -> str:
    """``design_data.c`` of a signal source: the sizes of its ports (numbers only), its variable table and
    ``UIOFMU_FMU``; never a value of the table."""
    sizes = table.sizes
    return "\n".join([
        "/* Generated by uiofmu: the sizes of a signal source (its table is resources/signals.bin). */",
        f'#include "{SOURCE_KERNEL.header}"', "",
        "const UiofmuSource UIOFMU_SOURCE = {",
        f"    .m = {int(sizes.get('u', 0))}, .q = {int(sizes.get('d', 0))}, .s = {int(sizes.get('theta', 0))}, "
        f".modes = {int(sizes.get('mode', 0))},",
        "};", ""])


def build_source(table: SignalTable, output, identifier: str = "signal_source", experiment: dict | None = None
                 ) -> Path:
    """Write the C signal-source FMU of ``table`` to ``output``.

    Parameters
    ----------
    table : SignalTable
        What it plays.
    output : str or Path
        The ``.fmu`` file to write (atomically).
    identifier : str
        The model identifier (an ASCII identifier).
    experiment : dict, optional
        Its ``<DefaultExperiment>`` (:func:`uiofmu.runtime.ports.experiment`).

    Returns
    -------
    Path
    """
    output = check_output_file(output, "FMU", ".fmu")
    _check_platform()
    data = table.to_bytes()
    ports = source_ports(table.sizes)
    spec = {"kind": "source", "sizes": table.sizes, "rows": int(table.times.size),
            "table": {"file": TABLE_FILE, "sha256": hashlib.sha256(data).hexdigest()}}
    guid = guid_of({"backend": "c", **spec})
    first, last = float(table.times[0]), float(table.times[-1])
    text = (f"signal source: {', '.join(f'{k}[{v}]' for k, v in table.sizes.items()) or 'nothing'} from a table of "
            f"{table.times.size} rows, {first:g} s to {last:g} s, each held until the next (uiofmu {__version__}, "
            "C backend)")
    rows = table_rows(SOURCE_KERNEL, "signal source", ports)
    design = source_data(table) + "\n".join(fmu_table(guid, identifier, SOURCE_KERNEL, rows))
    return pack_c_fmu(output, identifier, SOURCE_KERNEL, design,
                      lambda sources: description_xml(identifier, guid, text, sources, experiment, ports),
                      spec, ports=ports, rule=StepRule((), True), resources={TABLE_FILE: data})


__all__ = ["MAX_ROWS", "SOURCE_KERNEL", "SignalTable", "TABLE_FILE", "build_source"]
