"""What an FMU exposes, for observers and plants alike (numpy only): :func:`make_model` builds the model of
an FMU's ``model.json``, an observer's from its card's kernel (:mod:`uiofmu.runtime.kernels`), a plant's from its
kind (:mod:`uiofmu.runtime.plant_kinds`).

A model lists its ports, each a named vector: parameters (set before initialisation),
inputs, and outputs (computed on demand and cached until an input or the state changes).
The pythonfmu slave (``uiofmu/fmu/templates/pythonfmu_slave.py.tmpl``) maps ports to FMI variables
``name[1..size]`` without knowing what the model is; the C backend generates the same ports.

States (:meth:`ObserverModel.get_state`, :meth:`PlantModel.get_state`) are plain JSON-ready
data; ``set_state`` checks every field before it changes anything, because the state an
importer hands back may be truncated, edited or another FMU's (:class:`StateRejected`).
"""

from __future__ import annotations


from .card import card_from_data
from .labels import check_labels
from .models import Port, StatefulModel
from .observer_models import DelayedModel, FunctionalModel, ObserverModel
from .plant_kinds import LINEAR, PlantKind, fmu_kind
from .schedules import StepRejected
from .state import StateRejected
from .stepping import RuntimeInputError


class PlantModel(StatefulModel):
    """A plant as FMU ports: ``u, d -> y, x``; parameters ``x0`` and the runtime's physical ones; ``labels``:
    the names and units of its model's ``labels`` (:func:`uiofmu.runtime.labels.check_labels`).

    The runtime is the one of its ``plant_kind`` (:class:`~uiofmu.runtime.plant_kinds.PlantKind`, which also
    declares its ports); every runtime holds ``x0``, ``u``, ``d``, ``x``, ``y()``, ``step(h)`` and its physical
    parameters ``param_names``, ``params``, ``apply_parameters()``.
    """

    kind = "plant"
    labels = None

    def __init__(self, rt, param_targets: dict | None = None, labels: dict | None = None,
                 plant_kind: PlantKind = LINEAR):
        self.rt = rt
        self.plant_kind = plant_kind
        self.labels = check_labels(labels or {}, {"n": rt.n, "m": rt.u.shape[0], "p": rt.p, "q": rt.d.shape[0]},
                                   "labels")
        physical = [(name, param_targets[name]) for name in rt.param_names] if param_targets else []
        arrays = {"x0": rt.x0.copy(), "u": rt.u, "d": rt.d,
                  **{name: rt.params[i:i + 1].copy() for i, name in enumerate(rt.param_names)},
                  **plant_kind.arrays(rt)}
        self._declare(plant_kind.declare(rt, physical), arrays)
        self.dirty = True

    def initialize(self) -> None:
        """Take the parameters (initial state, seed, physical parameters, mismatch) and reset.

        Raises
        ------
        StepRejected
            For a ``mismatch`` that is not a finite number >= 0 (or that makes a matrix entry overflow).
        """
        named = self.named
        self.rt.x0 = named["x0"].values.copy()
        if self.plant_kind.theta_parameters:
            self.rt.params[:] = named["theta"].values
        else:
            for i, name in enumerate(self.rt.param_names):
                self.rt.params[i] = named[name].values[0]
        self.rt.apply_parameters()
        if "seed" in named:
            self.rt.seed = int(named["seed"].values[0])
        if "mismatch" in named:
            self.rt.set_mismatch(float(named["mismatch"].values[0]), int(named["mismatch_seed"].values[0]))
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
    """The model of an FMU's ``resources/model.json`` (``resources``: where its files are): a plant's by its kind
    (:func:`uiofmu.runtime.plant_kinds.fmu_kind`), an observer's by its card's kernel."""
    kind = fmu_kind(spec)
    if kind is None:
        card = card_from_data(spec["card"])
        return card.stepper.model(card)
    rt, targets, labels = kind.start(spec, resources)
    return PlantModel(rt, targets, labels, kind)


__all__ = ["DelayedModel", "FunctionalModel", "ObserverModel", "PlantModel", "Port", "RuntimeInputError",
           "StateRejected", "StepRejected", "make_model"]
