"""SSP 1.0 bundles of the whole loop: the plant, the observer and a signal source, connected by name.

An SSP file (System Structure and Parameterization 1.0, a zip) holds ``SystemStructure.ssd`` and the
FMUs in ``resources/``. SSP binds only constant values to inputs, so the problem's time-varying inputs
(its ``[signals]``, or an input table) are played by a third FMU, the C signal source
(:mod:`uiofmu.fmu.signal_source`); its outputs and the plant's are connected to the inputs of the same
name, as the master routes them (:func:`uiofmu.cosim.master.routes`):

* every plant input (``u``, ``d``, and ``mode`` or ``theta`` where the plant takes them) from the source;
* every observer input named like a plant output (``y``; ``mode``, ``theta``, ``ydot`` where the plant
  gives them) from the plant, every other (``u``, ...) from the source.

The bundle's ``<DefaultExperiment>`` is the observer's (its stop time, and its step as the fixed step
of the Open Simulation Platform's annotation, which libcosim reads). From the ``[signals]`` the source
holds a table of their values at the communication points of that experiment, exactly what
``uiofmu cosim`` with ``--steps fixed:STEP`` evaluates; from an input table it holds the table's rows, each
held from its time, as ``uiofmu cosim --inputs`` does.

An importer that steps every FMU and then passes outputs to inputs (a Jacobi loop, as libcosim does)
gives the plant the same inputs as our master, and the observer the same ``y`` before each step, so the
plant's state and the observer's internal state are the master's; it reads the observer's outputs
before it passes the new ``y``, so an output that depends on ``y`` at the same point (``xhat = Xz z +
Xy y``) shows that direct part one step late there (docs/ssp.md).
"""

from __future__ import annotations

import math
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path
from xml.etree.ElementTree import Element, SubElement, register_namespace, tostring

import numpy as np

from ..fmu.signal_source import SignalTable, build_source
from ..runtime.errors import FmuError, ProblemError
from ..runtime.files import atomic_output, check_output_file
from ..runtime.ports import experiment as checked_experiment
from .fmi import read_description, vector_sizes
from .inputs import CsvInputs, values_at
from .master import check_integers, communication_points, default_inputs, driven_inputs, observer_card, routes

SSD = "http://ssp-standard.org/SSP1/SystemStructureDescription"
SSC = "http://ssp-standard.org/SSP1/SystemStructureCommon"
#: The namespace of the Open Simulation Platform's annotations (libcosim's fixed-step algorithm).
OSP = "http://opensimulationplatform.com/SSP/OSPAnnotations"
#: The names of the components in the bundle (and of their FMUs in ``resources/``).
SOURCE, PLANT, OBSERVER = "source", "plant", "observer"
#: Most steps of a bundle's default experiment from ``[signals]`` (rows of the source's table).
MAX_STEPS = 10_000_000

for _prefix, _uri in (("ssd", SSD), ("ssc", SSC), ("osp", OSP)):
    register_namespace(_prefix, _uri)


@dataclass(frozen=True)
class Connection:
    """One connection of the bundle: ``start`` component's output ``connector`` to the ``end``
    component's input of the same name."""

    start: str
    end: str
    connector: str


@dataclass(frozen=True)
class SspBundle:
    """What :func:`write_ssp` wrote.

    Attributes
    ----------
    path : Path
        The ``.ssp`` file.
    experiment : dict
        Its default experiment: ``startTime``, ``stopTime``, ``stepSize`` (s).
    connections : tuple of Connection
    table : SignalTable
        What the signal source plays.
    """

    path: Path
    experiment: dict
    connections: tuple
    table: SignalTable

    @property
    def steps(self) -> int:
        """Steps of its default experiment."""
        return int(round(self.experiment["stopTime"] / self.experiment["stepSize"]))


