"""Convergence metrics of a co-simulation, and the comparison with the certified bound."""

from __future__ import annotations

import numpy as np

#: Relative slack of the bound comparison (round-off of the plant and observer steps).
BOUND_RTOL = 1e-9


def settling_index(norms: np.ndarray, fraction: float) -> int | None:
    """First index from which ``norms`` stays at or below ``fraction * norms[0]`` (None if never)."""
    if norms.size == 0:
        return None
    above = np.flatnonzero(norms > fraction * norms[0])
    if above.size == 0:
        return 0
    k = int(above[-1]) + 1
    return k if k < norms.size else None


def bound_ratio_step(ratio: np.ndarray) -> int:
    """The step k >= 1 of the largest ratio of the error to its bound (the first of equal ones; 0 for a
    run without steps): at k = 0 the bound is ``M ||e_0||`` and the ratio ``1 / M`` by construction (1
    with an overshoot of 1), which says nothing of the run."""
    return int(np.argmax(ratio[1:])) + 1 if ratio.size > 1 else 0


def allowance(bound: np.ndarray, rtol: float, floor: float) -> np.ndarray:
    """What the bound check allows at each point: ``bound_k (1 + rtol) + floor`` (``floor = rtol ||e_0||``,
    the round-off floor), the one formula of the check, the report's dotted line and its slack."""
    return bound * (1 + rtol) + floor


