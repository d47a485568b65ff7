"""The floating-point floor of a run's bound check: the leaks of each step carried by the certified decay.

A certified bound ``M delta^k ||e_0||`` is one of exact arithmetic: it falls without end, while a run in
double precision leaks at every step what round-off adds to the error recursion ``e_{k+1} = N_k e_k``
(``N_k`` the card's own matrix of the step). Those leaks, carried forward by the certificate itself, give
the floor the run can reach::

    leak_{k+1} = ||e_{k+1} - N_k e_k||,     carried_k = delta carried_{k-1} + M leak_k

(``||sum_j N...N leak_j|| <= sum_j M delta^(k-1-j) ||leak_j||``). They count as round-off only when every
step's leak is within :data:`LEAK_EPS` of the magnitudes that step adds up (the largest gain of the step's
matrices times the largest of ``||x||``, ``||xhat||``, ``||y||``, ``||u||``, ``||d||`` around it); a plant
other than the design model leaks far more than that, and then no floor is granted beyond the fixed one
(:func:`uiofmu.cosim.metrics.allowance`). The rule is the one the design-robustness campaign judges its
runs by (``benchmarks/design_robustness.py``).
"""

from __future__ import annotations

import numpy as np

from ..runtime.observer import Runtime
from ..runtime.schedules import StepRejected

#: A step's leak counts as round-off when it is at most this fraction of the magnitudes the step adds up
#: (about 4500 times the machine epsilon).
LEAK_EPS = 1e-12


def _largest_gain(mats: dict) -> float:
    """The largest Frobenius norm (at least the 2-norm) of a step's matrices (at least 1)."""
    norms = [float(np.sqrt(np.sum(np.square(v)))) for v in mats.values() if np.ndim(v) == 2 and np.size(v)]
    return max([1.0, *norms])


def _step_matrices(card, steps: np.ndarray, mode) -> list | None:
    """The card's step matrices of every step of the run (None where the schedule cannot give them
    from the run's steps and modes alone, or they have no ``N``).

    A schedule that gives the very same matrices for a step's ``(h, h_prev, mode, mode_prev)`` at two
    different k (a table of them) is asked once more per such key, not at every step."""
    rt = Runtime(card)
    schedule, h_prev, mode_prev = rt.schedule, rt.h_prev0, rt.mode_prev0 if mode is not None else None
    out, seen = [], {}
    try:
        for k, h in enumerate(np.asarray(steps, dtype=float).tolist()):
            m = int(mode[k]) if mode is not None else None
            key = (h, h_prev, m, mode_prev)
            known = seen.get(key)
            if known is not None and known[1]:
                mats = known[0]
            else:
                mats = schedule.step_matrices(k, h, h_prev, m, mode_prev)
                seen[key] = (mats, known is not None and known[0] is mats)
            out.append(mats)
            h_prev, mode_prev = h, m
    except (StepRejected, ValueError, TypeError, KeyError):
        return None                       # a step or mode the schedule refuses: no floor beyond the fixed one
    return out if all("N" in mats for mats in out) else None


def roundoff_floor(card, steps, x, xhat, y, u, d, mode=None) -> dict | None:
    """The leaks of a run against the card's error recursion, and the floor they carry.

    Parameters
    ----------
    card : Card
        An affine-kernel card with a ``decay_bound``.
    steps : (K,) array
        The steps of the run.
    x, xhat, y, u, d : (K+1, .) arrays
        The plant's state, the estimate, the outputs and the inputs at every point.
    mode : (K+1,) array, optional
        The modes of a switched plant.

    Returns
    -------
    dict or None
        ``carried`` (the largest carried leak over the run), ``worst_leak`` (the largest leak over its
        step's magnitude), ``leak_eps`` (:data:`LEAK_EPS`) and ``roundoff`` (every leak within it: the
        carried leaks are round-off); None when the card certifies no decay or its schedule cannot be
        replayed from the run.
    """
    decay = card.data.get("decay_bound")
    if decay is None or len(steps) == 0:
        return None
    mats = _step_matrices(card, steps, mode)
    if mats is None:
        return None
    over = float(card.data.get("overshoot_bound") or 1.0)
    e = np.asarray(x, dtype=float) - np.asarray(xhat, dtype=float)
    K = len(mats)
    leak, gain = np.zeros(K + 1), np.ones(K + 1)
    groups: dict = {}
    for k, m in enumerate(mats):
        groups.setdefault(id(m), (m, []))[1].append(k)
    for m, ks in groups.values():
        ks = np.asarray(ks)
        leak[ks + 1] = np.linalg.norm(e[ks + 1] - e[ks] @ np.asarray(m["N"], dtype=float).T, axis=1)
        gain[ks + 1] = _largest_gain(m)
    size = np.max([np.linalg.norm(np.asarray(a, dtype=float).reshape(K + 1, -1), axis=1)
                   for a in (x, xhat, y, u, d)], axis=0)
    magnitude = gain * np.maximum(size, np.concatenate([[0.0], size[:-1]]))
    scale = np.where(magnitude > 0, magnitude, 1.0)
    relative = np.where(magnitude > 0, leak / scale, np.where(leak > 0, np.inf, 0.0))
    carried, c = 0.0, 0.0
    for value in leak[1:].tolist():
        c = float(decay) * c + over * value
        carried = max(carried, c)
    worst = float(relative.max())
    return {"carried": carried, "worst_leak": worst, "leak_eps": LEAK_EPS, "roundoff": bool(worst <= LEAK_EPS)}


__all__ = ["LEAK_EPS", "roundoff_floor"]
