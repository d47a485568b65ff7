"""The co-simulation master: plant FMU and observer FMU on fmpy, with aperiodic steps.

Order at each communication point t_k (SPEC): read the plant's ``y`` (and true ``x``); set
the plant's ``u``, ``d`` and the observer's ``y``, ``u``; read ``xhat`` (and ``r``,
``dhat``); then ``doStep(t_k, h_k)`` on both. Inputs are held over each step.

A delayed observer (kernel ``delayed``, seed 001) also takes the plant's ``ydot`` (set after the
plant's ``u`` of t_k, so it is ``C x'`` with the input of the step about to be taken); the master
records its ``thetahat``, ``sigma_min`` and ``valid`` at every point and compares ``thetahat`` with the
true ``theta``, read from the plant FMU's parameter ``theta`` (the observer never reads it).
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field

import numpy as np

from ..runtime.card import Card, card_from_data
from ..runtime.errors import FmuError
from ..runtime.files import atomic_output, check_output_dir, write_atomic
from ..families import certified_bound
from .fmi import Fmu, FmuCallError, read_model_json, vector_sizes
from .inputs import CsvInputs, SignalInputs
from .metrics import delayed_metrics, error_metrics, functional_metrics
from ..progress import progress
from ..runtime.observer import Runtime
from ..runtime.observer import default_horizon as default_t_end
from .steps import step_sequence


@dataclass
class CosimResult:
    """Histories of one co-simulation (row k is the communication point t_k) and its metrics."""

    times: np.ndarray
    h: np.ndarray
    x: np.ndarray
    xhat: np.ndarray
    y: np.ndarray
    u: np.ndarray
    d: np.ndarray
    r: np.ndarray
    dhat: np.ndarray
    metrics: dict = field(default_factory=dict)
    card: Card | None = None
    bound: np.ndarray | None = None
    mode: np.ndarray | None = None
    functional: dict | None = None
    delayed: dict | None = None

    def columns(self) -> dict:
        """Named columns for ``results.csv``."""
        cols = {"time": self.times, "h": np.append(self.h, np.nan)}
        for name in ("x", "xhat", "y", "u", "d", "dhat", "r"):
            arr = getattr(self, name)
            for i in range(arr.shape[1]):
                cols[f"{name}[{i + 1}]"] = arr[:, i]
        if self.mode is not None:
            cols["mode"] = self.mode
        if self.functional is not None:
            f = self.functional
            for i in range(f["gx"].shape[1]):
                cols[f"gx[{i + 1}]"], cols[f"gx_true[{i + 1}]"] = f["gx"][:, i], f["true"][:, i]
            cols["gx_valid"] = f["valid"]
            cols["error_norm"] = np.linalg.norm(f["gx"] - f["true"], axis=1)
            return cols
        cols["error_norm"] = np.linalg.norm(self.x - self.xhat, axis=1)
        if self.delayed is not None:
            dl = self.delayed
            for i in range(dl["thetahat"].shape[1]):
                cols[f"thetahat[{i + 1}]"] = dl["thetahat"][:, i]
            if dl["theta"] is not None:
                cols["theta_error_norm"] = np.linalg.norm(dl["thetahat"] - dl["theta"], axis=1)
            cols["sigma_min"], cols["valid"] = dl["sigma_min"], dl["valid"]
        return cols


def observer_card(path) -> Card:
    """The design card packed in an observer FMU built by uiofmu, checked against the card schema
    and with its certificate re-checked at the stored matrices (:func:`uiofmu.synthesis.recheck`)."""
    from ..synthesis import recheck

    spec = read_model_json(path)
    if spec.get("kind") != "observer" or "card" not in spec:
        raise FmuError(f"{path}: this FMU is not an observer built by uiofmu (its model is a "
                       f"{str(spec.get('kind'))[:40]!r})")
    card = card_from_data(spec["card"])
    recheck(card)
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


def cosimulate(plant_path, observer_path, steps: np.ndarray, inputs=None, *, plant_x0=None, xhat0=None,
               plant_parameters: dict | None = None, show_progress: bool | None = None) -> CosimResult:
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
        Has ``u(t)`` and ``d(t)``; by default the signals of the observer's problem.
    plant_x0, xhat0 : array_like, optional
        Override the plant's initial state and the observer's initial estimate.
    plant_parameters : dict, optional
        Other plant parameters to set before initialisation, by port name (e.g. ``{"seed": [7]}``
        for a plant switching at random, ``{"theta": [...]}`` for a plant with unknown parameters:
        the plant simulates them and the metrics compare ``thetahat`` with them).
    show_progress : bool, optional
        Progress bar (default: when stderr is a terminal).

    Returns
    -------
    CosimResult

    Raises
    ------
    FmuError
        When an FMU refuses a call, naming the FMU, the time, the step and its message.
    """
    card = observer_card(observer_path)
    if inputs is None:
        inputs = default_inputs(card)
    steps = np.asarray(steps, dtype=float)
    K = len(steps)
    with Fmu(plant_path, "plant") as plant, Fmu(observer_path, "observer") as obs:
        if not plant.has("x"):
            raise FmuError(f"{plant_path}: the plant FMU has no x[...] outputs; the error needs the true state")
        fed, sourced = routes(plant, obs, inputs.sizes)
        plant.initialize(0.0, {**(plant_parameters or {}), **({"x0": plant_x0} if plant_x0 is not None else {})})
        obs.initialize(0.0, {"xhat0": xhat0} if xhat0 is not None else None)
        # the true parameters of a plant with unknown ones, as the plant FMU simulates them
        theta_true = plant.get("theta") if "theta" in plant.ports("parameter") else None
        n, p = len(plant.refs("x")), len(plant.refs("y"))
        m, q = len(plant.refs("u")), len(plant.refs("d"))
        T = np.zeros(K + 1)
        X, Y = np.zeros((K + 1, n)), np.zeros((K + 1, p))
        U, D = np.zeros((K + 1, m)), np.zeros((K + 1, q))
        H = {name: np.zeros((K + 1, size)) for name, size in obs.ports("output").items()}
        plant_inputs = list(plant.ports("input"))
        MODE = np.zeros(K + 1) if obs.has("mode") else None
        t = 0.0
        with progress(total=K, desc="co-simulation", unit="step", enabled=show_progress) as bar:
            for k in range(K + 1):
                values = inputs.values(t)
                for name in plant_inputs:
                    plant.set(name, values[name])
                for name in fed:
                    obs.set(name, plant.get(name))
                for name in sourced:
                    obs.set(name, values[name])
                y = plant.get("y")
                T[k], X[k], Y[k] = t, plant.get("x"), y
                if MODE is not None:
                    MODE[k] = (plant.get("mode") if "mode" in fed else np.round(values["mode"]))[0]
                U[k], D[k] = values.get("u", U[k]), values.get("d", D[k])
                for name, history in H.items():
                    history[k] = obs.get(name)
                if k == K:
                    break
                h = steps[k]
                for who, fmu in (("observer", obs), ("plant", plant)):
                    try:
                        fmu.step(t, h)
                    except FmuCallError as exc:
                        raise FmuError(f"the {who} FMU refused step {k} (t = {t:g} s, h = {h:g} s): "
                                       + (exc.messages[-1] if exc.messages else str(exc))) from None
                t = float(np.sum(steps[:k + 1])) if k % 1024 == 1023 else t + h
                bar.update()
    if card.kernel == "window":
        return _functional_result(card, T, steps, X, Y, U, D, H, MODE)
    if card.kernel == "delayed":
        return _delayed_result(card, T, steps, X, Y, U, D, H, theta_true)
    XH, R = H["xhat"], H["r"]
    DH = H.get("dhat", np.zeros((K + 1, 0)))
    nq = DH.shape[1]
    result = CosimResult(T, steps, X, XH, Y, U, D, R, DH, card=card, mode=MODE)
    bound = certified_bound(card, X[0] - XH[0], D)
    result.bound = bound
    result.metrics = error_metrics(T, steps, X, XH, bound, card.data.get("decay_bound"),
                                   card.data.get("overshoot_bound"), D if nq else None, DH if nq else None)
    if bound is not None:
        text = card.data.get("bound", "")
        if card.data.get("overshoot_bound") is not None:
            text = (text.replace("overshoot_bound", f"{card.data['overshoot_bound']:.4g}")
                    .replace("decay_bound**k", f"{card.data['decay_bound']:.6g}^k"))
        result.metrics["bound_formula"] = text
    if MODE is not None:
        result.metrics["modes"] = {"switches": int(np.count_nonzero(np.diff(MODE[:-1]))),
                                   "steps_in_mode": {str(int(i)): int(np.count_nonzero(MODE[:-1] == i))
                                                     for i in np.unique(MODE[:-1])}}
    return result