class _Ports:
    """The vectors of an FMU's model description by causality (what :func:`routes` asks), and each
    variable's type."""

    def __init__(self, path):
        self.description = read_description(path)
        self.types = {v.name: v.type for v in self.description.modelVariables}

    def ports(self, causality: str) -> dict:
        return vector_sizes(self.description.modelVariables, causality)

    def integer(self, name: str) -> bool:
        return self.types.get(f"{name}[1]") == "Integer"


def loop_experiment(observer: _Ports, card) -> dict:
    """The observer FMU's ``<DefaultExperiment>`` (start 0, its stop time and step), else its card's."""
    from ..runtime.ports import observer_experiment

    exp = observer.description.defaultExperiment
    if exp is None or exp.stepSize is None or exp.stopTime is None:
        return observer_experiment(card)
    if float(exp.startTime or 0.0) != 0.0:
        raise FmuError(f"the observer's default experiment starts at {exp.startTime} s; a bundle starts at 0")
    try:
        return checked_experiment(float(exp.stepSize), float(exp.stopTime))
    except ValueError as exc:
        raise FmuError(f"the observer FMU's {exc}") from None


def loop_table(inputs, sizes: dict, experiment: dict, integers=()) -> SignalTable:
    """What the signal source plays for the vectors ``sizes``: an input table's rows, or the input
    source's values at the communication points of ``experiment`` (fixed steps of ``stepSize`` to
    ``stopTime``, summed as :func:`uiofmu.cosim.master.communication_points` sums them).

    Raises
    ------
    ProblemError
        For a mode that is not an fmi2Integer, or a run of more than :data:`MAX_STEPS` steps.
    """
    if isinstance(inputs, CsvInputs):
        return SignalTable(inputs.times, {name: inputs.tables[name] for name in sizes}, f"--inputs {inputs.path}")
    step, stop = experiment["stepSize"], experiment["stopTime"]
    count = stop / step
    if not count <= MAX_STEPS:
        raise ProblemError(f"the default experiment's {count:.3g} steps of {step:g} s are more than {MAX_STEPS}")
    K = max(int(math.ceil(count - 1e-9)), 1)
    times = communication_points(np.full(K, step))
    got = values_at(inputs, times)
    check_integers(inputs, got, times, [name for name in integers if name in sizes])
    return SignalTable(times, {name: got[name] for name in sizes}, "signals")


def write_ssp(plant_path, observer_path, output, inputs=None, *, name: str | None = None) -> SspBundle:
    """Bundle a plant FMU, an observer FMU built by uiofmu and a signal source of the inputs into an SSP
    1.0 file.

    Parameters
    ----------
    plant_path, observer_path : str or Path
        The FMUs (see :func:`uiofmu.cosim.master.cosimulate`).
    output : str or Path
        The ``.ssp`` file to write (atomically).
    inputs : object, optional
        An input source (:mod:`uiofmu.cosim.inputs`): by default the ``[signals]`` of the observer's problem;
        a :class:`~uiofmu.cosim.inputs.CsvInputs` is played row by row.
    name : str, optional
        The system's name (default: the observer's card's name).

    Returns
    -------
    SspBundle

    Raises
    ------
    FmuError
        For FMUs that do not fit (an input nothing feeds, sizes that differ), naming the input.
    ProblemError
        For inputs that are not valid (a mode that is not an integer, a run too long).
    """
    output = check_output_file(output, "SSP", ".ssp")
    card = observer_card(observer_path)
    plant, obs = _Ports(plant_path), _Ports(observer_path)
    inputs = default_inputs(card) if inputs is None else inputs
    fed, sourced = routes(plant, obs, inputs.sizes)
    driven = {k: plant.ports("input")[k] for k in driven_inputs(plant, inputs.sizes)}   # not w_noise: left at 0
    sizes = {**driven, **{k: obs.ports("input")[k] for k in sourced}}
    integers = [k for k in sizes if (k in plant.ports("input") and plant.integer(k)) or
                (k in sourced and obs.integer(k))]
    experiment = loop_experiment(obs, card)
    table = loop_table(inputs, sizes, experiment, integers)
    connections = ([Connection(PLANT, OBSERVER, f"{k}[{i}]") for k in fed for i in range(1, obs.ports("input")[k] + 1)]
                   + [Connection(SOURCE, OBSERVER, f"{k}[{i}]") for k in sourced
                      for i in range(1, obs.ports("input")[k] + 1)]
                   + [Connection(SOURCE, PLANT, f"{k}[{i}]") for k, n in driven.items() for i in range(1, n + 1)])
    with tempfile.TemporaryDirectory(prefix="uiofmu_ssp_") as tmp:
        source_path = build_source(table, Path(tmp) / f"{SOURCE}.fmu", experiment=experiment)
        types = {SOURCE: {f"{k}[{i}]": ("Integer" if k == "mode" else "Real") for k, n in table.sizes.items()
                          for i in range(1, n + 1)},
                 PLANT: plant.types, OBSERVER: obs.types}
        ssd = system_structure(name or card.name, connections, types, experiment)
        with atomic_output(output, "SSP file") as part, zipfile.ZipFile(part, "w", zipfile.ZIP_DEFLATED) as z:
            z.writestr("SystemStructure.ssd", ssd)
            for component, path in ((SOURCE, source_path), (PLANT, plant_path), (OBSERVER, observer_path)):
                z.write(path, f"resources/{component}.fmu")
    return SspBundle(output, experiment, tuple(connections), table)


