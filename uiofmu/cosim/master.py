"""The co-simulation master: plant FMU and observer FMU on fmpy, with aperiodic steps.

Order at each communication point t_k (SPEC): read the plant's ``y`` (and true ``x``); set
the plant's ``u``, ``d`` and the observer's ``y``, ``u``; read ``xhat`` (and ``r``,
``dhat``); then ``doStep(t_k, h_k)`` on both. Inputs are held over each step.

A delayed observer (kernel ``delayed``, seed 001) also takes the plant's ``ydot`` (set after the
plant's ``u`` of t_k, so it is ``C x'`` with the input of the step about to be taken); the master
records its ``thetahat``, ``sigma_min`` and ``valid`` at every point and compares ``thetahat`` with the
true ``theta``, read from the plant FMU's parameter ``theta`` (the observer never reads it).

Where both FMUs have native binaries, the C driver of :mod:`uiofmu.cosim.native` makes the loop's calls (the
same ones, on the same buffers: the same results bit for bit); ``native=False`` keeps the loop in Python.
"""

from __future__ import annotations

import contextlib
import csv
import ctypes
import json
import math
import time
from collections import OrderedDict

import numpy as np

from ..runtime.card import Card, card_from_data
from ..runtime.errors import FmuError, ProblemError
from ..runtime.files import atomic_output, check_output_dir, write_atomic
from .fmu_cache import MAX_FILES, digest_of
from .fmi import (Fmu, FmuCallError, first_non_integer, not_an_integer, read_description, read_model_json, refused_step,
                  vector_sizes)
from .inputs import CsvInputs, SignalInputs, values_at
from .kernels import cosim_kernel
from .noise import certified_noise_gain, noise_metrics, noises, process_noise_metrics
from .native import available as native_available
from .twin import native_applies, run_twin_loop
from .result import CosimResult
from ..progress import progress
from ..runtime.observer import Runtime
from ..runtime.experiments import default_horizon as default_t_end
from .steps import step_sequence
from ..threads import single_blas_thread


#: The observer FMUs whose card re-checked in this process (the last MAX_FILES), by the SHA-256 of their bytes
#: and the archive limits they were read under: the text of their ``resources/model.json`` and the card's
#: read-only matrices.
_CHECKED: "OrderedDict[str, tuple]" = OrderedDict()


def _digest(path) -> str | None:
    """The SHA-256 of a file's bytes; None where it cannot be read (the reader then says why)."""
    try:
        return digest_of(path)
    except OSError:
        return None


def observer_card(path) -> Card:
    """The design card packed in an observer FMU built by uiofmu, checked against the card schema,
    with its certificate re-checked at the stored matrices (:func:`uiofmu.synthesis.recheck`) and,
    for a C FMU (whose binary holds the matrices), bound to the binary by the GUID both carry.

    The reading, the re-check and the binding are done once per content in a process: a file whose bytes
    (their SHA-256) passed them before gives its card again, its document parsed afresh from the text kept
    (the same before and after it was first read)."""
    from ..fmu.c_backend import guid_of
    from ..synthesis import recheck
    from .fmi import limits, open_archive, read_description, read_model_text

    digest = _digest(path)
    key = (digest, limits())
    hit = _CHECKED.get(key)
    if hit is not None:
        with contextlib.suppress(KeyError):      # another thread may have let it go meanwhile
            _CHECKED.move_to_end(key)
        text, matrices = hit
        return Card(json.loads(text)["card"], dict(matrices))
    text = read_model_text(path)
    spec = read_model_json(path, text)
    if spec.get("kind") != "observer" or "card" not in spec:
        raise FmuError(f"{path}: this FMU is not an observer built by uiofmu (its model is a "
                       f"{str(spec.get('kind'))[:40]!r})")
    card = card_from_data(spec["card"])
    recheck(card)
    with open_archive(path) as archive:
        compiled = "sources/design_data.c" in archive.namelist()
    guid = read_description(path).guid if compiled else None
    if compiled and str(guid).strip("{}") != guid_of(spec["card"]):
        raise FmuError(f"{path}: the card in resources/model.json is not the one its binary was built from (the "
                       f"FMU's GUID {str(guid)[:40]} is not the card's {guid_of(spec['card'])}): rebuild the FMU "
                       "from its card")
    if digest is not None and _digest(path) == digest:
        _CHECKED[key] = (text, card.matrices)
        while len(_CHECKED) > MAX_FILES:
            _CHECKED.popitem(last=False)
    return card


def default_steps(card: Card) -> str:
    """The steps an observer is designed for: ``fixed:dt``, or ``choice:`` of its intervals."""
    steps = Runtime(card).schedule.admissible_steps()
    return f"fixed:{steps[0]!r}" if len(steps) == 1 else "choice:" + ",".join(repr(h) for h in steps)



def default_inputs(card: Card):
    """The problem's ``[signals]`` recorded in the card."""
    from ..problem import problem_from_data

    problem = problem_from_data(card.data["problem"], default_name=card.name)
    return SignalInputs(problem.u, problem.d, problem.mode, problem.theta)