def _functional_result(card, T, steps, X, Y, U, D, H, MODE) -> CosimResult:
    """The run of a functional observer (window kernel): ``gx`` against ``G x`` of the point
    ``delay`` steps back (NaN before there is one), and :func:`functional_metrics`."""
    G = np.asarray(card.data["matrices"]["G"], dtype=float)
    delay, K1 = int(card.schedule["delay"]), len(T)
    true = np.full((K1, G.shape[0]), np.nan)
    true[delay:] = X[:K1 - delay] @ G.T
    empty = np.zeros((K1, 0))
    result = CosimResult(T, steps, X, empty, Y, U, D, empty, empty, card=card, mode=MODE,
                         functional={"gx": H["gx"], "true": true, "valid": H["gx_valid"][:, 0]})
    result.metrics = functional_metrics(T, steps, H["gx"], true, H["gx_valid"][:, 0], delay,
                                        int(card.schedule["length"]))
    result.metrics["formula"] = card.data.get("formula", "")
    return result


def _delayed_result(card, T, steps, X, Y, U, D, H, theta_true) -> CosimResult:
    """The run of a delayed observer (seed 001): the state error metrics, :func:`delayed_metrics`
    (theta against the plant's true theta, validity), and no certified bound: the card's bound holds
    on its premise set only, which a run is not known to stay in."""
    K1 = len(T)
    empty = np.zeros((K1, 0))
    valid = H["valid"][:, 0]
    sigma_bound = float(card.schedule["sigma_bound"])
    theta = None if theta_true is None or theta_true.size != H["thetahat"].shape[1] else theta_true
    result = CosimResult(T, steps, X, H["xhat"], Y, U, D, H["r"], empty, card=card,
                         delayed={"thetahat": H["thetahat"], "theta": theta, "sigma_min": H["sigma_min"][:, 0],
                                  "valid": valid, "sigma_bound": sigma_bound})
    result.metrics = error_metrics(T, steps, X, H["xhat"])
    result.metrics.update(delayed_metrics(T, steps, X, H["xhat"], H["thetahat"], theta, valid, H["sigma_min"][:, 0],
                                          sigma_bound, card.data.get("bound", "")))
    return result


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
    outputs, plant_in, obs_in = plant.ports("output"), plant.ports("input"), obs.ports("input")
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