def system_structure(name: str, connections, types: dict, experiment: dict) -> bytes:
    """``SystemStructure.ssd``: the three components with the connectors their connections use
    (``types``: ``{component: {variable: "Real" | "Integer"}}``), the connections, and the default
    experiment with its step as the Open Simulation Platform's fixed-step annotation."""
    root = Element(f"{{{SSD}}}SystemStructureDescription", {"version": "1.0", "name": str(name)})
    system = SubElement(root, f"{{{SSD}}}System", {"name": "loop",
                                                   "description": "plant, observer and the source of their inputs"})
    elements = SubElement(system, f"{{{SSD}}}Elements")
    used = {}
    for c in connections:
        used.setdefault(c.start, {})[c.connector] = "output"
        used.setdefault(c.end, {})[c.connector] = "input"
    for component in (SOURCE, PLANT, OBSERVER):
        element = SubElement(elements, f"{{{SSD}}}Component", {
            "name": component, "source": f"resources/{component}.fmu", "type": "application/x-fmu-sharedlibrary"})
        connectors = SubElement(element, f"{{{SSD}}}Connectors")
        for variable, kind in used.get(component, {}).items():
            kind_type = types[component].get(variable)
            if kind_type not in ("Real", "Integer"):
                raise FmuError(f"the {component} FMU has no Real or Integer variable {variable}")
            connector = SubElement(connectors, f"{{{SSD}}}Connector", {"name": variable, "kind": kind})
            SubElement(connector, f"{{{SSC}}}{kind_type}")
    links = SubElement(system, f"{{{SSD}}}Connections")
    for c in connections:
        SubElement(links, f"{{{SSD}}}Connection", {"startElement": c.start, "startConnector": c.connector,
                                                   "endElement": c.end, "endConnector": c.connector})
    default = SubElement(root, f"{{{SSD}}}DefaultExperiment", {"startTime": "0.0",
                                                               "stopTime": repr(float(experiment["stopTime"]))})
    annotation = SubElement(SubElement(default, f"{{{SSD}}}Annotations"), f"{{{SSC}}}Annotation",
                            {"type": "com.opensimulationplatform"})
    SubElement(SubElement(annotation, f"{{{OSP}}}Algorithm"), f"{{{OSP}}}FixedStepAlgorithm",
               {"baseStepSize": repr(float(experiment["stepSize"]))})
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + tostring(root, encoding="utf-8")


__all__ = ["Connection", "SspBundle", "loop_experiment", "loop_table", "system_structure", "write_ssp"]
