"""The scenarios of a campaign's rows: each a function of the campaign's seed and the row index
only, drawn along the campaign's axes when it is asked for."""

from __future__ import annotations

import numpy as np

from ...runtime.errors import ProblemError
from .file import Campaign
from .fmus import Setup


#: The axes whose value is one number (a column each).
SCALAR_AXES = ("d_scale", "quantization", "plant_mismatch")
#: Seeds of a plant's mismatch are fmi2Integers >= 0.
MISMATCH_SEEDS = 2**31


def scenario(campaign: Campaign, setup: Setup, row: int) -> dict:
    """The scenario of one row: a function of the campaign seed and the row index only.

    Parameters
    ----------
    campaign : Campaign
    setup : Setup
        Gives the vector sizes and the default steps.
    row : int
        0 <= row < campaign.runs.

    Returns
    -------
    dict
        ``row``, ``steps`` (a SPEC), ``steps_seed``, and per axis its drawn value: ``xhat0_error``
        (a list), ``d_scale`` (a float), ``plant.NAME`` (lists), ``noise_y`` (a list) with ``noise_seed``
        (drawn after the axes: they draw what they draw without it), ``quantization`` (a float),
        ``plant_mismatch`` (a float) with ``mismatch_seed`` (drawn after ``noise_seed``), ``noise_w`` (a list)
        with ``noise_w_seed`` (drawn last).
    """
    if not 0 <= row < campaign.runs:
        raise ProblemError(f"--replay: row {row} is not a row of the campaign (0 to {campaign.runs - 1})")
    rng = np.random.default_rng([campaign.seed, row])
    specs = campaign.steps or (setup.default_steps,)
    picks = {}
    if campaign.grid:
        index = row % campaign.grid_size()
        for name, count in reversed(campaign.grid_axes()):
            index, picks[name] = divmod(index, count)
    spec = specs[picks["steps"]] if "steps" in picks else specs[int(rng.integers(len(specs)))]
    out = {"row": row, "steps": spec, "steps_seed": int(rng.integers(2**32))}
    sizes = {"xhat0_error": setup.n, "d_scale": 1, "noise_y": setup.p, "quantization": 1, "plant_mismatch": 1,
             "noise_w": setup.r, **{f"plant.{k}": v for k, v in setup.parameters.items()}}
    integers = {f"plant.{k}" for k in setup.integers}
    for name, axis in campaign.named_axes():
        size = sizes[name]
        value = axis.value(axis.params["values"][picks[name]], size) if name in picks else axis.draw(rng, size)
        kind = int if name in integers else float
        out[name] = float(value[0]) if name in SCALAR_AXES else [kind(v) for v in value]
    if campaign.noise_y is not None:
        out["noise_seed"] = int(rng.integers(2**32))
    if campaign.plant_mismatch is not None:
        out["mismatch_seed"] = int(rng.integers(MISMATCH_SEEDS))
    if campaign.noise_w is not None:
        out["noise_w_seed"] = int(rng.integers(2**32))
    return out


def scenarios(campaign: Campaign, setup: Setup, start: int = 0):
    """The scenarios of the rows from ``start`` on, each made when it is asked for (:func:`scenario`).

    Parameters
    ----------
    campaign : Campaign
    setup : Setup
    start : int
        The first row.

    Yields
    ------
    dict
        The scenario of row ``start``, then of the next rows up to ``campaign.runs - 1``.
    """
    for row in range(start, campaign.runs):
        yield scenario(campaign, setup, row)


def batches(campaign: Campaign, size: int):
    """The rows in row order, in ranges of ``size`` (the last may be shorter): a batch is its rows' indices
    only, and each row's scenario is made by the worker that runs it (:func:`scenario`), so a campaign of any
    number of runs starts at once and the command's own process does not draw them.

    Yields
    ------
    range
    """
    for start in range(0, campaign.runs, size):
        yield range(start, min(start + size, campaign.runs))


def scaled_inputs(inputs, scale: float):
    """The input source with its ``d`` signals scaled by ``scale`` (every term's level and amplitude).

    Parameters
    ----------
    inputs : uiofmu.cosim.inputs.SignalInputs
    scale : float

    Returns
    -------
    uiofmu.cosim.inputs.SignalInputs
    """
    from ...signals import Signal, Term
    from ..inputs import SignalInputs

    levels = {"constant": ("value",), "sine": ("amplitude", "offset"), "step": ("value", "initial"),
              "random": ("mean", "std")}

    def term(t: Term) -> Term:
        return Term(t.kind, tuple((k, v * scale if k in levels[t.kind] else v) for k, v in t.params))

    signals = inputs.signals
    d = tuple(Signal(tuple(term(t) for t in s.terms)) for s in signals["d"])
    return SignalInputs(signals["u"], d, signals.get("mode", ()), signals.get("theta", ()))


__all__ = ["MISMATCH_SEEDS", "SCALAR_AXES", "batches", "scaled_inputs", "scenario", "scenarios"]
