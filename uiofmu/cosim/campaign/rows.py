"""The table of a campaign: its rows as they finish, in row order, in a file (:class:`RowFile`),
and ``campaign.csv`` written from it."""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path

from ...runtime.files import atomic_output
from .file import Campaign
from .fmus import Setup
from .sampling import SCALAR_AXES

#: Columns of every campaign table, before the axes.
HEAD = ["row"]
#: Scalar metrics first in the table (others follow in the order they appear).
PREFERRED = ["n_steps", "t_end", "initial_error_norm", "final_error_norm", "max_error_norm", "error_floor",
             "steps_to_1pct", "time_to_1pct", "step_min", "step_max", "bound_respected", "max_bound_ratio",
             "first_bound_violation", "final_bound", "rms_error", "dhat_rms_error", "dhat_rms_error_second_half"]


def cell(value) -> str:
    """A value as its table cell: empty for None and NaN, ``true``/``false``, a float by its repr."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return "" if math.isnan(value) else repr(value)
    return str(value)


def axis_columns(campaign: Campaign, setup: Setup) -> list:
    """The axis columns of the table: ``steps``, ``steps_seed``, then one per component."""
    cols = ["steps", "steps_seed"]
    sizes = {"xhat0_error": setup.n, "noise_y": setup.p, "noise_w": setup.r,
             **{f"plant.{k}": v for k, v in setup.parameters.items()}}
    for name, _ in campaign.named_axes():
        cols += [name] if name in SCALAR_AXES else [f"{name}[{i + 1}]" for i in range(sizes[name])]
    return (cols + (["noise_seed"] if campaign.noise_y is not None else [])
            + (["mismatch_seed"] if campaign.plant_mismatch is not None else [])
            + (["noise_w_seed"] if campaign.noise_w is not None else []))


def flat(sc: dict) -> dict:
    """A scenario with each list value spread over cells ``key[1]``, ``key[2]``, ...."""
    out = {}
    for key, value in sc.items():
        if isinstance(value, list):
            out.update({f"{key}[{i + 1}]": v for i, v in enumerate(value)})
        else:
            out[key] = value
    return out


def axis_cells(sc: dict, columns: list) -> list:
    """The row and axis cells of scenario ``sc`` in ``columns``, the table's (:data:`HEAD` and
    :func:`axis_columns`, found once for many rows)."""
    values = flat(sc)
    return [cell(values.get(c)) for c in columns]


def read_table(path) -> list:
    """A campaign table as a list of dicts of strings (the CSV cells)."""
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


#: Cells of a row that are not metrics.
_NOT_METRICS = ("status", "reason", "wall_s")


class RowFile:
    """The rows of a campaign as they finish, in row order, in a file (one CSV line a row): the row and
    axis cells, ``status``, ``reason``, ``wall_s``, then the metric cells in the order their keys first
    appeared (a later key adds a cell at the end). :meth:`write_table` writes the table from it.

    Parameters
    ----------
    path : Path
        The file (in the staging folder).
    campaign : Campaign
    setup : Setup
    """

    def __init__(self, path: Path, campaign: Campaign, setup: Setup):
        self.path = path
        self.head = HEAD + axis_columns(campaign, setup) + ["status", "reason"]
        self.keys: dict = {}
        self.file = open(path, "w", newline="", encoding="utf-8")
        self.writer = csv.writer(self.file, lineterminator="\n")

    def add(self, axis: list, result: dict) -> None:
        """Append a row: its row and axis cells ``axis`` (:func:`axis_cells`) and its ``result`` (status,
        reason, metrics)."""
        metrics = [k for k in result if k not in _NOT_METRICS]
        for key in metrics:
            self.keys.setdefault(key, len(self.keys))
        cells = [""] * len(self.keys)
        for key in metrics:
            cells[self.keys[key]] = cell(result[key])
        self.writer.writerow(axis + [cell(result.get("status")), cell(result.get("reason")),
                                     cell(result.get("wall_s"))] + cells)

    def columns(self) -> list:
        """The table's columns: the head, the metrics (:data:`PREFERRED` first) and ``wall_s``."""
        metrics = [k for k in PREFERRED if k in self.keys] + [k for k in self.keys if k not in PREFERRED]
        return self.head + metrics + ["wall_s"]

    def write_table(self, path: Path) -> Path:
        """Write ``campaign.csv`` of the rows so far to ``path``, atomically, reading the file once."""
        self.file.flush()
        n = len(self.head)
        where = [n + 1 + self.keys[k] for k in self.columns()[n:-1]]
        with atomic_output(path, "campaign table") as part, open(self.path, newline="", encoding="utf-8") as src, \
                open(part, "w", newline="", encoding="utf-8") as dst:
            writer = csv.writer(dst, lineterminator="\n")
            writer.writerow(self.columns())
            for cells in csv.reader(src):
                writer.writerow(cells[:n] + [cells[i] if i < len(cells) else "" for i in where] + [cells[n]])
            dst.flush()
            os.fsync(dst.fileno())
        return path

    def close(self) -> None:
        """Close the file."""
        self.file.close()


__all__ = ["HEAD", "PREFERRED", "RowFile", "axis_cells", "axis_columns", "cell", "flat", "read_table"]