@single_blas_thread
def cosimulate(plant_path, observer_path, steps: np.ndarray, inputs=None, *, plant_x0=None, xhat0=None,
               plant_parameters: dict | None = None, show_progress: bool | None = None,
               instances=None, card: Card | None = None, noise=None, quantization: float | None = None,
               native: bool = True) -> CosimResult:
    """Run the plant and observer FMUs together on the given communication steps.

    Parameters
    ----------
    plant_path, observer_path : str or Path
        FMUs; the plant has inputs ``u``, ``d`` and outputs ``y``, ``x``; the observer, built by
        uiofmu (its design card gives the default inputs and the certified bound), has inputs
        ``y``, ``u`` and outputs ``xhat``, ``r`` (and ``dhat``). A delayed observer also takes the
        plant's ``ydot`` and outputs ``thetahat``, ``sigma_min``, ``valid``; its plant has the parameter
        ``theta`` (the truth ``thetahat`` is compared with).
    steps : array_like
        Step lengths h_0, h_1, ... (see :func:`uiofmu.cosim.steps.step_sequence`).
    inputs : object, optional
        Has ``sizes`` and ``values(t)`` (and ``values_at(times)`` for all points at once); by default
        the signals of the observer's problem. Inputs are functions of time: they are evaluated for
        every communication point before the first step.
    plant_x0, xhat0 : array_like, optional
        Override the plant's initial state and the observer's initial estimate.
    plant_parameters : dict, optional
        Other plant parameters to set before initialisation, by port name (e.g. ``{"seed": [7]}``
        for a plant switching at random, ``{"theta": [...]}`` for a plant with unknown parameters:
        the plant simulates them and the metrics compare ``thetahat`` with them).
    show_progress : bool, optional
        Progress bar (default: when stderr is a terminal).
    instances : (Fmu, Fmu), optional
        The plant and observer already loaded (:class:`uiofmu.cosim.fmi.Fmu` of these paths), for many
        runs in one process: each run starts with ``fmi2Reset`` on both instead of loading them
        again, and leaves them open (a campaign's worker keeps them for all its runs).
    card : Card, optional
        The observer's card, already read and re-checked (:func:`observer_card`) for these runs.
    noise : str, Noise or list of them, optional
        White Gaussian noise (:mod:`uiofmu.cosim.noise`; text ``y=STD[,SEED]``, ``STD`` one number or a list
        ``[S1,...]`` per output): ``y`` is added to the plant's outputs on their way to the observer (the
        plant's state stays the truth), and a noise-free twin of the observer (a second instance of its FMU,
        fed the plant's own ``y``) runs in the same loop; ``w`` (alone: without ``y`` noise and quantization)
        feeds a plant FMU's process-noise input ``w_noise`` (refused for a plant without one), and the twin
        is then a whole noise-free loop, a second plant instance feeding the twin observer. The result is the
        twin's run (its bound check, the certified bound being one of noise-free outputs) with the noisy
        run in ``result.noise`` (``result.noise_w``) and the metrics of
        :func:`uiofmu.cosim.noise.noise_metrics` (:func:`uiofmu.cosim.noise.process_noise_metrics`). With
        ``instances``, a third one is the twin observer and a fourth, for process noise, the twin plant.
    quantization : float, optional
        An output quantum Q > 0: the observer receives ``Q round((y + v) / Q)`` (after the noise), the twin
        still the plant's own ``y``; the noise gain is then measured on what the observer received minus ``y``.
    native : bool
        Step in C (:mod:`uiofmu.cosim.native`) where every FMU of the run has a native binary (no pythonfmu FMU)
        and a C compiler built the driver; the results are the same bit for bit as with ``native=False``, the
        loop in Python.

    Returns
    -------
    CosimResult
        Its ``timing`` holds the CPU seconds of the run (``total``; ``steps``: from the initialised
        FMUs to the histories, inputs included; ``loop``: the stepping alone), ``fmi_calls_per_step`` and
        ``native`` (whether the C driver stepped).

    Raises
    ------
    FmuError
        When an FMU refuses a call, naming the FMU, the time, the step and its message.

    Notes
    -----
    The loop makes one ``fmi2SetReal`` and one ``fmi2GetReal`` (and ``fmi2SetInteger``,
    ``fmi2GetInteger`` where an FMU has Integer ports) per FMU and step, through fmpy's ctypes
    functions on value references resolved once and buffers allocated once: the plant writes its
    outputs into the same memory the observer reads its inputs from. With ``native``, the C driver makes
    the same calls through the same functions on the same buffers.
    """
    cpu0 = time.process_time()
    card = observer_card(observer_path) if card is None else card
    if inputs is None:
        inputs = default_inputs(card)
    steps = np.asarray(steps, dtype=float)
    K = len(steps)
    noise = noises(noise)
    quantum = check_quantum(quantization)
    if "w" in noise and "w_noise" not in vector_sizes(read_description(plant_path).modelVariables, "input"):
        raise ProblemError(f"--noise {noise['w'].text()}: the plant FMU {plant_path} takes no process noise (it has "
                           "no input w_noise: its problem declares no [plant] W)")
    if "w" in noise and ("y" in noise or quantum):
        raise ProblemError(f"--noise {noise['w'].text()}: process noise is measured alone (its twin loop is the "
                           "noise-free plant and observer); leave out the sensor noise and the quantization")
    if noise or quantum:
        result = _noisy_run(plant_path, observer_path, card, steps, inputs, noise, quantum, plant_x0, xhat0,
                            plant_parameters, show_progress, instances, native)
        return _timed(result, result.timing, cpu0)
    if instances is not None:
        for fmu in instances:
            fmu.reset()
    with contextlib.ExitStack() as stack:
        # loaded here are closed here, also when the second fails to load; given ones stay open
        plant, obs = instances or (stack.enter_context(Fmu(plant_path, "plant")),
                                   stack.enter_context(Fmu(observer_path, "observer")))
        fed, sourced, theta_true = _initialize(plant, obs, plant_path, inputs.sizes, plant_parameters, plant_x0, xhat0)
        cpu1 = time.process_time()
        T = communication_points(steps)
        source = values_at(inputs, T)
        plant_inputs = driven_inputs(plant, source)
        check_integers(inputs, source, T, [n for n in plant_inputs if plant.integer(n)]
                       + [n for n in sourced if obs.integer(n)])
        loop = _Loop(plant, obs, plant_inputs, fed, sourced, ["y", "x"], list(obs.ports("output")), source, K)
        program = loop.native_program(plant, obs, T, steps) if native and native_available(plant, obs) else None
        cpu2 = time.process_time()
        with progress(total=K, desc="co-simulation", unit="step", enabled=show_progress) as bar:
            if program is not None:
                program.run(bar)
            else:
                loop.run(T.tolist(), steps.tolist(), bar)
        cpu3 = time.process_time()
        X, Y, U, D, H, MODE = _histories(loop, plant, obs, source, fed, K)
        cpu4 = time.process_time()
    timing = {"steps": cpu4 - cpu1, "loop": cpu3 - cpu2, "fmi_calls_per_step": loop.calls_per_step,
              "native": program is not None}
    return _timed(_with_plant(cosim_kernel(card).result(card, T, steps, X, Y, U, D, H, MODE, theta_true),
                              plant_path, card, plant_parameters), timing, cpu0)


