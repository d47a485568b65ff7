"""How long a run is by default: the length of an observer's ``<DefaultExperiment>`` and of a
co-simulation without ``--t-end`` (:func:`default_horizon`), and a problem's ``[experiment] steps``
that overrides it (:func:`experiment_steps`).
"""

from __future__ import annotations

import math

import numpy as np

from .errors import CardError
from .schedules import make_schedule


def experiment_steps(problem) -> int | None:
    """The problem document's ``[experiment] steps`` (None when absent).

    Raises
    ------
    CardError
        For a value that is not an integer from 1 to 100,000 (a card from someone else).
    """
    table = problem.get("experiment") if isinstance(problem, dict) else None
    steps = table.get("steps") if isinstance(table, dict) else None
    if steps is None:
        return None
    if isinstance(steps, bool) or not isinstance(steps, int) or not 1 <= steps <= 100_000:
        raise CardError(f"design card problem.experiment.steps: expected an integer from 1 to 100000, found "
                        f"{repr(steps)[:40]}")
    return steps


def default_horizon(card, floor: int = 50, cap: int = 5000) -> float:
    """A run long enough for the certified bound to fall to 1e-3 of the initial error: 50 to 5000
    steps of the mean admissible step (the default ``--t-end`` of ``uiofmu cosim`` and the stop
    time of the FMU's ``<DefaultExperiment>``).

    A discrete design (``decay_bound`` delta, ``overshoot_bound`` M) needs ``log(1e-3 / M) / log(delta)``
    steps. A continuous-time kernel (``decay_rate`` beta in 1/s, ``overshoot`` M, no ``decay_bound``) needs
    its start-up (the premise's start ``valid_from``, at least its largest delay: no estimate is valid before)
    plus ``log(1e3 M) / beta`` seconds
    (``10 / beta`` without M), in steps of the schedule's default ``step``. Without either, ``cap`` steps.
    A problem's ``[experiment] steps`` overrides all of this (:func:`experiment_steps`).
    """
    decay, over = card.data.get("decay_bound"), card.data.get("overshoot_bound")
    h = float(np.mean(make_schedule(card.schedule, card.matrices).admissible_steps()))
    steps = experiment_steps(card.data.get("problem"))
    if steps is not None:
        return steps * h
    k = cap
    if decay and over and 0 < decay < 1:
        k = int(math.ceil(math.log(1e-3 / over) / math.log(decay)))
    elif decay is None and (card.data.get("decay_rate") or 0) > 0:
        rate, over = float(card.data["decay_rate"]), card.data.get("overshoot")
        seconds = math.log(1e3 * over) / rate if over and over >= 1 else 10.0 / rate
        seconds += max([float(t) for t in card.schedule.get("delays", [])]            # the start-up: the
                       + [float(card.schedule.get("valid_from", 0.0))], default=0.0)   # premise's start
        k = int(math.ceil(seconds / h)) if math.isfinite(seconds) else cap
    return min(max(k, floor), cap) * h


__all__ = ["default_horizon", "experiment_steps"]
