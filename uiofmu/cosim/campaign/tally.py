"""The summary of a campaign: what it needs of the finished rows, kept compact (:class:`Tally`), and
``summary.json`` made from it."""

from __future__ import annotations

import math
import re
from array import array

import numpy as np

from .file import Campaign
from .fmus import Setup
from .sampling import scenario

#: Kinds of failure reasons (:func:`reason_kind`) counted one by one in the summary (the others are
#: counted together).
MAX_REASONS = 1000
#: Metrics whose quantiles the summary gives.
QUANTILE_KEYS = ("steps_to_1pct", "time_to_1pct", "final_error_norm", "max_bound_ratio", "dhat_rms_error",
                 "dhat_rms_error_second_half", "rms_error", "noise_rms_error", "noise_gain_measured",
                 "noise_gain_ratio", "noise_w_rms_error", "noise_gain_w_measured", "noise_gain_w_ratio")
QUANTILES = (0.0, 0.05, 0.25, 0.5, 0.75, 0.95, 1.0)
#: Added to :data:`QUANTILE_KEYS` with a ``plant_mismatch`` axis: the error a mismatched plant settles at.
MISMATCH_KEYS = ("error_floor",)


_NUMBER = re.compile(r"(?<![\w.])[-+]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][-+]?\d+)?(?!\w)")


def reason_kind(reason: str) -> str:
    """A failure reason with its numbers masked as ``#`` (not the digits inside a name such as
    ``fmi2Discard``): the reasons of one kind of failure, whatever its step, time or value.

    Examples
    --------
    >>> reason_kind("refused step 12 (t = 1.2 s): h = 1.5e-3 s is not dt = 0.1 s (fmi2Discard)")
    'refused step # (t = # s): h = # s is not dt = # s (fmi2Discard)'
    """
    return _NUMBER.sub("#", reason)


class Tally:
    """What the summary and the figure need of the finished rows, kept compact: counters, the failure
    reasons grouped by kind (:func:`reason_kind`; at most :data:`MAX_REASONS` kinds, each with its count,
    one example and its first rows), the worst bound ratio and its row (and how many runs have their
    largest ratio at k = 1), and per :data:`QUANTILE_KEYS` figure an array of doubles of its values.
    Rows must come in row order (the worst ratio's row is then the first of equal ratios). With ``mismatch``
    (a ``plant_mismatch`` axis) also :data:`MISMATCH_KEYS` and each run's mismatch with its error floor."""

    def __init__(self, mismatch: bool = False):
        self.finished = self.ok = self.violations = self.other_reasons = self.ratios = self.ratios_at_start = 0
        self.reasons: dict = {}
        self.worst: tuple | None = None
        self.worst_noise: tuple | None = None       # (noise gain ratio, row, respected)
        self.noise_violations = 0
        self.noise_pairs = (array("d"), array("d"))   # a noisy run's ||sigma|| and its error, for the figure
        self.keys = QUANTILE_KEYS + (MISMATCH_KEYS if mismatch else ())
        self.values = {key: array("d") for key in self.keys}
        self.present = dict.fromkeys(self.keys, 0)
        self.mismatch_pairs = (array("d"), array("d"))   # a run's plant_mismatch and its error floor
        self.mismatch = mismatch

    def add(self, row: int, result: dict, mismatch: float | None = None) -> None:
        """Count the ``result`` of ``row`` (``mismatch``: its plant's, with a ``plant_mismatch`` axis)."""
        self.finished += 1
        if result["status"] != "ok":
            self._failure(row, result)
            return
        self.ok += 1
        for key in self.keys:
            if key in result:
                self.present[key] += 1
                if result[key] is not None:
                    self.values[key].append(result[key])
        ratio = result.get("max_bound_ratio")
        if ratio is not None and not math.isnan(ratio):
            self.ratios += 1
            self.ratios_at_start += result.get("max_bound_ratio_step") == 1
            if self.worst is None or ratio > self.worst[0]:
                self.worst = (ratio, row, result.get("bound_respected"), result.get("max_bound_ratio_step"))
        self.violations += result.get("bound_respected") is False
        for gain in ("noise_gain", "noise_gain_w"):                   # sensor noise, process noise
            ratio = result.get(f"{gain}_ratio")
            worse = self.worst_noise is None or (ratio is not None and ratio > self.worst_noise[0])
            if ratio is not None and not math.isnan(ratio) and worse:
                self.worst_noise = (ratio, row, result.get(f"{gain}_respected"))
            self.noise_violations += result.get(f"{gain}_respected") is False
        if result.get("noise_std_norm") is not None and result.get("noise_rms_error") is not None:
            self.noise_pairs[0].append(result["noise_std_norm"])
            self.noise_pairs[1].append(result["noise_rms_error"])
        if self.mismatch and mismatch is not None and result.get("error_floor") is not None:
            self.mismatch_pairs[0].append(mismatch)
            self.mismatch_pairs[1].append(result["error_floor"])

    def _failure(self, row: int, result: dict) -> None:
        kind = (result["status"], reason_kind(result["reason"]))
        entry = self.reasons.get(kind)
        if entry is None:
            if len(self.reasons) >= MAX_REASONS:
                self.other_reasons += 1
                return
            entry = self.reasons[kind] = {"kind": kind[1], "status": result["status"], "count": 0,
                                          "example": result["reason"], "rows": []}
        entry["count"] += 1
        if len(entry["rows"]) < 20:
            entry["rows"].append(row)

    def quantiles(self) -> dict:
        """Per figure: its count, the runs without it (``never`` reached 1 %, or ``missing``), and the
        quantiles and mean of its finite values (``non_finite`` counts the others, when there are)."""
        out = {}
        for key in self.keys:
            if not self.present[key]:
                continue
            values = np.frombuffer(self.values[key], dtype=float)
            finite = values[np.isfinite(values)]
            entry = {"count": len(values), "never" if key in ("steps_to_1pct", "time_to_1pct") else "missing":
                     self.present[key] - len(values)}
            if len(finite) < len(values):
                entry["non_finite"] = len(values) - len(finite)
            if finite.size:
                entry.update({f"q{int(round(q * 100)):02d}": float(np.quantile(finite, q)) for q in QUANTILES})
                entry["mean"] = float(np.mean(finite))
            out[key] = entry
        return out