def _with_plant(result: CosimResult, plant_path, card: Card, plant_parameters: dict | None) -> CosimResult:
    """The result with ``metrics["plant"]["is_design_model"]`` (:func:`plant_is_design_model`, and no plant
    perturbed by a ``mismatch`` above 0 is) where its bound is violated (what the summary's explanation
    needs), with the ``mismatch`` when one was asked for."""
    mismatch = float(np.ravel((plant_parameters or {}).get("mismatch", [0.0]))[0])
    if result.metrics.get("bound_respected") is False:
        result.metrics["plant"] = {"is_design_model": mismatch == 0 and plant_is_design_model(plant_path, card)}
    if mismatch:
        result.metrics.setdefault("plant", {})["mismatch"] = mismatch
    return result


def plant_is_design_model(plant_path, card: Card) -> bool:
    """Whether the plant FMU simulates the design's own problem: a plant FMU built by uiofmu whose model
    (``resources/model.json``) is the plant of the card's problem, all but its initial state."""
    from ..problem import problem_from_data

    try:
        spec = read_model_json(plant_path)
        design = problem_from_data(card.data["problem"], default_name=card.name).plant.to_data()
    except (FmuError, ProblemError, KeyError, TypeError, ValueError):
        return False
    plant = spec.get("plant") if spec.get("kind") == "plant" else None
    if not isinstance(plant, dict):
        return False
    return {k: v for k, v in plant.items() if k != "x0"} == {k: v for k, v in design.items() if k != "x0"}


def check_quantum(quantization) -> float | None:
    """An output quantum: None (none) or a finite number > 0 (raises :class:`ProblemError` naming it)."""
    if quantization is None:
        return None
    if (isinstance(quantization, bool) or not isinstance(quantization, (int, float))
            or not math.isfinite(quantization) or quantization <= 0):
        raise ProblemError(f"quantization: expected an output quantum, a finite number > 0, found {quantization!r}"
                           [:200])
    return float(quantization)


