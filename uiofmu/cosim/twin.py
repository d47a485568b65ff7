"""The co-simulation loop with noise: the plant, the observer fed the noisy ``y`` and its noise-free twin
(a second instance of the same observer FMU fed the plant's own ``y``), stepped together. With process
noise the plant itself moves, so the twin is a whole loop: a second instance of the plant FMU, given every
input but the noise, feeds the twin observer.

Order at each communication point t_k, as in :mod:`uiofmu.cosim.master`: set the plant's inputs; read its
outputs; set both observers' inputs (the observer's ``y`` plus the noise ``v_k``, the twin's ``y`` as the
plant gives it, the same ``u``, ``d``, ... to both); read both observers' outputs; then ``doStep(t_k, h_k)``
on the observer, the twin and the plant.
"""

from __future__ import annotations

import numpy as np

from .fmi import Fmu, FmuCallError
from ..runtime.errors import FmuError


def _step(fmu: Fmu, who: str, k: int, t: float, h: float) -> None:
    try:
        fmu.step(t, h)
    except FmuCallError as exc:
        raise FmuError(f"the {who} FMU refused step {k} (t = {t:g} s, h = {h:g} s): "
                       + (exc.messages[-1] if exc.messages else str(exc))) from None


def run_twin_loop(plant: Fmu, obs: Fmu, twin: Fmu, plant_inputs: list, fed: list, sourced: list, source: dict,
                  measured, times: np.ndarray, steps: np.ndarray, bar, twin_plant: Fmu | None = None) -> tuple:
    """Step the plant, the observer fed the measured ``y`` and its noise-free twin over every point.

    Parameters
    ----------
    plant, obs, twin : Fmu
        Initialised.
    plant_inputs : list of str
        The plant's inputs (from ``source``).
    fed, sourced : list of str
        The observer inputs the plant feeds and those the source does (:func:`~uiofmu.cosim.master.routes`).
    source : dict of str to numpy.ndarray
        The source's values at every point.
    measured : callable
        ``measured(k, y)``: what the observer receives at point k for the plant's ``y`` (noisy, quantised).
    times, steps : arrays
        The communication points and the steps.
    bar
        A progress bar (``update(n)``).
    twin_plant : Fmu, optional
        Initialised as the plant: the twin observer's plant, given every plant input but ``w_noise``
        (which stays at its start value 0).

    Returns
    -------
    (dict, dict, dict, dict)
        The plant's recorded outputs (``x``, ``y`` and those it feeds, and ``y_measured``: what the observer
        received), the observer's outputs and the twin's, by name, one row per point, and the twin plant's
        recorded outputs (the plant's when there is no twin plant).
    """
    K = len(steps)
    outputs = plant.ports("output")
    recorded = {name: np.zeros((K + 1, outputs[name])) for name in dict.fromkeys(["x", "y", *fed]) if name in outputs}
    recorded["y_measured"] = np.zeros_like(recorded["y"])
    other = {name: np.zeros_like(values) for name, values in recorded.items() if name != "y_measured"} \
        if twin_plant is not None else recorded
    H = {name: np.zeros((K + 1, size)) for name, size in obs.ports("output").items()}
    H_twin = {name: np.zeros((K + 1, size)) for name, size in twin.ports("output").items()}
    for k in range(K + 1):
        for name in plant_inputs:
            plant.set(name, source[name][k])
        for name in outputs:
            if name in recorded:
                recorded[name][k] = plant.get(name)
        if twin_plant is not None:
            for name in plant_inputs:
                if name != "w_noise":
                    twin_plant.set(name, source[name][k])
            for name in other:
                other[name][k] = twin_plant.get(name)
        recorded["y_measured"][k] = measured(k, recorded["y"][k])
        for name in fed:
            obs.set(name, recorded["y_measured"][k] if name == "y" else recorded[name][k])
            twin.set(name, other[name][k])
        for name in sourced:
            obs.set(name, source[name][k])
            twin.set(name, source[name][k])
        for name in H:
            H[name][k] = obs.get(name)
            H_twin[name][k] = twin.get(name)
        if k == K:
            break
        t, h = float(times[k]), float(steps[k])
        _step(obs, "observer", k, t, h)
        _step(twin, "observer's noise-free twin", k, t, h)
        _step(plant, "plant", k, t, h)
        if twin_plant is not None:
            _step(twin_plant, "plant's noise-free twin", k, t, h)
        bar.update(1)
    return recorded, H, H_twin, other


__all__ = ["run_twin_loop"]
