"""The histories of one co-simulation and its metrics (:class:`CosimResult`): what the master returns,
``results.csv`` holds and the report draws; :func:`run_result` makes one of a run's histories, as the
master records them and as ``uiofmu report`` reads them back.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..runtime.card import Card
from ..runtime.labels import column_labels
from .metrics import delayed_metrics, error_metrics, functional_metrics, mode_metrics


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
    noise: dict | None = None      # a run with measurement noise: v, its std, the noisy estimate and both errors
    noise_w: dict | None = None    # a run with process noise: w, the noisy loop's error and its twin loop's
    names: dict | None = None      # the names and units when there is no card (a run read back from its files)
    estimate: str = "xhat"         # "zhat": a functional observer's run, x holding Lf x and xhat its zhat

    @property
    def labels(self) -> dict:
        """The names and units of the card's problem (:mod:`uiofmu.runtime.labels`), or ``names``; empty
        without either."""
        return self.card.labels if self.card is not None else (self.names or {})

    def column_labels(self) -> dict:
        """``{column of results.csv: label}`` for every labelled column (``{"xhat[1]": "T_room estimate [K]"}``)."""
        names = ("x", "xhat") if self.estimate == "xhat" else ()        # Lf x and zhat are no states
        return column_labels(self.labels, {name: getattr(self, name).shape[1]
                                           for name in (*names, "y", "u", "d", "dhat", "r")})

    def columns(self) -> dict:
        """Named columns for ``results.csv``."""
        cols = {"time": self.times, "h": np.append(self.h, np.nan)}
        column = {"x": "zhat_true", "xhat": "zhat"} if self.estimate == "zhat" else {}
        for name in ("x", "xhat", "y", "u", "d", "dhat", "r"):
            arr = getattr(self, name)
            for i in range(arr.shape[1]):
                cols[f"{column.get(name, name)}[{i + 1}]"] = arr[:, i]
        if self.mode is not None:
            cols["mode"] = self.mode
        if self.functional is not None:
            f = self.functional
            for i in range(f["gx"].shape[1]):
                cols[f"gx[{i + 1}]"], cols[f"gx_true[{i + 1}]"] = f["gx"][:, i], f["true"][:, i]
            cols["gx_valid"] = f["valid"]
            cols["error_norm"] = np.linalg.norm(f["gx"] - f["true"], axis=1)
            if self.noise is not None:
                self._noise_columns(cols, "gx")
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
        if self.noise is not None:
            self._noise_columns(cols, self.estimate)
        return cols

    def _noise_columns(self, cols: dict, estimate: str) -> None:
        """The columns of a run with measurement noise: the noise ``v[i]`` added to ``y[i]``, the estimate of
        the observer fed the noisy outputs (``xhat_noisy[i]``, or ``gx_noisy[i]``) and its error norm
        (``error_norm_noisy``)."""
        nz = self.noise
        for i in range(nz["v"].shape[1]):
            cols[f"v[{i + 1}]"] = nz["v"][:, i]
        for i in range(nz["estimate"].shape[1]):
            cols[f"{estimate}_noisy[{i + 1}]"] = nz["estimate"][:, i]
        cols["error_norm_noisy"] = np.linalg.norm(nz["error"], axis=1)


def run_result(times, h, x, xhat, y, u, d, r, dhat, *, mode=None, bound=None, decay=None, overshoot=None,
               functional: dict | None = None, window: tuple | None = None, formula: str = "",
               delayed: dict | None = None, bound_text: str | None = None, roundoff: dict | None = None,
               **known) -> CosimResult:
    """A run's :class:`CosimResult` with its metrics computed from its histories (:mod:`uiofmu.cosim.metrics`).

    Parameters
    ----------
    times, h, x, xhat, y, u, d, r, dhat : arrays
        The histories (row k is t_k; ``h`` the K steps).
    mode : array, optional
        The plant's mode at each point (a switched plant): ``metrics["modes"]``.
    bound, decay, overshoot : optional
        The certified bound at each point and the design's decay and overshoot it is compared with.
    functional : dict, optional
        A functional observer's ``gx``, ``true`` and ``valid``.
    window : (int, int), optional
        With ``functional``: its ``(delay, length)``.
    formula : str
        With ``functional``: its ``metrics["formula"]``.
    delayed : dict, optional
        A delayed observer's ``thetahat``, ``theta``, ``sigma_min``, ``valid`` and ``sigma_bound``.
    bound_text : str, optional
        The card's bound in words: of a delayed observer, for its metrics; else ``metrics["bound_formula"]``
        (with a bound only).
    roundoff : dict, optional
        With ``bound``: the run's leaks and the floor they carry (:func:`uiofmu.cosim.roundoff.roundoff_floor`).
    **known
        ``card`` or ``names`` (:class:`CosimResult`).

    Returns
    -------
    CosimResult
    """
    args = (times, h, x, xhat, y, u, d, r, dhat)
    if functional is not None:
        result = CosimResult(*args, mode=mode, functional=functional, **known)
        result.metrics = functional_metrics(times, h, functional["gx"], functional["true"], functional["valid"],
                                            *window)
        result.metrics["formula"] = formula
        return result
    if delayed is not None:
        dl = delayed
        result = CosimResult(*args, delayed=delayed, **known)
        result.metrics = error_metrics(times, h, x, xhat)
        result.metrics.update(delayed_metrics(times, h, x, xhat, dl["thetahat"], dl["theta"], dl["valid"],
                                              dl["sigma_min"], dl["sigma_bound"], bound_text or ""))
        return result
    estimated = dhat.shape[1] > 0
    result = CosimResult(*args, bound=bound, mode=mode, **known)
    result.metrics = error_metrics(times, h, x, xhat, bound, decay, overshoot, d if estimated else None,
                                   dhat if estimated else None, roundoff=roundoff)
    if bound is not None and bound_text is not None:
        result.metrics["bound_formula"] = bound_text
    if mode is not None:
        result.metrics["modes"] = mode_metrics(mode)
    return result


__all__ = ["CosimResult", "run_result"]