def _noisy_run(plant_path, observer_path, card: Card, steps: np.ndarray, inputs, noise: dict, quantum, plant_x0,
               xhat0, plant_parameters, show_progress, instances, native: bool = True) -> CosimResult:
    """:func:`cosimulate` with noise: the plant, the observer fed the noisy ``y`` and its noise-free twin
    (:func:`uiofmu.cosim.twin.run_twin_loop`); the twin's result, with the noisy run in ``result.noise``."""
    K = len(steps)
    T = communication_points(steps)
    with contextlib.ExitStack() as stack:
        if instances is not None:
            for fmu in instances:
                fmu.reset()
        plant, obs = instances[:2] if instances else (stack.enter_context(Fmu(plant_path, "plant")),
                                                       stack.enter_context(Fmu(observer_path, "observer")))
        twin = (instances[2] if instances and len(instances) > 2
                else stack.enter_context(Fmu(observer_path, "observer-noise-free")))
        twin_plant = None
        source = values_at(inputs, T)
        sizes = dict(inputs.sizes)
        if "w" in noise:
            twin_plant = (instances[3] if instances and len(instances) > 3
                          else stack.enter_context(Fmu(plant_path, "plant-noise-free")))
            sizes["w_noise"] = plant.ports("input")["w_noise"]
            source["w_noise"] = noise["w"].samples(K + 1, sizes["w_noise"])
        fed, sourced, theta_true = _initialize(plant, obs, plant_path, sizes, plant_parameters, plant_x0, xhat0)
        twin.initialize(0.0, {"xhat0": xhat0} if xhat0 is not None else None)
        if twin_plant is not None:
            twin_plant.initialize(0.0, {**(plant_parameters or {}), **({"x0": plant_x0} if plant_x0 is not None
                                                                       else {})})
        plant_inputs = driven_inputs(plant, source)
        check_integers(inputs, source, T, [n for n in plant_inputs if plant.integer(n)]
                       + [n for n in sourced if obs.integer(n)])
        p = len(plant.refs("y"))
        v = noise["y"].samples(K + 1, p) if "y" in noise else np.zeros((K + 1, p))
        native = native and native_applies(plant, obs, twin, fed, twin_plant)
        with progress(total=K, desc="co-simulation with noise", unit="step", enabled=show_progress) as bar:
            recorded, H, H_twin, twin_recorded = run_twin_loop(plant, obs, twin, plant_inputs, fed, sourced, source,
                                                               v, quantum, T, steps, bar, native, twin_plant)
        if "zhat" in H:                  # a functional observer: its bound reads x_0 - xhat0
            H["xhat0"] = H_twin["xhat0"] = np.asarray(obs.get("xhat0"), dtype=float)
    X, Y = recorded["x"], recorded["y"]
    X_twin, Y_twin = twin_recorded["x"], twin_recorded["y"]
    U = source["u"] if "u" in source else np.zeros((K + 1, 0))
    D = source["d"] if "d" in source else np.zeros((K + 1, 0))
    MODE = None
    if obs.has("mode"):
        MODE = recorded["mode"][:, 0].copy() if "mode" in fed else np.round(source["mode"])[:, 0]
    kernel = cosim_kernel(card)
    result = _with_plant(kernel.result(card, T, steps, X_twin, Y_twin, U, D, H_twin, MODE, theta_true), plant_path,
                         card, plant_parameters)
    noisy = kernel.result(card, T, steps, X, Y, U, D, H, MODE, theta_true)
    if "y" in noise or quantum:
        truth = noisy.x if kernel.estimate == "xhat" else noisy.functional["true"]     # x, or Lf x (zhat)
        dhat = H.get("dhat")
        v = recorded["y_measured"] - Y                 # what the observer received beyond the plant's y
        result.metrics.update(noise_metrics(card, v, kernel.estimate_of(noisy), kernel.estimate_of(result), truth,
                                            dhat if dhat is not None and dhat.size else None, D,
                                            noise=noise.get("y"), quantum=quantum))
        result.noise = {"v": v, "std": np.asarray(result.metrics["noise"]["effective_std"]),
                        "estimate": kernel.estimate_of(noisy), "error": kernel.estimate_of(noisy) - truth,
                        "twin_error": kernel.estimate_of(result) - truth}
    result.timing = {"native": native}
    if "w" in noise:
        truth, truth_twin = ((noisy.x, result.x) if kernel.estimate == "xhat"
                             else (noisy.functional["true"], result.functional["true"]))
        error, twin_error = kernel.estimate_of(noisy) - truth, kernel.estimate_of(result) - truth_twin
        w = source["w_noise"][:K]                       # the noise held over each step taken
        result.metrics.update(process_noise_metrics(certified_noise_gain(card, "gain_w"), error, twin_error, w))
        result.metrics.setdefault("noise", {})["w"] = {"std": noise["w"].stds(sizes["w_noise"]).tolist(),
                                                      "seed": noise["w"].seed, "text": noise["w"].text(),
                                                      "noise_norm": float(np.sqrt(np.sum(w * w)))}
        result.noise_w = {"w": w, "error": error, "twin_error": twin_error}
    return result



def _initialize(plant: Fmu, obs: Fmu, plant_path, sizes: dict, plant_parameters, plant_x0, xhat0) -> tuple:
    """Route the signals (``sizes``: the vectors the source offers) and initialise both FMUs: ``(fed, sourced)``
    of :func:`routes` and the plant's true ``theta`` (None for a plant without one)."""
    if not plant.has("x"):
        raise FmuError(f"{plant_path}: the plant FMU has no x[...] outputs; the error needs the true state")
    fed, sourced = routes(plant, obs, sizes)
    plant.initialize(0.0, {**(plant_parameters or {}), **({"x0": plant_x0} if plant_x0 is not None else {})})
    obs.initialize(0.0, {"xhat0": xhat0} if xhat0 is not None else None)
    # the true parameters of a plant with unknown ones, as the plant FMU simulates them
    theta_true = plant.get("theta") if "theta" in plant.ports("parameter") else None
    return fed, sourced, theta_true


def _histories(loop: _Loop, plant: Fmu, obs: Fmu, source: dict, fed: list, K: int) -> tuple:
    """``(X, Y, U, D, H, MODE)`` of a finished loop: the plant's state and outputs, the inputs, the
    observer's outputs by name and the plant's mode (None without one)."""
    n, p = len(plant.refs("x")), len(plant.refs("y"))
    m, q = len(plant.refs("u")), len(plant.refs("d"))
    X, Y = np.zeros((K + 1, n)), np.zeros((K + 1, p))
    U, D = np.zeros((K + 1, m)), np.zeros((K + 1, q))
    X[:], Y[:] = loop.plant_history("x"), loop.plant_history("y")
    if "u" in source:
        U[:] = source["u"]
    if "d" in source:
        D[:] = source["d"]
    H = {name: np.zeros((K + 1, size)) for name, size in obs.ports("output").items()}
    for name, history in H.items():
        history[:] = loop.observer_history(name)
    if "zhat" in H:                      # a functional observer: its bound reads x_0 - xhat0
        H["xhat0"] = np.asarray(obs.get("xhat0"), dtype=float)
    MODE = None
    if obs.has("mode"):
        MODE = loop.plant_history("mode")[:, 0].copy() if "mode" in fed else np.round(source["mode"])[:, 0]
    return X, Y, U, D, H, MODE


