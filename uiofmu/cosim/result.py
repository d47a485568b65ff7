"""The histories of one co-simulation and its metrics (:class:`CosimResult`): what the master returns,
``results.csv`` holds and the report draws.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..runtime.card import Card
from ..runtime.labels import column_labels


@dataclass
class CosimResult:
    """Histories of one co-simulation (row k is the communication point t_k) and its metrics."""

    times: np.ndarray
    h: np.ndarray
    x: np.ndarray
    xhat: np.ndarray
    y: np.ndarray
    u: np.ndarray
    d: np.ndarray
    r: np.ndarray
    dhat: np.ndarray
    metrics: dict = field(default_factory=dict)
    card: Card | None = None
    bound: np.ndarray | None = None
    mode: np.ndarray | None = None
    functional: dict | None = None
    delayed: dict | None = None
    timing: dict = field(default_factory=dict)
    names: dict | None = None      # the names and units when there is no card (a run read back from its files)

    @property
    def labels(self) -> dict:
        """The names and units of the card's problem (:mod:`uiofmu.runtime.labels`), or ``names``; empty
        without either."""
        return self.card.labels if self.card is not None else (self.names or {})

    def column_labels(self) -> dict:
        """``{column of results.csv: label}`` for every labelled column (``{"xhat[1]": "T_room estimate [K]"}``)."""
        return column_labels(self.labels, {name: getattr(self, name).shape[1]
                                           for name in ("x", "xhat", "y", "u", "d", "dhat", "r")})

    def columns(self) -> dict:
        """Named columns for ``results.csv``."""
        cols = {"time": self.times, "h": np.append(self.h, np.nan)}
        for name in ("x", "xhat", "y", "u", "d", "dhat", "r"):
            arr = getattr(self, name)
            for i in range(arr.shape[1]):
                cols[f"{name}[{i + 1}]"] = arr[:, i]
        if self.mode is not None:
            cols["mode"] = self.mode
        if self.functional is not None:
            f = self.functional
            for i in range(f["gx"].shape[1]):
                cols[f"gx[{i + 1}]"], cols[f"gx_true[{i + 1}]"] = f["gx"][:, i], f["true"][:, i]
            cols["gx_valid"] = f["valid"]
            cols["error_norm"] = np.linalg.norm(f["gx"] - f["true"], axis=1)
            return cols
        cols["error_norm"] = np.linalg.norm(self.x - self.xhat, axis=1)
        if self.bound is not None:
            cols["bound"] = self.bound
        if self.delayed is not None:
            dl = self.delayed
            for i in range(dl["thetahat"].shape[1]):
                cols[f"thetahat[{i + 1}]"] = dl["thetahat"][:, i]
            if dl["theta"] is not None:
                cols["theta_error_norm"] = np.linalg.norm(dl["thetahat"] - dl["theta"], axis=1)
            cols["sigma_min"], cols["valid"] = dl["sigma_min"], dl["valid"]
        return cols


__all__ = ["CosimResult"]
