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


def error_metrics(times: np.ndarray, steps: np.ndarray, x: np.ndarray, xhat: np.ndarray,
                  bound: np.ndarray | None = None, decay: float | None = None, overshoot: float | None = None,
                  d: np.ndarray | None = None, dhat: np.ndarray | None = None,
                  bound_rtol: float = BOUND_RTOL) -> dict:
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
        (the last term admits round-off once the error is down at ``rtol`` of where it began);
        ``max_bound_ratio`` is the largest ratio of the error to that allowance.

    Returns
    -------
    dict
        ``steps``, ``initial_error_norm``, ``final_error_norm``, ``rms_error`` (per state),
        ``steps_to_1pct``, ``time_to_1pct``, and when certified ``certified_decay``,
        ``certified_overshoot``, ``bound_respected``, ``max_bound_ratio``,
        ``first_bound_violation``; ``dhat_rms_error`` with an unknown-input estimate.
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
        slack = bound * (1 + bound_rtol) + bound_rtol * norms[0]
        with np.errstate(over="ignore", divide="ignore"):
            ratio = np.divide(norms, slack, out=np.zeros_like(norms), where=slack > 0)
        bad = np.flatnonzero(norms > slack)
        out.update({"certified_decay": decay, "certified_overshoot": overshoot,
                    "bound_respected": bool(bad.size == 0), "max_bound_ratio": float(ratio.max()),
                    "first_bound_violation": int(bad[0]) if bad.size else None,
                    "error_at_first_violation": float(norms[bad[0]]) if bad.size else None,
                    "bound_at_first_violation": float(bound[bad[0]]) if bad.size else None,
                    "final_bound": float(bound[-1])})
    if d is not None and dhat is not None and dhat.size and len(d) > 1:
        err = dhat[1:] - d[:-1]
        out["dhat_rms_error"] = np.sqrt(np.mean(err * err, axis=0)).tolist()
        half = len(err) // 2
        out["dhat_rms_error_second_half"] = np.sqrt(np.mean(err[half:] ** 2, axis=0)).tolist()
    return out


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
