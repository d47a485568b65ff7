"""What an FMU exposes, for observers and plants alike (numpy only).

A model lists its ports, each a named vector: parameters (set before initialisation),
inputs, and outputs (computed on demand and cached until an input or the state changes).
The pythonfmu slave (``uiofmu/fmu/templates/pythonfmu_slave.py.tmpl``) maps ports to FMI variables
``name[1..size]`` without knowing what the model is; the C backend generates the same ports.

States (:meth:`ObserverModel.get_state`, :meth:`PlantModel.get_state`) are plain JSON-ready
data; ``set_state`` checks every field before it changes anything, because the state an
importer hands back may be truncated, edited or another FMU's (:class:`StateRejected`).
"""

from __future__ import annotations

import numpy as np

from .card import card_from_data
from .labels import check_labels
from .plant_runtime import PlantRuntime
from .ports import PortSpec, lpv_plant_ports, parametric_plant_ports, plant_ports
from .observer import Runtime, RuntimeInputError
from .schedules import StepRejected
from .state import StateReader, StateRejected


def _port_values(r: StateReader, key: str, ports: list) -> list:
    """The port values of a state: one list per port, of ``port.size`` numbers each (they are
    what the master sets through fmi2SetReal, so they may be non-finite: the FMU checks them
    where they are used, at initialisation and at each step)."""
    values = r.state[key]
    if not isinstance(values, (list, tuple)) or len(values) != len(ports):
        found = f"{len(values)} entries" if isinstance(values, (list, tuple)) else type(values).__name__
        raise StateRejected(f"{r.what} state field {key!r}: expected {len(ports)} lists (one per port), found {found}")
    out = [r.vector(f"{key}.{port.name}", port.size, finite=False, value=vals) for port, vals in zip(ports, values)]
    for port, vals in zip(ports, out):
        if port.spec.type == "Integer" and not np.all((vals == np.round(vals)) & (np.abs(vals) <= 2 ** 31)):
            raise StateRejected(f"{r.what} state field '{key}.{port.name}': expected integers (an fmi2Integer), "
                                f"found {vals.tolist()}")
    return out


class Port:
    """A declared port (:class:`~uiofmu.runtime.ports.PortSpec`) with the array holding its values."""

    def __init__(self, spec: PortSpec, values: np.ndarray):
        if values.shape != (spec.size,):
            raise ValueError(f"port {spec.name}: {values.shape[0]} values for a port of size {spec.size}")
        self.spec = spec
        self.values = values

    name = property(lambda self: self.spec.name, doc="The port's name.")
    key = property(lambda self: self.spec.key, doc="The port in code (:attr:`PortSpec.key`): what ``named`` uses.")
    description = property(lambda self: self.spec.description, doc="What the port carries.")
    causality = property(lambda self: self.spec.causality, doc="parameter, input or output.")
    depends = property(lambda self: self.spec.depends, doc="The input ports an output depends on.")

    @property
    def size(self) -> int:
        """Number of scalar variables."""
        return self.spec.size


class PortsModel:
    """A model's ports: all of them in declaration order (``ports``, the order of their value
    references) and by causality (``parameters``, ``inputs``, ``outputs``)."""

    def _declare(self, specs: list, arrays: dict) -> None:
        """Each declared port over its array in ``arrays`` (by the port's key; a new zero vector where
        none). Values are floats for every type: an Integer port holds integral values (every C int is
        exact). ``named`` finds a port by its key (its name unless the declaration renamed it)."""
        self.ports = [Port(s, np.zeros(s.size) if arrays.get(s.key) is None else arrays[s.key]) for s in specs]
        self.parameters, self.inputs, self.outputs = ([p for p in self.ports if p.causality == c]
                                                      for c in ("parameter", "input", "output"))
        self.named = {p.key: p for p in self.ports}