def summary(campaign: Campaign, setup: Setup, tally: Tally, cancelled: bool = False,
            elapsed: float | None = None, workers: int | None = None, startup_s: float | None = None) -> dict:
    """``summary.json``: runs, failures and their reasons by kind, the worst bound ratio with its row,
    step and scenario (``every_run_at_bound_start``: every run's largest ratio is at k = 1, the first
    step it is measured at, so the worst row stands out by that step alone), with a ``noise_y`` axis the
    worst measured-over-certified noise gain ratio with its row and scenario (``worst_noise_gain_ratio``)
    and the runs whose certified noise gain failed, quantiles of the convergence and error figures;
    ``elapsed_s`` and ``runs_per_s`` count from the
    cluster's start (``cluster_startup_s`` before it) to the last row."""
    ranked = sorted(tally.reasons.values(), key=lambda e: -e["count"])
    out = {"campaign": str(campaign.path), "observer": setup.name, "runs": campaign.runs,
           "finished": tally.finished, "ok": tally.ok, "failures": tally.finished - tally.ok,
           "failure_reasons": ranked[:50], "cancelled": cancelled, "seed": campaign.seed, "t_end": setup.t_end}
    if tally.other_reasons:
        out["failures_of_other_reasons"] = tally.other_reasons
    if tally.worst is not None:
        value, row, respected, step = tally.worst
        out["worst_max_bound_ratio"] = {"value": value, "row": row, "step": step,
                                        "scenario": scenario(campaign, setup, row), "bound_respected": respected,
                                        "every_run_at_bound_start": tally.ratios_at_start == tally.ratios}
        out["bound_violations"] = tally.violations
    else:
        out["worst_max_bound_ratio"] = None
    if campaign.noise_y is not None or campaign.quantization is not None or campaign.noise_w is not None:
        worst = tally.worst_noise
        out["worst_noise_gain_ratio"] = None if worst is None else {
            "value": worst[0], "row": worst[1], "scenario": scenario(campaign, setup, worst[1]),
            "noise_gain_respected": worst[2]}
        out["noise_gain_violations"] = tally.noise_violations
    out["quantiles"] = tally.quantiles()
    if elapsed is not None:
        out["elapsed_s"] = elapsed
        out["runs_per_s"] = tally.finished / elapsed if elapsed > 0 else None
    if startup_s is not None:
        out["cluster_startup_s"] = startup_s
    if workers is not None:
        out["workers"] = workers
    out["axes"] = {"steps": list(campaign.steps or (setup.default_steps,)),
                   **{name: axis.describe() for name, axis in campaign.named_axes()}}
    return out


__all__ = ["MAX_REASONS", "MISMATCH_KEYS", "QUANTILES", "QUANTILE_KEYS", "Tally", "reason_kind", "summary"]
