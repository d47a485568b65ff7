"""What an FMU's model is made of, for observers and plants alike (numpy only): its ports, each a named
vector (parameters set before initialisation, inputs, and outputs computed on demand and cached until an
input or the state changes), and a state that is plain JSON-ready data. ``set_state`` checks every field
before it changes anything, because the state an importer hands back may be truncated, edited or another
FMU's (:class:`~uiofmu.runtime.state.StateRejected`).
"""

from __future__ import annotations

import numpy as np

from .ports import PortSpec
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


__all__ = ["Port", "PortsModel", "StatefulModel"]