class StatefulModel(PortsModel):
    """What observer and plant models share: their state is the runtime's plus the parameter ports'."""

    kind = "model"

    @property
    def labels(self) -> dict:
        """Names and units of the ports' elements (:mod:`uiofmu.runtime.labels`): an observer's from its card."""
        return self.card.labels

    def get_state(self) -> dict:
        """JSON-ready state.

        Returns
        -------
        dict
            ``runtime`` (the runtime's ``get_state``) and ``parameters`` (the parameter ports'
            values, one list per port: the master may have set them after the last initialisation).
        """
        self._ports_to_runtime()
        return {"runtime": self.rt.get_state(), "parameters": [p.values.tolist() for p in self.parameters]}

    def _ports_to_runtime(self) -> None:
        """Hand the inputs the runtime keeps outside the ports' arrays (a mode) to the runtime."""

    def _runtime_to_ports(self) -> None:
        """The reverse, after a state restore: those inputs' ports take the restored values."""

    def set_state(self, state: dict) -> None:
        """Restore :meth:`get_state`; nothing changes unless every field is valid.

        Parameters
        ----------
        state : dict

        Raises
        ------
        StateRejected
            The field that is missing, unknown or malformed is named.
        """
        r = StateReader(state, ("runtime", "parameters"), self.kind)
        params = _port_values(r, "parameters", self.parameters)
        self.rt.set_state(state["runtime"])               # checks everything before it changes
        for port, values in zip(self.parameters, params):
            port.values[:] = values
        self._runtime_to_ports()
        self.dirty = True


class ObserverModel(StatefulModel):
    """The observer of a design card as FMU ports: ``y, u -> xhat, r, dhat``."""

    kind = "observer"

    def __init__(self, spec: dict):
        self.card = card_from_data(spec["card"])
        self.rt = Runtime(self.card)
        arrays = {"xhat0": self.rt.xhat0.copy(), "h_prev0": np.array([self.rt.h_prev0]), "y": self.rt.y,
                  "u": self.rt.u, "mode_prev0": np.array([float(self.rt.mode_prev0)]),
                  "mode": np.array([float(self.rt.mode)])}
        self._declare(self.card.ports, arrays)
        self.dirty = True

    def initialize(self) -> None:
        """Take the parameters (called when leaving initialisation mode); raises StepRejected
        for an h_prev0 that is not a design interval or a mode_prev0 that is not a mode, and
        then nothing has changed."""
        named = self.named
        if "h_prev0" in named:                         # checked before anything changes
            h_prev0 = float(named["h_prev0"].values[0])
            self.rt.schedule.output_matrices(0, h_prev0)
            self.rt.h_prev0 = h_prev0
        if "mode_prev0" in named:
            mode_prev0 = int(named["mode_prev0"].values[0])
            try:
                self.rt.schedule.index(mode_prev0, "mode_prev0")
            except ValueError as exc:
                raise StepRejected(str(exc)) from None
            self.rt.mode_prev0 = mode_prev0
        self.rt.xhat0 = named["xhat0"].values.copy()
        self.rt.reset()
        self.dirty = True

    def notices(self) -> list:
        """Messages the schedule left for the log (drained)."""
        out = list(self.rt.schedule.notices)
        self.rt.schedule.notices.clear()
        return out

    def refresh(self) -> None:
        """Recompute the outputs from the current inputs and state."""
        named = self.named
        named["xhat"].values[:] = self.rt.xhat()
        named["r"].values[:] = self.rt.residual()
        if self.rt.has_dhat:
            named["dhat"].values[:] = self.rt.dhat()
        self.dirty = False

    def _ports_to_runtime(self) -> None:
        if "mode" in self.named:
            self.rt.set_mode(int(self.named["mode"].values[0]))

    def _runtime_to_ports(self) -> None:
        if "mode" in self.named:
            self.named["mode"].values[0] = self.rt.mode

    def step(self, t: float, h: float) -> None:
        """One communication step; raises StepRejected or RuntimeInputError."""
        self._ports_to_runtime()
        self.rt.step(h)
        self.dirty = True