def _timed(result: CosimResult, timing: dict, cpu0: float) -> CosimResult:
    result.timing = {"total": time.process_time() - cpu0, **timing}
    return result


def communication_points(steps) -> np.ndarray:
    """The communication points t_0 = 0, t_1, ..., t_K of the steps: each the previous plus its step,
    re-summed from zero every 1024 steps (so round-off does not pile up over long runs)."""
    steps = np.asarray(steps, dtype=float)
    times = np.zeros(len(steps) + 1)
    for a in range(0, len(steps), 1024):          # add.accumulate adds in order: ((t + h_a) + h_a+1) + ...
        b = min(a + 1024, len(steps))
        times[a:b] = np.add.accumulate(np.concatenate([times[a:a + 1], steps[a:b - 1]]))
        if b % 1024 == 0:
            times[b] = float(np.sum(steps[:b]))
        else:
            times[b] = times[b - 1] + steps[b - 1]
    return times


#: Steps between two progress updates.
CHUNK = 256

_DTYPES = {"Real": np.float64, "Integer": np.intc}

#: fmi2Status fmi2{Set,Get}{Real,Integer}(fmi2Component, const fmi2ValueReference*, size_t, values*), with the
#: pointers passed as addresses (into the loop's buffers: no ctypes array per row).
_VALUES_FUNCTION = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t, ctypes.c_void_p)


class _Loop:
    """The co-simulation loop on buffers allocated once, with one call per FMU, direction and type.

    For each type (Real, Integer) a matrix with a row per communication point holds, side by side,
    the plant's inputs, the observer's inputs from the source, the plant outputs the observer takes
    and the plant's other recorded outputs, so that each call of a step reads or writes one contiguous
    slice of the point's row (the plant writes what the observer then reads, in the same memory)::

        | plant inputs | observer's source inputs | plant outputs fed to the observer | other plant outputs |
        '- plant set --'------------- observer set ---------------------------------'
                                                  '------------------ plant get ----------------------'

    The source's values fill their columns for all points before the first step; the observer's
    outputs have matrices of their own; the matrices are the histories. A vector the two FMUs type
    differently (Real on one, Integer on the other) sits with the plant's outputs and is converted
    into the observer's columns at each step, as :meth:`Fmu.set` would.
    """

    def __init__(self, plant: Fmu, obs: Fmu, plant_inputs: list, fed: list, sourced: list, recorded: list,
                 obs_outputs: list, source: dict, K: int):
        self.K, self.keep, self.times = K, [], []
        kind = {}
        for fmu, who, names in ((plant, "plant", [*plant_inputs, *fed, *recorded]),
                                (obs, "obs", [*fed, *sourced, *obs_outputs])):
            kind.update({(who, n): "Integer" if fmu.integer(n) else "Real" for n in names})
        shared = [n for n in fed if kind["plant", n] == kind["obs", n]]
        converted = [n for n in fed if n not in shared]
        gets = [*shared, *converted, *(n for n in recorded if n not in fed)]
        self.plant_cols, self.obs_cols, self.buffers, calls, convert_into = {}, {}, {}, {}, {}
        for t, dtype in _DTYPES.items():
            blocks = [("plant set", plant, [n for n in plant_inputs if kind["plant", n] == t]),
                      ("source", obs, [n for n in [*sourced, *converted] if kind["obs", n] == t]),
                      ("fed", plant, [n for n in shared if kind["plant", n] == t]),
                      ("other", plant, [n for n in gets if n not in shared and kind["plant", n] == t])]
            edges, col, fill = [0], 0, []
            for block, fmu, names in blocks:
                for n in names:
                    width = len(fmu.refs(n))
                    if block in ("fed", "other"):
                        self.plant_cols[n] = (t, col, width)
                    elif block == "plant set" or n in sourced:
                        fill.append((n, col, col + width))
                    else:
                        convert_into[n] = (t, col, width)
                    col += width
                edges.append(col)
            W = np.zeros((K + 1, col), dtype=dtype)
            for n, a, b in fill:
                W[:, a:b] = source[n] if t == "Real" else _integers(source[n])
            outs = [n for n in obs_outputs if kind["obs", n] == t]
            O = np.zeros((K + 1, sum(len(obs.refs(n)) for n in outs)), dtype=dtype)
            at = 0
            for n in outs:
                self.obs_cols[n] = (t, at, len(obs.refs(n)))
                at += len(obs.refs(n))
            self.buffers[t] = (W, O)
            spans = {"plant set": (plant, blocks[0][2], W, 0),
                     "observer set": (obs, blocks[1][2] + blocks[2][2], W, edges[1]),
                     "plant get": (plant, blocks[2][2] + blocks[3][2], W, edges[2]),
                     "observer get": (obs, outs, O, 0)}
            for what, (fmu, names, buffer, first) in spans.items():
                calls[what, t] = _call_entry(fmu, f"fmi2{'Set' if 'set' in what else 'Get'}{t}", names, buffer,
                                             first, self.keep)
        self.conversions = [(n, self.plant_cols[n], convert_into[n]) for n in converted]
        if converted:     # called with the point's index as its "address" (base 0, stride 1)
            calls["convert", "Real"] = (self._convert, None, None, None, 0, 1, [], "")
        order = ["plant set", "plant get", "convert", "observer set", "observer get"]
        self.calls = [calls[what, t] for what in order for t in _DTYPES if calls.get((what, t)) is not None]
        self.steps = [(obs.function("fmi2DoStep"), obs.component, obs.messages),
                      (plant.function("fmi2DoStep"), plant.component, plant.messages)]
        self.calls_per_step = sum(1 for c in self.calls if c[1] is not None) + len(self.steps)

    def native_program(self, plant: Fmu, obs: Fmu, times: np.ndarray, steps: np.ndarray):
        """This loop as a program of the C driver (:class:`uiofmu.cosim.native.Program`): the same calls on the
        same buffers in the same order, the conversions of :meth:`_convert` in C (a refused one raises
        :meth:`_convert`'s error), both doSteps last."""
        from .native import Program, call_failed

        program = Program(times, steps)
        program.keep(self)                  # the value references and buffers the calls point into
        owners = {id(plant.messages): plant, id(obs.messages): obs}

        def refused(k, status, mark):
            self._convert(None, None, None, k)

        for function, component, refs, count, base, stride, log, name in self.calls:
            if component is None:                   # the conversions between differently typed vectors
                for _, (ts, a, width), (td, b, _) in self.conversions:
                    program.convert(self.buffers[ts][0], a, self.buffers[td][0], b, width, refused)
                continue
            fmu = owners[id(log)]
            program.call(fmu, function, refs, count, base, stride, call_failed(fmu, name))
        program.step(obs, "observer")
        program.step(plant, "plant")
        return program

    def _convert(self, component, refs, count, k) -> int:
        """Copy the differently typed fed vectors of point ``k`` into the observer's columns (a plant's
        Real output that is not an fmi2Integer raises :class:`FmuError` naming it)."""
        for name, (ts, a, width), (td, b, _) in self.conversions:
            src, dst = self.buffers[ts][0][k], self.buffers[td][0][k]
            bad = first_non_integer(src[a:a + width]) if td == "Integer" else -1
            if bad >= 0:
                raise FmuError(not_an_integer(f"the plant's output {name}[{bad + 1}], an Integer input of the "
                                              f"observer, at t = {self.times[k]:g} s", src[a + bad]))
            dst[b:b + width] = src[a:a + width]
        return 0

    def run(self, times: list, steps: list, bar) -> None:
        """Every communication point, :data:`CHUNK` steps between progress updates."""
        K, self.times = self.K, times
        run = _chunk4 if len(self.calls) == 4 and all(c[1] is not None for c in self.calls) else _chunk
        for k0 in range(0, K + 1, CHUNK):
            count = min(CHUNK, K + 1 - k0)
            run(self.calls, self.steps, times, steps, k0, count, K)
            bar.update(min(count, K - k0))

    def plant_history(self, name: str) -> np.ndarray:
        """The plant output ``name`` at every point, as floats (no columns when the plant has none)."""
        if name not in self.plant_cols:
            return np.zeros((self.K + 1, 0))
        t, a, width = self.plant_cols[name]
        return self.buffers[t][0][:, a:a + width].astype(float)

    def observer_history(self, name: str) -> np.ndarray:
        """The observer output ``name`` at every point, as floats."""
        t, a, width = self.obs_cols[name]
        return self.buffers[t][1][:, a:a + width].astype(float)


