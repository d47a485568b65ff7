"""``campaign.png``: the distributions of a campaign's convergence time and bound ratio, and its
worst run against its certified bound."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...runtime.files import atomic_output
from .tally import Tally


def _hist(ax, values, color, marks: tuple = ()) -> int:
    """A histogram of the finite values, its axis in plain numbers (no offset such as ``1e-6+1``); values
    all (nearly) equal give one bar, wide enough to see beside the ``marks`` (x positions the caller
    draws), ticked at its value and annotated with the spread. How many values it drew."""
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    if not values.size:
        return 0
    lo, hi = float(values.min()), float(values.max())
    pad = max(abs(hi) * 1e-6, 1e-12)
    if hi - lo < pad:
        far = [m for m in marks if abs(m - lo) > pad]
        pad = max([pad] + [0.02 * abs(m - lo) for m in far])
        ax.hist(values, bins=1, range=(lo - pad, hi + pad), color=color)
        ax.set_xticks([lo, *far])
        ax.set_xticklabels([f"{x:.6g}" for x in (lo, *far)])
        same = f"all {values.size} at {lo:.10g}" if lo == hi else \
            f"all {values.size} within {hi - lo:.1e} of {lo:.10g}"
        ax.annotate(same, (0.5, 0.5), xycoords="axes fraction", ha="center", color="black",
                    bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none"})
    else:
        ax.hist(values, bins=min(40, max(5, len(values) // 5)), range=(lo, hi), color=color)
        ax.ticklabel_format(axis="x", style="plain", useOffset=False)
    return values.size


def _plot_noise(ax, tally: Tally) -> None:
    """The error of each run with sensor noise (rms over its second half) against its noise level."""
    level, error = (np.frombuffer(a, dtype=float) for a in tally.noise_pairs)
    ax.loglog(np.maximum(level, 1e-300), np.maximum(error, 1e-300), ".", alpha=0.6)
    ax.set_xlabel("sensor noise std ||sigma||")
    ax.set_ylabel("rms error with noise (second half)")
    ax.set_title(f"error against the noise level ({len(level)} noisy run(s); "
                 f"{tally.noise_violations} above the certified gain)", fontsize=10)
    ax.grid(alpha=0.3, which="both")


def _plot_mismatch(ax, tally: Tally) -> None:
    """The error each run settles at (its error floor) against its plant's relative mismatch."""
    level, floor = (np.frombuffer(a, dtype=float) for a in tally.mismatch_pairs)
    ax.semilogy(level, np.maximum(floor, 1e-300), ".", alpha=0.6)
    ax.set_xlabel("plant mismatch (relative std of A, B, E)")
    ax.set_ylabel("error floor (median ||e_k|| over the last fifth)")
    ax.set_title(f"error against the mismatch ({len(level)} run(s))", fontsize=10)
    ax.grid(alpha=0.3, which="both")


def plot_campaign(tally: Tally, worst_result, worst: dict | None, path, title: str = "") -> Path:
    """``campaign.png``: distributions of the convergence time and of the bound ratio (their finite
    values), the worst run's error against its certified bound, with sensor noise each noisy run's
    error against its noise level, and with a ``plant_mismatch`` axis each run's error floor against its
    mismatch.

    Parameters
    ----------
    tally : Tally
        The finished rows.
    worst_result : uiofmu.cosim.result.CosimResult or None
        The worst run, re-run.
    worst : dict or None
        The summary's ``worst_max_bound_ratio``.
    path : str or Path
        The PNG file (written atomically).
    title : str

    Returns
    -------
    Path
    """
    from ..report import pyplot

    plt = pyplot()[0]
    noisy, mismatched = len(tally.noise_pairs[0]) > 0, len(tally.mismatch_pairs[0]) > 0
    panels = 3 + noisy + mismatched
    fig, axes = plt.subplots(1, panels, figsize=(5 * panels, 4.2))
    if noisy:
        _plot_noise(axes[3], tally)
    if mismatched:
        _plot_mismatch(axes[-1], tally)
    conv = tally.values["time_to_1pct"]
    never = tally.present["time_to_1pct"] - len(conv)
    ax = axes[0]
    drawn = _hist(ax, conv, "tab:blue")
    ax.set_xlabel("time to 1 % of the initial error [s]")
    ax.set_ylabel("runs")
    ax.set_title(f"convergence: {drawn} run(s) under 1 %" + (f", {never} not within the run" if never else ""))
    ax = axes[1]
    if _hist(ax, tally.values["max_bound_ratio"], "tab:green", marks=(1.0,)):
        ax.axvline(1.0, color="tab:red", linestyle="--", label="bound")
        ax.legend()
    ax.set_xlabel("max over k >= 1 of ||e_k|| / certified bound_k")
    ax.set_title(f"bound ratio ({tally.finished - tally.ok} failed run(s))")
    ax = axes[2]
    if worst_result is not None:
        err = np.linalg.norm(worst_result.x - worst_result.xhat, axis=1)
        ax.semilogy(worst_result.times, np.maximum(err, 1e-300), label="||e_k||")
        if worst_result.bound is not None:
            ax.semilogy(worst_result.times, np.maximum(worst_result.bound, 1e-300), "--", label="certified bound")
        ax.legend()
        if worst.get("every_run_at_bound_start"):
            ax.set_title(f"every run nearest its bound at k = 1 (ratio up to {worst['value']:.4g}); row {worst['row']}",
                         fontsize=10)
        else:
            ax.set_title(f"worst run: row {worst['row']} (ratio {worst['value']:.4g} at k = {worst['step']})")
    else:
        ax.set_title("worst run: none with a bound")
    ax.set_xlabel("time [s]")
    fig.suptitle(title)
    fig.tight_layout()
    try:
        with atomic_output(path, "campaign figure") as part:
            fig.savefig(part, format="png", dpi=90)
    finally:
        plt.close(fig)
    return Path(path)


__all__ = ["plot_campaign"]