def error_metrics(times: np.ndarray, steps: np.ndarray, x: np.ndarray, xhat: np.ndarray,
                  bound: np.ndarray | None = None, decay: float | None = None, overshoot: float | None = None,
                  d: np.ndarray | None = None, dhat: np.ndarray | None = None,
                  bound_rtol: float = BOUND_RTOL, roundoff: dict | None = None) -> dict:
    """The SPEC metrics of one run.

    Parameters
    ----------
    times : (K+1,) array
        Communication points t_0..t_K.
    steps : (K,) array
        Step lengths h_0..h_{K-1}.
    x, xhat : (K+1, n) arrays
        True state and estimate at each point.
    bound : (K+1,) array, optional
        The certified bound on ``||e_k||`` for this run (see
        :func:`uiofmu.families.certified_bound`).
    decay, overshoot : float, optional
        The certified asymptotic ``delta`` and ``M``, reported alongside.
    d, dhat : (K+1, q) arrays, optional
        Unknown input applied over ``[t_k, t_{k+1})`` and its estimate at ``t_k`` (which
        estimates the input over the previous step).
    bound_rtol : float
        Relative slack of the bound comparison: ``||e_k|| <= bound_k (1 + rtol) + rtol ||e_0||``
        (the last term, the round-off floor, admits round-off once the error is down at ``rtol`` of
        where it began: a certified bound is one of exact arithmetic, and falls below what a run in
        double precision can reach); ``max_bound_ratio`` is the largest ratio of the error to that
        allowance.
    roundoff : dict, optional
        The run's leaks against the card's error recursion (:func:`uiofmu.cosim.roundoff.roundoff_floor`):
        when they are round-off, the floor grows by ``(1 + rtol) carried`` (the largest leak carried by the
        certified decay), so a correct observer in double precision is not reported as violating its
        bound; ``roundoff_floor`` reports them either way.

    Returns
    -------
    dict
        ``steps``, ``initial_error_norm``, ``final_error_norm``, ``rms_error`` (per state),
        ``steps_to_1pct``, ``time_to_1pct``, and when certified ``certified_decay``,
        ``certified_overshoot``, ``bound_respected``, ``max_bound_ratio`` (from k = 1 on) and the step
        it is at, ``max_bound_ratio_step`` (:func:`bound_ratio_step`), ``first_bound_violation``,
        ``bound_rtol``, ``bound_floor`` (``rtol ||e_0||``, plus the carried leaks when they are round-off)
        and ``points_on_floor`` (the points where the error exceeds the bound itself and is accepted only
        as round-off below the floor), ``roundoff_floor`` (with ``roundoff``); ``dhat_rms_error`` with an
        unknown-input estimate.
    """
    e = x - xhat
    norms = np.linalg.norm(e, axis=1)
    k1 = settling_index(norms, 0.01)
    out = {
        "steps": int(len(steps)),
        "t_end": float(times[-1]),
        "initial_error_norm": float(norms[0]),
        "final_error_norm": float(norms[-1]),
        "rms_error": np.sqrt(np.mean(e * e, axis=0)).tolist(),
        "max_error_norm": float(norms.max()),
        "error_floor": float(np.median(norms[-max(1, len(norms) // 5):])),
        "steps_to_1pct": k1,
        "time_to_1pct": None if k1 is None else float(times[k1]),
        "step_min": float(steps.min()) if steps.size else None,
        "step_max": float(steps.max()) if steps.size else None,
    }
    if bound is not None:
        floor = bound_rtol * norms[0]
        if roundoff is not None and roundoff["roundoff"]:
            floor += (1 + bound_rtol) * roundoff["carried"]
        slack = allowance(bound, bound_rtol, floor)
        with np.errstate(over="ignore", divide="ignore"):
            ratio = np.divide(norms, slack, out=np.zeros_like(norms), where=slack > 0)
        bad = np.flatnonzero(norms > slack)
        worst = bound_ratio_step(ratio)
        out.update({"certified_decay": decay, "certified_overshoot": overshoot,
                    "bound_respected": bool(bad.size == 0), "max_bound_ratio": float(ratio[worst]),
                    "max_bound_ratio_step": worst,
                    "first_bound_violation": int(bad[0]) if bad.size else None,
                    "error_at_first_violation": float(norms[bad[0]]) if bad.size else None,
                    "bound_at_first_violation": float(bound[bad[0]]) if bad.size else None,
                    "final_bound": float(bound[-1]), "bound_rtol": bound_rtol, "bound_floor": float(floor),
                    "points_on_floor": int(np.count_nonzero((norms > bound * (1 + bound_rtol)) & (norms <= slack)))})
        if roundoff is not None:
            out["roundoff_floor"] = dict(roundoff)
    if d is not None and dhat is not None and dhat.size and len(d) > 1:
        err = dhat[1:] - d[:-1]
        out["dhat_rms_error"] = np.sqrt(np.mean(err * err, axis=0)).tolist()
        half = len(err) // 2
        out["dhat_rms_error_second_half"] = np.sqrt(np.mean(err[half:] ** 2, axis=0)).tolist()
    return out


def mode_metrics(mode: np.ndarray) -> dict:
    """The modes of a switched run: ``switches`` and ``steps_in_mode`` (by mode, as text).

    Parameters
    ----------
    mode : (K+1,) array
        The mode at each communication point; the last point starts no step and is not counted.

    Returns
    -------
    dict
    """
    steps = np.asarray(mode)[:-1]
    return {"switches": int(np.count_nonzero(np.diff(steps))),
            "steps_in_mode": {str(int(i)): int(np.count_nonzero(steps == i)) for i in np.unique(steps)}}


def functional_metrics(times: np.ndarray, steps: np.ndarray, gx: np.ndarray, true: np.ndarray, valid: np.ndarray,
                       delay: int, window: int, rtol: float = 1e-9) -> dict:
    """The metrics of a functional observer (window kernel): when its output becomes exact.

    Parameters
    ----------
    times, steps : arrays
        Communication points and step lengths.
    gx : (K+1, d) array
        The observer's ``gx`` at each point.
    true : (K+1, d) array
        ``G x`` of the point ``delay`` steps back (NaN where there is none).
    valid : (K+1,) array
        The observer's ``gx_valid``.
    delay, window : int
        From the card.
    rtol : float
        ``gx`` is exact at a point when ``|gx - G x| <= rtol * max(1, |G x|)`` (round-off).

    Returns
    -------
    dict
        ``steps``, ``t_end``, ``window``, ``delay``, ``valid_from`` (first point with ``gx_valid``),
        ``steps_to_exact`` (first point from which ``gx`` stays exact; None if never),
        ``exact_from_first_full_window``, ``max_error_norm`` and ``final_error_norm`` (where valid),
        ``max_relative_error_when_valid``.
    """
    err = np.linalg.norm(gx - true, axis=1)
    scale = np.maximum(1.0, np.linalg.norm(np.nan_to_num(true), axis=1))
    ok = (valid > 0.5) & (err <= rtol * scale)
    bad = np.flatnonzero(~ok)
    exact = (int(bad[-1]) + 1 if bad.size else 0)
    exact = exact if exact < len(ok) else None
    on = np.flatnonzero(valid > 0.5)
    valid_from = int(on[0]) if on.size else None
    rel = err[on] / scale[on] if on.size else np.zeros(0)
    return {
        "steps": int(len(steps)), "t_end": float(times[-1]), "window": int(window), "delay": int(delay),
        "valid_from": valid_from, "steps_to_exact": exact,
        "exact_from_first_full_window": exact is not None and exact == valid_from,
        "max_error_norm": float(np.nanmax(err)) if np.isfinite(err).any() else None,
        "final_error_norm": float(err[-1]),
        "max_relative_error_when_valid": float(rel.max()) if rel.size else None,
        "step_min": float(steps.min()) if steps.size else None,
        "step_max": float(steps.max()) if steps.size else None,
    }


def _stretches(flag: np.ndarray, times: np.ndarray) -> list:
    """The maximal runs of points where ``flag`` holds, as ``[first time, last time]`` pairs."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], flag.astype(int), [0]])))
    return [[float(times[a]), float(times[b - 1])] for a, b in zip(edges[::2], edges[1::2])]


#: Most invalid stretches listed in ``metrics.json`` (their count is always given).
MAX_STRETCHES = 20


def delayed_metrics(times: np.ndarray, steps: np.ndarray, x: np.ndarray, xhat: np.ndarray, thetahat: np.ndarray,
                    theta: np.ndarray | None, valid: np.ndarray, sigma_min: np.ndarray, sigma_bound: float,
                    bound_text: str = "") -> dict:
    """The metrics of a delayed observer with parameter identification (seed 001).

    Parameters
    ----------
    times, steps : arrays
        Communication points t_0..t_K and step lengths h_0..h_{K-1}.
    x, xhat : (K+1, n) arrays
        True state and estimate.
    thetahat : (K+1, n_theta) array
        The observer's ``thetahat`` at each point (held while not valid).
    theta : (n_theta,) array or None
        The true parameters, read from the plant FMU's parameter ``theta`` (None: the plant has none,
        and there are no theta metrics).
    valid : (K+1,) array
        The observer's ``valid`` (1 or 0).
    sigma_min : (K+1,) array
        The observer's run-time rank margin ``sigma_min(C D_y)``.
    sigma_bound : float
        The card's premise bound on it (``schedule.sigma_bound``).
    bound_text : str
        The card's ``bound`` (a statement about the premise set).

    Returns
    -------
    dict
        ``validity``: ``fraction`` (of the run's time during which the estimates were valid, each step
        counted as valid when it starts valid), ``points_valid``, ``first_valid_point`` and
        ``first_valid_time`` (None if never), the ``invalid_stretches`` after the first valid point
        (count and up to :data:`MAX_STRETCHES` ``[from, to]`` time pairs), ``sigma_bound`` and the smallest
        ``sigma_min`` after start-up; ``state_from_first_valid``: the state error at the first valid point
        and the time from which it stays below 1 % of it; ``theta`` (with a true theta): ``true``,
        ``final``, ``final_error_norm``, ``final_relative_error``, ``time_to_1pct`` and ``steps_to_1pct``
        (the first valid point from which every valid point has ``||thetahat - theta|| <= 0.01 ||theta||``;
        None if the last valid point does not), ``max_error_norm_when_valid``, ``rms_error_when_valid``;
        ``certified_bound``: a sentence saying that no bound is compared, and why.
    """
    ok = np.asarray(valid) > 0.5
    on = np.flatnonzero(ok)
    first = int(on[0]) if on.size else None
    weights = np.asarray(steps, dtype=float)
    total = float(weights.sum())
    fraction = float(weights[ok[:-1]].sum() / total) if total > 0 else float(ok.mean())
    after = slice(first, None) if first is not None else slice(0, 0)
    invalid = _stretches(~ok[after], times[after]) if first is not None else []
    started = times >= (times[first] if first is not None else np.inf)
    out = {"validity": {
        "fraction": fraction, "points_valid": int(ok.sum()), "points": int(ok.size),
        "first_valid_point": first, "first_valid_time": None if first is None else float(times[first]),
        "invalid_stretches": len(invalid), "invalid_stretch_times": invalid[:MAX_STRETCHES],
        "sigma_bound": float(sigma_bound),
        "sigma_min_after_start": float(np.min(sigma_min[started])) if started.any() else None}}
    norms = np.linalg.norm(x - xhat, axis=1)
    if first is not None:
        k = settling_index(norms[first:], 0.01)
        out["state_from_first_valid"] = {"error_norm": float(norms[first]),
                                         "steps_to_1pct": None if k is None else first + k,
                                         "time_to_1pct": None if k is None else float(times[first + k])}
    if theta is not None:
        theta = np.asarray(theta, dtype=float)
        err = np.linalg.norm(thetahat - theta, axis=1)
        scale = float(np.linalg.norm(theta))
        good = ok & (err <= 0.01 * scale)
        bad = np.flatnonzero(ok & ~good)
        k1 = None
        if on.size and good[on[-1]]:
            later = on[on > bad[-1]] if bad.size else on
            k1 = int(later[0])
        out["theta"] = {
            "true": theta.tolist(), "true_from": "the plant FMU's parameter theta (the observer never reads it)",
            "final": thetahat[-1].tolist(), "final_error_norm": float(err[-1]),
            "final_relative_error": float(err[-1] / scale) if scale > 0 else None,
            "steps_to_1pct": k1, "time_to_1pct": None if k1 is None else float(times[k1]),
            "max_error_norm_when_valid": float(err[ok].max()) if on.size else None,
            "rms_error_when_valid": np.sqrt(np.mean((thetahat[ok] - theta) ** 2, axis=0)).tolist() if on.size else None}
    out["certified_bound"] = ("none for this family: the design's bound holds on the premise set only (trajectories "
                              "whose Gamma stays in the premise grid's set), which a run is not known to stay in, so "
                              "no run is compared with it" + (f"; the card says: {bound_text}" if bound_text else ""))
    return out