def check_integers(inputs, source: dict, times: np.ndarray, names) -> None:
    """Refuse a source value for an Integer input that is not an fmi2Integer (:func:`~.fmi.first_non_integer`).

    Parameters
    ----------
    inputs : object
        The input source; its ``key(name, i)``, when it has one, names the element in messages.
    source : dict of str to numpy.ndarray
        Its values at every communication point (:func:`~uiofmu.cosim.inputs.values_at`).
    times : numpy.ndarray
        The communication points.
    names : list of str
        The vectors an FMU takes as Integer.

    Raises
    ------
    ProblemError
        Naming the input, the time and the value.
    """
    for name in names:
        values = np.asarray(source[name], dtype=float).reshape(len(times), -1)
        bad = first_non_integer(values)
        if bad >= 0:
            k, i = divmod(bad, values.shape[1])
            where = inputs.key(name, i) if hasattr(inputs, "key") else f"the input {name}[{i + 1}]"
            raise ProblemError(not_an_integer(f"{where} at t = {times[k]:g} s", values[k, i]))


def _integers(values: np.ndarray) -> np.ndarray:
    """Source values as fmi2Integer (exactly: :func:`check_integers` passed them)."""
    return np.asarray(values, dtype=float).astype(np.intc)


def _call_entry(fmu: Fmu, function: str, names: list, buffer: np.ndarray, first: int, keep: list):
    """One call of the loop: the binary's function (as :data:`_VALUES_FUNCTION`), the instance, the
    address of the value references of ``names`` (the array appended to ``keep``, which holds it as long
    as the loop lives) and where point k's values are: the address ``base + k * stride`` of column
    ``first`` of row k of ``buffer``; None when the FMU has none of them."""
    refs = fmu.value_references(names)
    if not len(refs):
        return None
    keep.append(refs)
    address = ctypes.cast(fmu.function(function), ctypes.c_void_p).value
    base = buffer.ctypes.data + first * buffer.itemsize
    return (_VALUES_FUNCTION(address), fmu.component, ctypes.addressof(refs), len(refs), base, buffer.strides[0],
            fmu.messages, function)