class FunctionalModel(StatefulModel):
    """A window-kernel observer (:mod:`uiofmu.runtime.window`) as FMU ports: ``y, theta -> gx, gx_valid``."""

    kind = "observer"

    def __init__(self, spec: dict):
        from .window import WindowRuntime

        self.card = card_from_data(spec["card"])
        self.rt = WindowRuntime(self.card)
        self._declare(self.card.ports, {"y": self.rt.y, "theta": self.rt.theta})
        self.dirty = True

    def initialize(self) -> None:
        """No parameters: back to an empty window."""
        self.rt.reset()
        self.dirty = True

    def notices(self) -> list:
        """Messages for the log (none)."""
        return []

    def refresh(self) -> None:
        """Recompute ``gx`` and ``gx_valid`` from the window and the current inputs."""
        self.named["gx"].values[:] = self.rt.gx()
        self.named["gx_valid"].values[0] = 1.0 if self.rt.valid else 0.0
        self.dirty = False

    def step(self, t: float, h: float) -> None:
        """One communication step; raises StepRejected or RuntimeInputError."""
        self.rt.step(h)
        self.dirty = True


class DelayedModel(StatefulModel):
    """A delayed-kernel observer (:mod:`uiofmu.runtime.delayed`) as FMU ports:
    ``y, ydot, u -> xhat, thetahat, r, sigma_min, valid``."""

    kind = "observer"

    def __init__(self, spec: dict):
        from .delayed import DelayedRuntime

        self.card = card_from_data(spec["card"])
        self.rt = DelayedRuntime(self.card)
        self._declare(self.card.ports, {"xhat0": self.rt.xhat0.copy(), "y": self.rt.y, "ydot": self.rt.ydot,
                                        "u": self.rt.u})
        self.dirty = True

    def initialize(self) -> None:
        """Take ``xhat0`` and start over (empty delay buffer)."""
        self.rt.xhat0 = self.named["xhat0"].values.copy()
        self.rt.reset()
        self.dirty = True

    def notices(self) -> list:
        """The kernel's notes for the log (validity lost; drained)."""
        out = list(self.rt.notices)
        self.rt.notices.clear()
        return out

    def refresh(self) -> None:
        """Recompute the outputs from the current inputs and state."""
        named = self.named
        named["xhat"].values[:] = self.rt.xhat()
        named["thetahat"].values[:] = self.rt.theta()
        named["r"].values[:] = self.rt.residual()
        named["sigma_min"].values[0] = self.rt.margin()
        named["valid"].values[0] = 1.0 if self.rt.valid else 0.0
        self.dirty = False

    def step(self, t: float, h: float) -> None:
        """One communication step; raises StepRejected or RuntimeInputError."""
        self.rt.step(h)
        self.dirty = True


