"""The design card: one JSON document that carries a design from ``design`` to ``build``,
``validate`` and ``cosim``.

Floats are written with :func:`repr` (shortest text that reads back bit-identical), so a
card round-trips exactly. The card is data only: no pickle, no code.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import CardError
from .matrices import freeze

FORMAT = "uiofmu.design"
VERSION = 1
REQUIRED = ("format", "version", "family", "name", "dims", "time", "dt", "schedule", "matrices",
            "initial", "certificate", "problem")

#: Matrices of the runtime and their shapes in terms of the dims (before any schedule axes).
RUNTIME_SHAPES = {
    "N": ("nz", "nz"), "L": ("nz", "p"), "G": ("nz", "m"), "c": ("nz",),
    "Xz": ("n", "nz"), "Xy": ("n", "p"), "C": ("p", "n"),
    "Dy": ("q", "p"), "Yx": ("p", "n"), "Yu": ("p", "m"), "Yc": ("p",),
}
#: Matrices every card has; the ``Dy, Yx, Yu, Yc`` group is present when ``dhat`` is estimated.
CORE = ("N", "L", "G", "c", "Xz", "Xy", "C")
DHAT = ("Dy", "Yx", "Yu", "Yc")


def to_lists(value):
    """Arrays (and complex numbers) to nested lists of floats, recursively."""
    if isinstance(value, np.ndarray):
        return value.tolist() if value.dtype.kind in "biuf" else to_lists(value.tolist())
    if isinstance(value, dict):
        return {k: to_lists(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_lists(v) for v in value]
    if isinstance(value, (np.floating,)):
        return float(value)
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def _dump(value, indent: int) -> str:
    """JSON with numeric rows on one line (readable matrices); floats via repr."""
    pad = " " * indent
    if isinstance(value, dict):
        if not value:
            return "{}"
        if len(value) <= 6 and all(isinstance(v, (int, float, bool, str)) or v is None for v in value.values()):
            return "{" + ", ".join(f"{json.dumps(str(k))}: {_dump(v, 0)}" for k, v in value.items()) + "}"
        items = [f'{pad} {json.dumps(str(k))}: {_dump(v, indent + 1)}' for k, v in value.items()]
        return "{\n" + ",\n".join(items) + f"\n{pad}}}"
    if isinstance(value, list):
        if all(isinstance(v, (int, float, bool, str)) or v is None for v in value):
            return "[" + ", ".join(_dump(v, 0) for v in value) + "]"
        return "[\n" + ",\n".join(f"{pad} {_dump(v, indent + 1)}" for v in value) + f"\n{pad}]"
    if isinstance(value, float):
        if not math.isfinite(value):
            raise CardError(f"a design card cannot hold the non-finite number {value}")
        return repr(value)
    return json.dumps(value)


@dataclass(frozen=True)
class Card:
    """A checked design card.

    Attributes
    ----------
    data : dict
        The whole JSON document.
    matrices : dict of str to numpy.ndarray
        The runtime matrices, read-only (with leading schedule axes where the schedule has them).
    """

    data: dict
    matrices: dict

    @property
    def family(self) -> str:
        """The observer family."""
        return self.data["family"]

    @property
    def name(self) -> str:
        """Model name."""
        return self.data["name"]

    @property
    def dims(self) -> dict:
        """``n, m, p, q, nz``."""
        return self.data["dims"]

    @property
    def dt(self) -> float | None:
        """Design period (None when the schedule follows the communication step)."""
        return self.data["dt"]

    @property
    def schedule(self) -> dict:
        """How the runtime picks matrices (``kind`` and its data)."""
        return self.data["schedule"]

    @property
    def has_dhat(self) -> bool:
        """Whether the card estimates the unknown input."""
        return all(k in self.matrices for k in DHAT)

    def to_json(self) -> str:
        """The card as text."""
        return _dump(self.data, 0) + "\n"

    def write(self, path) -> Path:
        """Write the card to ``path`` (parents created)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(self.to_json(), encoding="utf-8")
        return path


def _check_shape(name: str, arr: np.ndarray, dims: dict, lead: int) -> None:
    want = tuple(dims[d] for d in RUNTIME_SHAPES[name])
    if arr.ndim != lead + len(want) or arr.shape[lead:] != want:
        raise CardError(f"card matrices.{name}: expected trailing shape {want} after {lead} schedule axes, "
                        f"found {arr.shape}")


def card_from_data(data: dict, require_verified: bool = True) -> Card:
    """Check a card document and build a :class:`Card`.

    Parameters
    ----------
    data : dict
        The parsed JSON.
    require_verified : bool
        Refuse a card whose certificate was not verified (default).

    Returns
    -------
    Card

    Raises
    ------
    CardError
        Naming the missing or malformed key.
    """
    from .schedules import schedule_axes

    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise CardError(f'not a uiofmu design card: "format" must be "{FORMAT}"')
    missing = [k for k in REQUIRED if k not in data]
    if missing:
        raise CardError(f"design card: missing key(s) {', '.join(missing)}")
    if data["version"] != VERSION:
        raise CardError(f"design card version {data['version']!r} is not supported (this uiofmu reads {VERSION})")
    dims = data["dims"]
    for d in ("n", "m", "p", "q", "nz"):
        if not isinstance(dims.get(d), int) or dims[d] < 0:
            raise CardError(f"design card dims.{d}: expected a non-negative integer, found {dims.get(d)!r}")
    if require_verified and not data["certificate"].get("verified", False):
        raise CardError("design card: its certificate is not verified (certificate.verified is false); "
                        "it cannot be built or run")
    lead = schedule_axes(data["schedule"])
    mats = {}
    for name, value in data["matrices"].items():
        if name not in RUNTIME_SHAPES:
            continue
        try:
            arr = np.array(value, dtype=float)
        except (TypeError, ValueError):
            raise CardError(f"card matrices.{name}: not a numeric array") from None
        if not np.all(np.isfinite(arr)):
            raise CardError(f"card matrices.{name}: contains non-finite numbers")
        _check_shape(name, arr, dims, lead.get(name, 0))
        mats[name] = freeze(arr)
    absent = [k for k in CORE if k not in mats]
    if absent:
        raise CardError(f"design card matrices: missing {', '.join(absent)}")
    return Card(data, mats)


def read_card(path, require_verified: bool = True) -> Card:
    """Read and check a design card file.

    Parameters
    ----------
    path : str or Path
    require_verified : bool
        Refuse an unverified certificate (default).

    Returns
    -------
    Card
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise CardError(f"{path}: no such design card") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CardError(f"{path}: not a readable JSON design card ({exc})") from None
    return card_from_data(data, require_verified)