def _chunk(calls: list, steps_: list, times: list, steps: list, k0: int, count: int, K: int) -> None:
    """Points k0 .. k0 + count - 1: the sets and gets of point k, then both doSteps (none at t_K).

    Each call's status is checked: above fmi2Warning it raises :class:`FmuCallError` with the lines the
    FMU logged during that call (a refused doStep an :class:`FmuError` naming the FMU, step and time).
    """
    for k in range(k0, k0 + count):
        for function, component, refs, n, base, stride, log, name in calls:
            start = len(log)
            status = function(component, refs, n, base + k * stride)
            if status > 1:
                raise FmuCallError(name, status, log[start:]) from None
        if k == K:
            return
        _do_steps(steps_, k, times[k], steps[k])


def _chunk4(calls: list, steps_: list, times: list, steps: list, k0: int, count: int, K: int) -> None:
    """:func:`_chunk` unrolled for four calls a step (one set and one get per FMU, the common case)."""
    (f1, c1, r1, n1, b1, s1, l1, m1), (f2, c2, r2, n2, b2, s2, l2, m2) = calls[0], calls[1]
    (f3, c3, r3, n3, b3, s3, l3, m3), (f4, c4, r4, n4, b4, s4, l4, m4) = calls[2], calls[3]
    for k in range(k0, k0 + count):
        start = len(l1)
        status = f1(c1, r1, n1, b1 + k * s1)
        if status > 1:
            raise FmuCallError(m1, status, l1[start:]) from None
        start = len(l2)
        status = f2(c2, r2, n2, b2 + k * s2)
        if status > 1:
            raise FmuCallError(m2, status, l2[start:]) from None
        start = len(l3)
        status = f3(c3, r3, n3, b3 + k * s3)
        if status > 1:
            raise FmuCallError(m3, status, l3[start:]) from None
        start = len(l4)
        status = f4(c4, r4, n4, b4 + k * s4)
        if status > 1:
            raise FmuCallError(m4, status, l4[start:]) from None
        if k == K:
            return
        _do_steps(steps_, k, times[k], steps[k])


def _do_steps(steps_: list, k: int, t: float, h: float) -> None:
    """fmi2DoStep(t, h) on the observer, then on the plant (``steps_``: their function, component and
    log); a refusal raises the :class:`FmuError` of :func:`~.fmi.refused_step`."""
    for who, (do, component, log) in zip(("observer", "plant"), steps_):
        start = len(log)
        status = do(component, t, h, 1)
        if status > 1:
            raise refused_step(who, k, t, h, FmuCallError("fmi2DoStep", status, log[start:]))


#: A plant input that a run without it leaves at its start value (0): process noise, given by ``--noise w=...``.
OPTIONAL_PLANT_INPUTS = ("w_noise",)


def driven_inputs(plant, source) -> list:
    """The plant's inputs a run sets from the source (``source``: its vectors by name): every one, but an
    :data:`OPTIONAL_PLANT_INPUTS` one the source does not give."""
    return [name for name in plant.ports("input") if name not in OPTIONAL_PLANT_INPUTS or name in source]


def routes(plant, obs, source: dict) -> tuple[list, list]:
    """Which observer inputs the plant feeds and which the input source does, by name.

    Every observer input named like a plant output takes that output (``y``; ``mode``,
    ``theta``, ``ydot`` where a plant has them); every other observer input, and every plant
    input, takes the input source's vector of the same name (``u``, ``d``, ``mode``, ``theta``).

    Parameters
    ----------
    plant, obs : Fmu
    source : dict of str to int
        The vectors the input source offers, with their sizes.

    Returns
    -------
    (list of str, list of str)
        The observer inputs fed by the plant, and those fed by the source.

    Raises
    ------
    FmuError
        For a vector whose sizes differ between the FMUs (or the source), and for an input
        that nothing feeds, naming it.
    """
    outputs, obs_in = plant.ports("output"), obs.ports("input")
    plant_in = {name: size for name, size in plant.ports("input").items() if name in driven_inputs(plant, source)}
    fed = [name for name in obs_in if name in outputs]
    for name in fed:
        if outputs[name] != obs_in[name]:
            raise FmuError(f"the plant has {outputs[name]} outputs {name} but the observer expects {obs_in[name]}")
    sourced = [name for name in obs_in if name not in outputs]
    for who, ports in (("plant", plant_in), ("observer", {k: obs_in[k] for k in sourced})):
        for name, size in ports.items():
            if name not in source:
                offered = ", ".join(f"{k}[{v}]" for k, v in source.items() if v) or "nothing"
                raise FmuError(f"the {who} FMU takes the input {name}[1..{size}], which no plant output and no "
                               f"input of the source gives (the source gives {offered})")
            if source[name] != size:
                raise FmuError(f"the {who} FMU takes {size} inputs {name}, the input source gives {source[name]}")
    return fed, sourced


#: Formats of the results table (``cosim --format``): ``csv`` (every double as its shortest exact text),
#: ``npz`` (numpy's zip of one array per column, always at hand) and ``parquet`` (with pyarrow installed).
RESULT_FORMATS = ("csv", "npz", "parquet")
#: Rows of ``results.csv`` written between two progress updates.
WRITE_CHUNK = 8192