class PlantModel(StatefulModel):
    """A plant as FMU ports: ``u, d -> y, x``; parameters ``x0`` and the runtime's physical ones; ``labels``:
    the names and units of its model's ``labels`` (:func:`uiofmu.runtime.labels.check_labels`).

    The runtime is a linear :class:`~uiofmu.runtime.plant_runtime.PlantRuntime` or a
    :class:`~uiofmu.runtime.mujoco_runtime.MujocoRuntime`; both hold ``x0``, ``u``, ``d``, ``x``, ``y()``,
    ``step(h)`` and their physical parameters ``param_names``, ``params``, ``apply_parameters()``.
    """

    kind = "plant"
    labels = None

    def __init__(self, rt, param_targets: dict | None = None, labels: dict | None = None):
        self.rt = rt
        self.labels = check_labels(labels or {}, {"n": rt.n, "m": rt.u.shape[0], "p": rt.p, "q": rt.d.shape[0]},
                                   "labels")
        physical = [(name, param_targets[name]) for name in rt.param_names] if param_targets else []
        arrays = {"x0": rt.x0.copy(), "u": rt.u, "d": rt.d,
                  **{name: rt.params[i:i + 1].copy() for i, name in enumerate(rt.param_names)}}
        rule = getattr(rt, "rule", None)
        if rule is not None:
            arrays.update(seed=np.array([float(rt.seed)]), mode=np.array([float(rt.mode_in)]))
        if hasattr(rt, "theta_in"):
            arrays["theta"] = rt.theta_in if rt.kind == "input" else None
            specs = lpv_plant_ports(rt.n, rt.p, rt.q, rt.s, rt.kind, bool(np.any(rt.parts["D"])))
        elif hasattr(rt, "ydot"):
            arrays["theta"] = rt.params.copy()
            specs = parametric_plant_ports(rt.n, rt.m, rt.p, rt.params.size)
        else:
            specs = plant_ports(rt.n, rt.u.shape[0], rt.p, rt.d.shape[0], physical, rule)
        self._declare(specs, arrays)
        self.dirty = True

    def initialize(self) -> None:
        """Take the parameters (initial state, seed, physical parameters) and reset."""
        named = self.named
        self.rt.x0 = named["x0"].values.copy()
        if hasattr(self.rt, "ydot"):
            self.rt.params[:] = named["theta"].values
        else:
            for i, name in enumerate(self.rt.param_names):
                self.rt.params[i] = named[name].values[0]
        self.rt.apply_parameters()
        if "seed" in named:
            self.rt.seed = int(named["seed"].values[0])
        self.rt.reset()
        self.dirty = True

    def _ports_to_runtime(self) -> None:
        port = self.named.get("mode")
        if port is not None and port.causality == "input":
            self.rt.mode_in = int(port.values[0])

    def _runtime_to_ports(self) -> None:
        port = self.named.get("mode")
        if port is not None and port.causality == "input":
            port.values[0] = self.rt.mode_in

    def refresh(self) -> None:
        """Recompute the outputs."""
        self._ports_to_runtime()
        self.named["y"].values[:] = self.rt.y()
        self.named["x"].values[:] = self.rt.x
        port = self.named.get("mode")
        if port is not None and port.causality == "output":
            port.values[0] = self.rt.mode()
        port = self.named.get("theta")
        if port is not None and port.causality == "output":
            port.values[:] = self.rt.theta()
        if "ydot" in self.named:
            self.named["ydot"].values[:] = self.rt.ydot()
        self.dirty = False

    def step(self, t: float, h: float) -> None:
        """One communication step; raises RuntimeInputError."""
        self._ports_to_runtime()
        self.rt.step(h)
        self.dirty = True

    def notices(self) -> list:
        """Messages for the log (none for plants)."""
        return []


def make_model(spec: dict, resources: str = "."):
    """The model of an FMU's ``resources/model.json`` (``resources``: where its files are)."""
    if spec["kind"] == "mujoco":
        from .mujoco_runtime import MujocoRuntime

        return PlantModel(MujocoRuntime(spec["mujoco"], resources), spec["mujoco"].get("parameters", {}))
    if spec["kind"] == "plant":
        labels = spec.get("labels")
        if "parameters" in spec["plant"]:
            from .parametric_plant import ParametricPlantRuntime

            return PlantModel(ParametricPlantRuntime(spec["plant"]), labels=labels)
        if "scheduling" in spec["plant"]:
            from .lpv import LpvPlantRuntime

            return PlantModel(LpvPlantRuntime(spec["plant"]), labels=labels)
        if "modes" in spec["plant"]:
            from .switching import SwitchedPlantRuntime

            return PlantModel(SwitchedPlantRuntime(spec["plant"]), labels=labels)
        return PlantModel(PlantRuntime(spec["plant"]), labels=labels)
    if spec["card"].get("kernel") == "window":
        return FunctionalModel(spec)
    if spec["card"].get("kernel") == "delayed":
        return DelayedModel(spec)
    return ObserverModel(spec)


__all__ = ["DelayedModel", "FunctionalModel", "ObserverModel", "PlantModel", "Port", "RuntimeInputError",
           "StateRejected", "StepRejected", "make_model"]
