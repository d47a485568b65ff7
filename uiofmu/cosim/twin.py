"""The co-simulation loop with noise: the plant, the observer fed the noisy ``y`` and its noise-free twin
(a second instance of the same observer FMU fed the plant's own ``y``), stepped together. With process
noise the plant itself moves, so the twin is a whole loop: a second instance of the plant FMU, given every
input but the noise, feeds the twin observer.

Order at each communication point t_k, as in :mod:`uiofmu.cosim.master`: set the plant's inputs; read its
outputs; set both observers' inputs (the observer's ``y`` plus the noise ``v_k``, the twin's ``y`` as the
plant gives it, the same ``u``, ``d``, ... to both); read both observers' outputs; then ``doStep(t_k, h_k)``
on the observer, the twin and the plant (and the twin's plant, read and stepped after the plant).
"""

from __future__ import annotations

import numpy as np

from .fmi import Fmu, FmuCallError, refused_step


def _step(fmu: Fmu, who: str, k: int, t: float, h: float) -> None:
    try:
        fmu.step(t, h)
    except FmuCallError as exc:
        raise refused_step(who, k, t, h, exc) from None


def measured(v: np.ndarray, quantum: float | None):
    """``measured(k, y)``: what the observer receives at point k for the plant's ``y``: ``y + v[k]``, rounded to
    a multiple of ``quantum`` with one (half to even)."""

    def at(k, y):
        noisy = y + v[k]
        return quantum * np.round(noisy / quantum) if quantum else noisy

    return at


def run_twin_loop(plant: Fmu, obs: Fmu, twin: Fmu, plant_inputs: list, fed: list, sourced: list, source: dict,
                  v: np.ndarray, quantum: float | None, times: np.ndarray, steps: np.ndarray, bar,
                  native: bool = True, twin_plant: Fmu | None = None) -> tuple:
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
    v : numpy.ndarray
        The noise added to the plant's ``y`` at every point, a row per point.
    quantum : float or None
        The output quantum (:func:`measured`).
    times, steps : arrays
        The communication points and the steps.
    bar
        A progress bar (``update(n)``).
    native : bool
        Step in the C driver (:mod:`uiofmu.cosim.native`), where :func:`native_applies` (the caller asks it);
        the results are the same bit for bit.
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
    if native:
        return _native_twin_loop(plant, obs, twin, plant_inputs, fed, sourced, source, v, quantum, times, steps, bar,
                                 twin_plant)
    K = len(steps)
    measure = measured(v, quantum)
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
        recorded["y_measured"][k] = measure(k, recorded["y"][k])
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


def native_applies(plant: Fmu, obs: Fmu, twin: Fmu, fed: list, twin_plant: Fmu | None = None) -> bool:
    """Whether the C driver can run this loop: native binaries (:func:`uiofmu.cosim.native.available`) for the
    plant, both observers and the twin's plant if there is one, the plant's ``y`` Real on both sides and every
    other vector the plant feeds of one type on both."""
    from . import native

    if any(plant.integer(name) != obs.integer(name) for name in fed) or plant.integer("y") or obs.integer("y"):
        return False
    return native.available(plant, obs, twin, *([twin_plant] if twin_plant is not None else []))


def _dtype(fmu: Fmu, name: str):
    return np.intc if fmu.integer(name) else np.float64


def _function(fmu: Fmu, what: str, name: str) -> str:
    return f"fmi2{what}{'Integer' if fmu.integer(name) else 'Real'}"


def _native_twin_loop(plant: Fmu, obs: Fmu, twin: Fmu, plant_inputs: list, fed: list, sourced: list, source: dict,
                      v: np.ndarray, quantum: float | None, times: np.ndarray, steps: np.ndarray, bar,
                      twin_plant: Fmu | None) -> tuple:
    """:func:`run_twin_loop` in the C driver: the same calls in the same order, one per FMU and vector, on
    buffers with a row per point (the source's values typed as each FMU takes them; the plant's outputs and
    the observers' as they give them, as floats once the run is over). The twin's plant, if any, is a fourth
    FMU of the program, set and read after the plant and stepped after it."""
    from .native import Program

    K = len(steps)
    program = Program(times, steps)
    outputs = plant.ports("output")
    def typed(fmu: Fmu, name: str) -> np.ndarray:
        """The source's values of ``name`` as ``fmu`` takes them (an Integer's checked by the master before)."""
        values = np.ascontiguousarray(source[name], dtype=float)
        return values.astype(np.intc) if fmu.integer(name) else values

    for name in plant_inputs:
        program.values(plant, _function(plant, "Set", name), [name], typed(plant, name))
    recorded = {name: np.zeros((K + 1, outputs[name]), dtype=_dtype(plant, name))
                for name in dict.fromkeys(["x", "y", *fed]) if name in outputs}
    for name in outputs:
        if name in recorded:
            program.values(plant, _function(plant, "Get", name), [name], recorded[name])
    other = recorded
    if twin_plant is not None:
        for name in plant_inputs:
            if name != "w_noise":
                program.values(twin_plant, _function(twin_plant, "Set", name), [name], typed(twin_plant, name))
        other = {name: np.zeros_like(history) for name, history in recorded.items()}
        for name in other:
            program.values(twin_plant, _function(twin_plant, "Get", name), [name], other[name])
    y_measured = np.zeros_like(recorded["y"])
    program.measure(recorded["y"], np.ascontiguousarray(v, dtype=float), quantum, y_measured)
    for name in fed:
        program.values(obs, _function(obs, "Set", name), [name], y_measured if name == "y" else recorded[name])
        program.values(twin, _function(twin, "Set", name), [name], other[name])
    for name in sourced:
        values = typed(obs, name)
        program.values(obs, _function(obs, "Set", name), [name], values)
        program.values(twin, _function(twin, "Set", name), [name], values)
    H = {name: np.zeros((K + 1, size), dtype=_dtype(obs, name)) for name, size in obs.ports("output").items()}
    H_twin = {name: np.zeros((K + 1, size), dtype=_dtype(twin, name)) for name, size in twin.ports("output").items()}
    for name in H:
        program.values(obs, _function(obs, "Get", name), [name], H[name])
        program.values(twin, _function(twin, "Get", name), [name], H_twin[name])
    for fmu, who in ((obs, "observer"), (twin, "observer's noise-free twin"), (plant, "plant"),
                     *([(twin_plant, "plant's noise-free twin")] if twin_plant is not None else [])):
        program.step(fmu, who)
    program.run(bar)
    as_float = {name: history.astype(float) for name, history in recorded.items()}
    twin_recorded = ({name: history.astype(float) for name, history in other.items()} if twin_plant is not None
                     else as_float)
    as_float["y_measured"] = y_measured
    return (as_float, {name: h.astype(float) for name, h in H.items()},
            {name: h.astype(float) for name, h in H_twin.items()}, twin_recorded)


__all__ = ["measured", "native_applies", "run_twin_loop"]