def check_format(fmt: str) -> str:
    """``fmt`` if it is one of :data:`RESULT_FORMATS` that can be written here (parquet needs pyarrow).

    Raises
    ------
    ProblemError
        Naming the format and what it needs.
    """
    if fmt not in RESULT_FORMATS:
        raise ProblemError(f"--format {str(fmt)[:40]!r}: expected one of {', '.join(RESULT_FORMATS)}")
    if fmt == "parquet":
        try:
            import pyarrow  # noqa: F401
        except ImportError:
            raise ProblemError("--format parquet: needs pyarrow (pip install pyarrow), which is not installed; "
                               "--format npz writes a binary table with numpy alone") from None
    return fmt


def _write_csv(cols: dict, part, show_progress: bool | None) -> None:
    """The columns as CSV, :data:`WRITE_CHUNK` rows between progress updates (a bar on a terminal)."""
    names, rows = list(cols), len(next(iter(cols.values())))
    with open(part, "w", newline="") as f, progress(total=rows, desc="writing results.csv", unit="row",
                                                    enabled=show_progress) as bar:
        w = csv.writer(f)
        w.writerow(names)
        for k0 in range(0, rows, WRITE_CHUNK):
            chunk = [np.asarray(cols[name][k0:k0 + WRITE_CHUNK], dtype=float).tolist() for name in names]
            w.writerows(["" if math.isnan(v) else repr(v) for v in row] for row in zip(*chunk))
            bar.update(len(chunk[0]))


def _write_binary(cols: dict, part, fmt: str) -> None:
    """The columns as ``npz`` (one float64 array per column) or ``parquet`` (one float64 column each)."""
    arrays = {name: np.asarray(values, dtype=float) for name, values in cols.items()}
    if fmt == "npz":
        with open(part, "wb") as f:
            np.savez(f, **arrays)
        return
    import pyarrow as pa
    import pyarrow.parquet as pq

    pq.write_table(pa.table(arrays), part)


def write_outputs(result: CosimResult, out_dir, title: str | None = None, *, report: bool = True,
                  fmt: str = "csv", show_progress: bool | None = None) -> dict:
    """Write ``results.FMT``, ``metrics.json`` and (unless ``report`` is false) ``report.png`` into ``out_dir``.

    Parameters
    ----------
    result : CosimResult
    out_dir : str or Path
    title : str, optional
        Of the report.
    report : bool
        Draw ``report.png``.
    fmt : str
        One of :data:`RESULT_FORMATS` (:func:`check_format`): the table is ``results.csv``,
        ``results.npz`` or ``results.parquet``, with the same columns.
    show_progress : bool, optional
        A bar while the CSV is written (default: when stderr is a terminal).

    Notes
    -----
    ``results.csv`` has a column ``bound`` (the certified bound of each point) where the design certifies one, and
    ``metrics.json`` the key ``title`` when a title is given: with both, ``uiofmu report`` redraws the figure.

    The columns of ``results.csv`` keep their FMI names (``x[1]``, ``xhat[1]``, ...); where the problem names
    its states, inputs and outputs, ``metrics.json`` maps each such column to its label (``"labels": {"x[1]":
    "T_room [K]"}``), keeps the problem's names and units (``plant_labels``, for ``uiofmu report``), and the
    report's legends and axes use them.

    Returns
    -------
    dict
        The paths written.
    """
    out = check_output_dir(out_dir, "output folder")
    fmt = check_format(fmt)
    cols = result.columns()
    table = out / f"results.{fmt}"
    with atomic_output(table, "results table") as part:
        if fmt == "csv":
            _write_csv(cols, part, show_progress)
        else:
            _write_binary(cols, part, fmt)
    labels = result.column_labels()
    document = {**result.metrics, **({"labels": labels, "plant_labels": result.labels} if labels else {}),
                "results_file": table.name,
                **({"title": title} if title else {})}     # the names, units, table and title, for `uiofmu report`
    write_atomic(out / "metrics.json", json.dumps(document, indent=2) + "\n", "metrics")
    paths = {"results": table, "metrics": out / "metrics.json"}
    if report:
        from .report import plot_report     # matplotlib only when a figure is drawn

        paths["report"] = plot_report(result, out / "report.png", title)
    return paths


def load_inputs(csv_path, plant_path, observer_path=None):
    """Inputs from a CSV with a column for every input the FMUs take that no plant output feeds
    (the plant's ``u[i]``, ``d[i]``, ..., and the observer's others), and no other column; the FMUs'
    Integer inputs (``mode``) take fmi2Integer values only."""

    def ports(path):
        variables = read_description(path).modelVariables
        integers = {v.name[:v.name.index("[")] for v in variables
                    if v.causality == "input" and v.type == "Integer" and "[" in v.name}
        return vector_sizes(variables, "input"), vector_sizes(variables, "output"), integers

    sizes, outputs, integers = ports(plant_path)
    owners = dict.fromkeys(sizes, "plant")
    if observer_path is not None:
        observer_inputs, _, observer_integers = ports(observer_path)
        for name, size in observer_inputs.items():
            if name not in outputs and name not in sizes:
                sizes[name], owners[name] = size, "observer"
        integers |= observer_integers
    return CsvInputs(csv_path, sizes, owners, integers)


__all__ = ["OPTIONAL_PLANT_INPUTS", "CosimResult", "cosimulate", "default_inputs", "default_steps", "default_t_end",
           "driven_inputs", "load_inputs", "observer_card", "routes", "step_sequence", "write_outputs"]