def write_outputs(result: CosimResult, out_dir, title: str | None = None) -> dict:
    """Write ``results.csv``, ``metrics.json`` and ``report.png`` into ``out_dir``.

    Returns
    -------
    dict
        The paths written.
    """
    from .report import plot_report

    out = check_output_dir(out_dir, "output folder")
    cols = result.columns()
    with atomic_output(out / "results.csv", "results table") as part, open(part, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        for row in zip(*cols.values()):
            w.writerow(["" if isinstance(v, float) and math.isnan(v) else repr(float(v)) for v in row])
    write_atomic(out / "metrics.json", json.dumps(result.metrics, indent=2) + "\n", "metrics")
    plot_report(result, out / "report.png", title)
    return {"results": out / "results.csv", "metrics": out / "metrics.json", "report": out / "report.png"}


def load_inputs(csv_path, plant_path, observer_path=None):
    """Inputs from a CSV with a column for every input the FMUs take that no plant output feeds
    (the plant's ``u[i]``, ``d[i]``, ..., and the observer's others), and no other column."""
    from fmpy import read_model_description

    def inputs_and_outputs(path):
        try:
            variables = read_model_description(str(path)).modelVariables
        except Exception as exc:  # noqa: BLE001 - fmpy raises plain exceptions for broken archives
            raise FmuError(f"{path}: not a readable FMU ({exc})") from None
        return vector_sizes(variables, "input"), vector_sizes(variables, "output")

    sizes, outputs = inputs_and_outputs(plant_path)
    owners = dict.fromkeys(sizes, "plant")
    if observer_path is not None:
        for name, size in inputs_and_outputs(observer_path)[0].items():
            if name not in outputs and name not in sizes:
                sizes[name], owners[name] = size, "observer"
    return CsvInputs(csv_path, sizes, owners)


__all__ = ["CosimResult", "cosimulate", "default_inputs", "default_steps", "default_t_end", "load_inputs",
           "observer_card", "routes", "step_sequence", "write_outputs"]
