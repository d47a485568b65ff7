"""The co-simulation report: one figure a person understands at a glance."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..runtime.errors import ProblemError
from ..runtime.files import atomic_output


def pyplot():
    """matplotlib's pyplot on the Agg backend (no display needed) and the colours of its property cycle.

    Returns
    -------
    plt : module
        ``matplotlib.pyplot``.
    colors : list of str
        The colours of ``axes.prop_cycle``, in order.
    """
    try:
        import matplotlib
    except ValueError as exc:               # matplotlib validates MPLBACKEND (and matplotlibrc) on import
        raise ProblemError(f"matplotlib refuses its settings ({str(exc)[:160]}): unset MPLBACKEND or fix the "
                           "matplotlibrc (uiofmu draws with Agg whatever it says)") from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt, plt.rcParams["axes.prop_cycle"].by_key()["color"]


def _panels(plt, rows: int, cols: int, figsize: tuple, shade):
    """A figure of panels over one shared time axis, each shaded by ``shade`` and gridded.

    Parameters
    ----------
    plt : module
        ``matplotlib.pyplot``.
    rows, cols : int
        The panels' layout.
    figsize : tuple of float
        The figure's size in inches.
    shade : callable
        ``shade(ax)`` draws the stretches to shade on one panel (before anything else is drawn).

    Returns
    -------
    fig : Figure
    axes : ndarray of Axes
    """
    fig, axes = plt.subplots(rows, cols, figsize=figsize, sharex=True, constrained_layout=True)
    for ax in axes.flat:
        shade(ax)
        ax.grid(alpha=0.3)
    return fig, axes


def _plot_states(ax, t, result, colors, title: str) -> None:
    """The true states (solid) and their estimates (dashed) in one colour per component.

    Parameters
    ----------
    ax : Axes
    t : ndarray
        The time axis.
    result : CosimResult
        Its ``x`` and ``xhat`` are drawn.
    colors : list of str
        The colours, cycled over the components.
    title : str
        The panel's title.
    """
    for i in range(result.x.shape[1]):
        c = colors[i % len(colors)]
        ax.plot(t, result.x[:, i], color=c, lw=1.6, label=f"x[{i + 1}]")
        ax.plot(t, result.xhat[:, i], color=c, lw=1.2, ls="--", label=f"xhat[{i + 1}]")
    ax.set_title(title)
    ax.legend(ncol=2, fontsize=8)


def _save(plt, fig, path, title: str | None) -> Path:
    """Title the figure, write it as ``path`` (a PNG, atomically) and close it.

    Parameters
    ----------
    plt : module
        ``matplotlib.pyplot``.
    fig : Figure
    path : str or Path
    title : str or None
        The figure's title (none when empty).

    Returns
    -------
    Path
        ``path``.
    """
    _thin_lines(fig)
    if title:
        fig.suptitle(title)
    path = Path(path)
    with atomic_output(path, "report") as part:
        fig.savefig(part, dpi=110, format="png")
    plt.close(fig)
    return path


#: The most points a line of the report draws; a longer line (a long run) is thinned to about this many
#: (the axes keep the limits of the full data), a shorter one is drawn as it is.
MAX_POINTS = 5000


def _thin_lines(fig, limit: int = MAX_POINTS) -> None:
    """Thin every line of ``fig`` with more than ``limit`` points: a line keeps, in each of ``limit / 4``
    runs of consecutive points, its first, lowest, highest and last (so peaks and steps stay where they
    are); markers without a line keep evenly spaced points."""
    for ax in fig.axes:
        for line in ax.get_lines():
            x, y = np.asarray(line.get_xdata(), dtype=float), np.asarray(line.get_ydata(), dtype=float)
            if x.ndim != 1 or x.shape != y.shape or x.size <= limit:
                continue
            if line.get_linestyle() in ("None", "", " "):
                keep = np.unique(np.linspace(0, x.size - 1, limit).round().astype(int))
            else:
                edges = np.linspace(0, x.size, limit // 4 + 1).round().astype(int)
                picks = []
                for a, b in zip(edges[:-1], edges[1:]):
                    run = y[a:b]
                    finite = np.isfinite(run)
                    picks.append(a)
                    if finite.any():
                        picks += [a + int(np.argmin(np.where(finite, run, np.inf))),
                                  a + int(np.argmax(np.where(finite, run, -np.inf)))]
                    picks.append(b - 1)
                keep = np.unique(picks)
            line.set_data(x[keep], y[keep])


def plot_report(result, path, title: str | None = None) -> Path:
    """Write ``report.png``: states and estimates, error norm against the certified bound,
    the communication steps used, and the unknown input against its estimate.

    Parameters
    ----------
    result : CosimResult
    path : str or Path
    title : str, optional

    Returns
    -------
    Path
    """
    if result.functional is not None:
        return plot_functional(result, path, title)
    if result.delayed is not None:
        return plot_delayed(result, path, title)
    plt, colors = pyplot()
    m = result.metrics
    scale, unit = (3600.0, "h") if result.times[-1] > 4 * 3600 else (1.0, "s")
    t = result.times / scale
    fig, axes = plt.subplots(2, 2, figsize=(12, 7.5), constrained_layout=True)
    ax = axes[0, 0]
    _plot_states(ax, t, result, colors, "true state (solid) and estimate (dashed)")
    ax.set_xlabel(f"time [{unit}]")
    ax.grid(alpha=0.3)

    ax = axes[0, 1]
    norms = np.linalg.norm(result.x - result.xhat, axis=1)
    floor = max(norms[0], 1e-300) * 1e-16
    ax.semilogy(t, np.maximum(norms, floor), lw=1.5, label="measured ||x - xhat||")
    if result.bound is not None:
        ok = ("respected at every step" if m["bound_respected"] else
              f"exceeded from step {m['first_bound_violation']}; the error settles at {m['error_floor']:.1e}")
        ax.semilogy(t, np.maximum(result.bound, floor), "k--", lw=1.2,
                    label=f"certified bound (δ = {m['certified_decay']:.4g}): {ok}")
    ax.axhline(0.01 * norms[0], color="gray", ls=":", lw=1, label="1 % of initial error")
    if m.get("steps_to_1pct") is not None:
        ax.axvline(t[m["steps_to_1pct"]], color="gray", lw=0.8)
    ax.set_title("estimation error")
    ax.set_xlabel(f"time [{unit}]")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, which="both")

    ax = axes[1, 0]
    if result.mode is not None:
        modes = result.mode[:-1]
        ax.step(t[:-1], modes, where="post", lw=1.2)
        ax.set_yticks(np.unique(modes))
        ax.set_title(f"mode of each step ({m['modes']['switches']} switches; {len(result.h)} steps of "
                     f"{result.h.min():.4g} s)")
        ax.set_ylabel("alpha_k")
    else:
        ax.step(t[:-1], result.h, where="post", lw=1.2)
        ax.set_title(f"communication steps ({len(result.h)} steps, h in [{result.h.min():.4g}, "
                     f"{result.h.max():.4g}] s)")
        ax.set_ylabel("h_k [s]")
    ax.set_xlabel(f"time [{unit}]")
    ax.grid(alpha=0.3)

    ax = axes[1, 1]
    if result.dhat.size and result.dhat.shape[1]:
        for i in range(result.d.shape[1]):
            c = colors[i % len(colors)]
            ax.step(t, result.d[:, i], where="post", color=c, lw=1.6, label=f"d[{i + 1}] (held over step)")
            ax.plot(t[:-1], result.dhat[1:, i], ".", color=c, ms=3, label=f"dhat[{i + 1}] (drawn at its step's start)")
        ax.set_title("unknown input and its estimate")
    else:
        for i in range(result.r.shape[1]):
            ax.plot(t, result.r[:, i], lw=1.2, label=f"r[{i + 1}]")
        ax.set_title("output residual r = y - C xhat")
    ax.set_xlabel(f"time [{unit}]")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return _save(plt, fig, path, title)


def plot_functional(result, path, title: str | None = None) -> Path:
    """``report.png`` of a functional observer: the functional and its estimate (the window-filling
    steps shaded), the error on a log scale with the first exact step, and the inputs.

    Parameters
    ----------
    result : CosimResult
        With ``functional`` (``gx``, ``true``, ``valid``).
    path : str or Path
    title : str, optional

    Returns
    -------
    Path
    """
    plt, colors = pyplot()
    m, f = result.metrics, result.functional
    k = np.arange(len(result.times))
    filling = m["valid_from"] if m["valid_from"] is not None else len(k)
    fig, axes = _panels(plt, 3, 1, (10, 8.5), lambda ax: ax.axvspan(-0.5, filling - 0.5, color="0.9", lw=0))
    ax = axes[0]
    for i in range(f["gx"].shape[1]):
        c = colors[i % len(colors)]
        ax.plot(k, f["true"][:, i], color=c, lw=1.6, label=f"(G x)[{i + 1}] at k - {m['delay']}")
        ax.plot(k, np.where(f["valid"] > 0.5, f["gx"][:, i], np.nan), "o", color=c, ms=3, mfc="none",
                label=f"gx[{i + 1}]")
    ax.set_title(f"the functional and its estimate (window of {m['window']} outputs, delay {m['delay']}; "
                 f"shaded: window filling)")
    ax.legend(fontsize=8, ncol=2)
    ax = axes[1]
    err = np.linalg.norm(f["gx"] - f["true"], axis=1)
    ax.semilogy(k, np.maximum(err, 1e-18), ".-", lw=1)
    exact = m["steps_to_exact"]
    if exact is not None:
        ax.axvline(exact, color="k", ls="--", lw=1, label=f"exact (round-off) from step {exact}")
        ax.legend(fontsize=8)
    ax.set_title("error |gx - G x| (0 drawn at 1e-18)")
    ax = axes[2]
    for i in range(result.d.shape[1]):
        ax.step(k, result.d[:, i], where="post", lw=1.2, label=f"d[{i + 1}] (unknown)")
    for i in range(result.y.shape[1]):
        ax.plot(k, result.y[:, i], lw=1, label=f"y[{i + 1}]")
    ax.set_title("inputs and outputs")
    ax.set_xlabel("step k")
    ax.legend(fontsize=8, ncol=3)
    return _save(plt, fig, path, title)


def _shade_invalid(ax, t, valid) -> None:
    """Shade the stretches of ``t`` where ``valid`` is 0 (each point's stretch runs to the next point)."""
    bad = np.asarray(valid) < 0.5
    edges = np.flatnonzero(np.diff(np.concatenate([[0], bad.astype(int), [0]])))
    for a, b in zip(edges[::2], edges[1::2]):
        ax.axvspan(t[a], t[min(b, len(t) - 1)], color="0.88", lw=0, zorder=0)


def plot_delayed(result, path, title: str | None = None) -> Path:
    """``report.png`` of a delayed observer with parameter identification (seed 001): states and
    estimates, the state error, the rank margin ``sigma_min`` against the card's premise bound, and
    ``thetahat`` against the true ``theta``; the stretches where the observer says its estimates are not
    valid (start-up, margin below the bound) shaded in every panel.

    Parameters
    ----------
    result : CosimResult
        With ``delayed`` (``thetahat``, ``theta``, ``sigma_min``, ``valid``, ``sigma_bound``).
    path : str or Path
    title : str, optional

    Returns
    -------
    Path
    """
    plt, colors = pyplot()
    m, dl = result.metrics, result.delayed
    t, valid = result.times, dl["valid"]
    v = m["validity"]
    fig, axes = _panels(plt, 2, 2, (12, 8), lambda ax: _shade_invalid(ax, t, valid))
    _plot_states(axes[0, 0], t, result, colors, "true state (solid) and estimate (dashed); shaded: not valid")

    ax = axes[0, 1]
    norms = np.linalg.norm(result.x - result.xhat, axis=1)
    floor = max(float(norms.max()), 1e-300) * 1e-9
    ax.semilogy(t, np.maximum(norms, floor), lw=1.5, label=f"measured ||x - xhat|| (below {floor:.1e} drawn there)")
    ax.set_title("state error (no certified bound: it holds on the premise set only)")
    ax.legend(fontsize=8)

    ax = axes[1, 0]
    sig = np.asarray(dl["sigma_min"], dtype=float)
    low = dl["sigma_bound"] * 1e-3
    ax.semilogy(t, np.maximum(sig, low), lw=1.3, label=f"sigma_min(C D_y) at run time (below {low:.1e} drawn there)")
    ax.set_ylim(bottom=low / 2)
    ax.axhline(dl["sigma_bound"], color="k", ls="--", lw=1.2, label=f"premise bound {dl['sigma_bound']:.3g}")
    ax.set_title(f"rank margin; valid {100 * v['fraction']:.1f} % of the run, from t = "
                 + (f"{v['first_valid_time']:g} s" if v["first_valid_time"] is not None else "never"))
    ax.set_xlabel("time [s]")
    ax.legend(fontsize=8)

    ax = axes[1, 1]
    th = dl["thetahat"]
    for i in range(th.shape[1]):
        c = colors[i % len(colors)]
        if dl["theta"] is not None:
            ax.axhline(dl["theta"][i], color=c, lw=1.6, label=f"theta[{i + 1}] = {dl['theta'][i]:.4g} (plant)")
        ax.plot(t, th[:, i], color=c, lw=1.1, ls="--", label=f"thetahat[{i + 1}]")
    if dl["theta"] is not None:             # transients while the observer starts may be far off: keep theta in view
        mid, spread = float(np.mean(dl["theta"])), float(np.ptp(dl["theta"])) + float(np.max(np.abs(dl["theta"])))
        ax.set_ylim(mid - 2 * spread, mid + 2 * spread)
    tm = m.get("theta")
    if tm is not None:
        when = f"within 1 % from t = {tm['time_to_1pct']:g} s" if tm["time_to_1pct"] is not None else "never within 1 %"
        ax.set_title(f"parameters: {when}, final relative error {tm['final_relative_error']:.2g}")
    else:
        ax.set_title("parameter estimate (the plant has no parameter theta to compare with)")
    ax.set_xlabel("time [s]")
    ax.legend(fontsize=8, ncol=2)
    return _save(plt, fig, path, title)
