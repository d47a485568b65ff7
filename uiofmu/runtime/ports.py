"""The ports of an FMU, declared once: the models, ``modelDescription.xml`` and the C tables use it.

A port is a named vector of FMI variables ``name[1..size]`` of one causality and one type. Its
value references are the positions of its elements in the declaration: the ports in order,
each element after the other, from 0. Its ``key`` names it in code (the models' arrays, the C
kernels' port ids), its ``name`` in the FMU: a port renamed here (its key kept) is renamed in
both backends. An output declares the inputs it depends on at the same communication point
(``depends``): ``xhat = Xz z + Xy y`` depends on ``y`` when the kernel feeds ``y`` through, the
plant's ``y = C x`` on none; importers that check for algebraic loops read it from
``<ModelStructure>``.

The declaration of an observer follows from its card (kernel, dims, schedule, dhat) and is
written into the card by ``uiofmu design``; :func:`check_declared` refuses a card whose
declaration differs from the one its kernel implements.

The kernels the C backend implements list every port they may have in :data:`KERNEL_PORTS`, in
the order of their C port ids; their declaration functions pick and size those ports, and the C
backend generates each kernel's port header (ids, names, causalities, types) from them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from .errors import CardError
from .experiments import default_horizon
from .schedules import make_schedule

CAUSALITIES = ("parameter", "input", "output")
TYPES = ("Real", "Integer")


@dataclass(frozen=True)
class PortSpec:
    """One port.

    Attributes
    ----------
    name : str
        FMI variables are ``name[1]`` .. ``name[size]``.
    size : int
    causality : {"parameter", "input", "output"}
        Parameters are fixed (set before initialisation), inputs continuous, outputs computed.
    description : str
    type : {"Real", "Integer"}
    depends : tuple of str
        Outputs: the input ports they depend on at the same communication point.
    key : str
        The port in code: the models' arrays and the C kernel's port id ``UIOFMU_<KERNEL>_<KEY>``
        (default: the name). Not part of the card.
    """

    name: str
    size: int
    causality: str
    description: str
    type: str = "Real"
    depends: tuple = ()
    key: str = ""

    def __post_init__(self):
        if not self.key:
            object.__setattr__(self, "key", self.name)

    def to_data(self) -> dict:
        """The card's JSON form."""
        return {"name": self.name, "size": self.size, "causality": self.causality, "description": self.description,
                "type": self.type, "depends": list(self.depends)}


def value_references(ports) -> dict:
    """``{port name: first value reference}`` of a declaration."""
    out, vr = {}, 0
    for port in ports:
        out[port.name] = vr
        vr += port.size
    return out


#: Steps of a plant FMU's default experiment.
PLANT_EXPERIMENT_STEPS = 200

#: Most steps of a default experiment: fmpy's simulate_fmu doubles the step while the run has
#: more than 1000 of them, and an observer refuses the doubled step.
MAX_EXPERIMENT_STEPS = 1000


def experiment(step: float, stop: float) -> dict:
    """A ``<DefaultExperiment>``: from 0 to ``stop`` s in steps of ``step`` s (checked numbers).

    Raises
    ------
    ValueError
        For a step or stop time that is not a positive finite number, or a stop before the step.
    """
    step, stop = float(step), float(stop)
    if not (math.isfinite(step) and math.isfinite(stop) and 0 < step <= stop):
        raise ValueError(f"default experiment: expected 0 < stepSize <= stopTime, found {step!r}, {stop!r}")
    return {"startTime": 0.0, "stopTime": stop, "stepSize": step}


def observer_experiment(card) -> dict:
    """An observer's default experiment: its first admissible step (``dt``, the first design
    interval, or the default ``step`` of a continuous-time kernel), until the certified bound has
    fallen to 1e-3 (:func:`default_horizon`; for the delayed kernel its start-up plus the decay of
    its premise-set bound), and at most :data:`MAX_EXPERIMENT_STEPS` steps after its start-up (the schedule's
    ``valid_from``: 2 s for the delayed example at 1 ms, whose estimates are valid from 1 s). The stop time is a
    whole number
    of steps (a horizon in mean design intervals is rounded up): an importer stepping at ``stepSize``
    ends on it without a shorter last step, which the observer would refuse."""
    step = make_schedule(card.schedule, card.matrices).admissible_steps()[0]
    start_up = math.ceil(float(card.schedule.get("valid_from", 0.0)) / step - 1e-9)
    steps = min(max(math.ceil(default_horizon(card) / step - 1e-9), 1), MAX_EXPERIMENT_STEPS + start_up)
    return experiment(step, steps * step)


def plant_experiment(step: float, steps: int | None = None) -> dict:
    """A plant's default experiment: ``steps`` (default :data:`PLANT_EXPERIMENT_STEPS`) steps of ``step``."""
    return experiment(step, (steps or PLANT_EXPERIMENT_STEPS) * float(step))


def plant_spec(data: dict, experiment: dict | None = None, labels: dict | None = None) -> dict:
    """What a plant FMU packs, for either backend: ``{"kind": "plant", "plant": data}`` with its
    ``experiment`` and ``labels`` (names and units) when given."""
    return {"kind": "plant", "plant": data, **({"experiment": experiment} if experiment else {}),
            **({"labels": labels} if labels else {})}


def write_experiment(root, spec: dict) -> None:
    """Append ``<DefaultExperiment>`` (:func:`experiment`'s numbers, written with ``repr``)."""
    from xml.etree.ElementTree import SubElement      # here: only what writes an FMU needs the XML

    spec = experiment(spec["stepSize"], spec["stopTime"])
    SubElement(root, "DefaultExperiment", {k: repr(v) for k, v in spec.items()})


def model_structure(root, ports) -> None:
    """Append ``<ModelStructure>`` for variables written in declaration order (value reference =
    index - 1): every output under ``<Outputs>`` with the inputs it depends on (``dependencies``,
    possibly empty: no feedthrough) and under ``<InitialUnknowns>`` (outputs are ``calculated``)."""
    from xml.etree.ElementTree import SubElement

    first, index, outputs = {}, 1, []
    for port in ports:
        first[port.name] = index
        if port.causality == "output":
            outputs += [(index + i, port) for i in range(port.size)]
        index += port.size
    sizes = {port.name: port.size for port in ports}
    structure = SubElement(root, "ModelStructure")
    if outputs:
        out = SubElement(structure, "Outputs")
        for i, port in outputs:
            deps = [first[name] + k for name in port.depends for k in range(sizes[name])]
            SubElement(out, "Unknown", {"index": str(i), "dependencies": " ".join(map(str, deps))})
        init = SubElement(structure, "InitialUnknowns")
        for i, _ in outputs:
            SubElement(init, "Unknown", {"index": str(i)})


#: Every port of each kernel the C backend implements, in the order of its C port ids
#: (``UIOFMU_<KERNEL>_<KEY>``, from 0): sizes 0 here; the declaration functions below pick and size
#: them, and set what depends on the design (an output's ``depends``, the causality of a switched
#: plant's ``mode`` and of an LPV plant's ``theta``, given here as the one they have most often).
KERNEL_PORTS = {
    "affine": (
        PortSpec("xhat0", 0, "parameter", "initial state estimate at the start time"),
        PortSpec("h_prev0", 0, "parameter", "sampling interval assumed before the first step, h_{-1} [s]"),
        PortSpec("y", 0, "input", "measured outputs at the current communication point"),
        PortSpec("u", 0, "input", "known inputs at the current communication point"),
        PortSpec("xhat", 0, "output", "state estimate at the current communication point"),
        PortSpec("r", 0, "output", "output residual y - C xhat"),
        PortSpec("dhat", 0, "output", "unknown-input estimate over the last step"),
        PortSpec("mode_prev0", 0, "parameter", "mode assumed before the first step, alpha_{-1}", type="Integer"),
        PortSpec("mode", 0, "input", "mode of the plant over the step from the current communication point (1..N)",
                 type="Integer"),
        PortSpec("zhat", 0, "output", "estimate of the functionals Lf x at the current communication point"),
    ),
    "window": (
        PortSpec("y", 0, "input", "measured outputs at the current communication point"),
        PortSpec("theta", 0, "input", "scheduling parameter at the current communication point"),
        PortSpec("gx", 0, "output", "the functional G x at the point delay steps back (0 until valid)"),
        PortSpec("gx_valid", 0, "output", "1 once the output window is full (gx exact), else 0", type="Integer"),
    ),
    "plant": (
        PortSpec("x0", 0, "parameter", "initial state"),
        PortSpec("u", 0, "input", "known inputs (held over the step)"),
        PortSpec("d", 0, "input", "unknown inputs (held over the step)"),
        PortSpec("y", 0, "output", "measured outputs C x"),
        PortSpec("x", 0, "output", "true state (for validation)"),
        PortSpec("seed", 0, "parameter", "seed of the random switching", type="Integer"),
        PortSpec("mode", 0, "output", "mode of the step from the current point (1..N)", type="Integer"),
        PortSpec("mismatch", 0, "parameter", "relative std of the perturbation of A, B, E (0: the design model)"),
        PortSpec("mismatch_seed", 0, "parameter", "seed of the perturbation of A, B, E", type="Integer"),
        PortSpec("w_noise", 0, "input", "process noise (held over the step), entering through W"),
    ),
    "lpv": (
        PortSpec("x0", 0, "parameter", "initial state"),
        PortSpec("u", 0, "input", "known inputs (none: every input of an LPV plant is unknown)"),
        PortSpec("d", 0, "input", "unknown inputs (held over the step)"),
        PortSpec("theta", 0, "output", "scheduling parameter T x at the current point"),
        PortSpec("y", 0, "output", "measured outputs C(theta) x + D(theta) d"),
        PortSpec("x", 0, "output", "true state (for validation)"),
    ),
    "source": (
        PortSpec("u", 0, "output", "known inputs from the current communication point (held over the step)"),
        PortSpec("d", 0, "output", "unknown inputs from the current communication point (held over the step)"),
        PortSpec("theta", 0, "output", "scheduling parameter from the current communication point"),
        PortSpec("mode", 0, "output", "mode of the step from the current communication point (1..N)",
                 type="Integer"),
    ),
    "parametric": (
        PortSpec("x0", 0, "parameter", "initial state"),
        PortSpec("theta", 0, "parameter", "the unknown constant parameters the plant simulates"),
        PortSpec("u", 0, "input", "known inputs (held over the step)"),
        PortSpec("y", 0, "output",
                 "measured outputs C x"),
        PortSpec("ydot", 0, "output", "their derivative C x' at the current point", depends=("u",)),
        PortSpec("x", 0, "output", "true state (for validation)"),
    ),
    "delayed": (
        PortSpec("xhat0", 0, "parameter", "initial state estimate (also of the delayed copies)"),
        PortSpec("y", 0, "input", "measured outputs at the current communication point"),
        PortSpec("ydot", 0, "input", "their measured derivative"),
        PortSpec("u", 0, "input", "known inputs (held over the step)"),
        PortSpec("xhat", 0, "output", "state estimate (held while not valid)", depends=("y", "ydot", "u")),
        PortSpec("thetahat", 0, "output", "parameter estimate (34) (held while not valid)",
                 depends=("y", "ydot", "u")),
        PortSpec("r", 0, "output", "output residual y - C xhat", depends=("y", "ydot", "u")),
        PortSpec("sigma_min", 0, "output", "rank margin sigma_min(C D_y) now", depends=("y", "ydot")),
        PortSpec("valid", 0, "output", "1 while the estimates are valid (delays filled, margin above the "
                 "premise bound)", type="Integer", depends=("y", "ydot")),
    ),
}


def _with_physical(plant: tuple) -> tuple:
    """The ports of a plant kernel with physical parameters: ``x0``, ``u``, ``d``, ``y``, ``x`` of the plant
    kernel's entries ``plant`` (what :func:`plant_ports` declares), and after ``x0`` the port ``params``, whose
    elements are the physical parameters (each declared as a port of its own, named by the plant's spec)."""
    by_key = {port.key: port for port in plant}
    params = PortSpec("params", 0, "parameter", "the physical parameters, each declared as a port of its own")
    return (by_key["x0"], params, *(by_key[key] for key in ("u", "d", "y", "x")))


#: The MuJoCo plant kernel's ports (:func:`_with_physical`).
KERNEL_PORTS = {**KERNEL_PORTS, "mujoco": _with_physical(KERNEL_PORTS["plant"])}

#: The ports whose causality a kernel takes from its design, and the causalities it implements
#: (every other port has the one of :data:`KERNEL_PORTS`): a switched plant's ``mode`` is an input
#: under rule ``input``, else an output; an LPV plant's ``theta`` an input for kind ``input``, else
#: the output ``T x``.
DESIGN_CAUSALITY = {("plant", "mode"): ("input", "output"), ("lpv", "theta"): ("input", "output")}


def kernel_port(kernel: str, key: str, size: int, **changes) -> PortSpec:
    """The port ``key`` of ``kernel`` (:data:`KERNEL_PORTS`) with ``size`` elements and ``changes``
    (``depends``, ``causality``, ``description``); its ``depends`` given as keys of the kernel's ports,
    written as their names."""
    ports = {port.key: port for port in KERNEL_PORTS[kernel]}
    if "depends" in changes:
        changes["depends"] = tuple(ports[k].name for k in changes["depends"])
    return replace(ports[key], size=size, **changes)


def observer_ports(dims: dict, schedule_kind: str, has_dhat: bool, feeds_y: bool = True,
                   feeds_u: bool = False) -> list:
    """The declaration of the affine observer kernel (every family today).

    A functional observer (``dims.nf``) outputs ``zhat`` (``nf``) in place of ``xhat`` and ``r`` where its order is
    below ``n``: it estimates ``Lf x``, not ``x``, so no residual ``y - C xhat`` (and no ``dhat``) is defined; one of
    order ``n`` estimates the state, and outputs ``xhat``, ``r`` and ``zhat = Lf xhat``.

    Parameters
    ----------
    dims : dict
        The card's ``dims`` (``n``, ``m``, ``p``, ``q``).
    schedule_kind : str
        ``interval`` adds the parameter ``h_prev0``; ``mode`` the Integer parameter ``mode_prev0``
        and the Integer input ``mode``.
    has_dhat : bool
        Adds the output ``dhat``.
    feeds_y : bool
        Whether ``xhat`` depends on the ``y`` of the same communication point (``Xy != 0``).
    feeds_u : bool
        Whether ``xhat`` (and so ``r``) depends on the ``u`` of the same communication point (``Xu != 0``).

    Returns
    -------
    list of PortSpec
    """
    n, m, p, q = dims["n"], dims["m"], dims["p"], dims["q"]

    def port(key, size, **changes):
        return kernel_port("affine", key, size, **changes)

    ports = [port("xhat0", n)]
    if schedule_kind == "interval":
        ports.append(port("h_prev0", 1))
    if schedule_kind == "mode":
        ports.append(port("mode_prev0", 1))
    ports += [port("y", p), port("u", m)]
    if schedule_kind == "mode":
        ports.append(port("mode", 1))
    direct = (("y",) if feeds_y else ()) + (("u",) if feeds_u else ())
    if "nf" in dims and dims["nz"] != n:           # functionals only
        return ports + [port("zhat", dims["nf"], depends=direct)]
    ports += [port("xhat", n, depends=direct), port("r", p, depends=("y",) + (("u",) if feeds_u else ()))]
    if "nf" in dims:                               # order n: zhat = Lf xhat
        return ports + [port("zhat", dims["nf"], depends=direct)]
    if has_dhat:
        ports.append(port("dhat", q, depends=("y",)))
    return ports


def window_ports(p: int, d: int, s: int) -> list:
    """The declaration of the window kernel (dead-beat functional observers): inputs ``y`` and, when
    the formula uses it, ``theta``; outputs ``gx`` (the functional, depending on both) and the
    Integer ``gx_valid`` (1 once the window is full, 0 before: it depends on no input)."""
    def port(key, size, **changes):
        return kernel_port("window", key, size, **changes)

    ports = [port("y", p)] + ([port("theta", s)] if s else [])
    return ports + [port("gx", d, depends=("y", "theta") if s else ("y",)), port("gx_valid", 1)]


def plant_ports(n: int, m: int, p: int, q: int, parameters=(), switching: str | None = None,
                mismatch: bool = True, r: int = 0, feeds: tuple = ()) -> list:
    """The declaration of a plant: parameters ``x0`` and the physical ``(name, what)`` pairs,
    inputs ``u``, ``d`` (held over the step), outputs ``y = C x + D u + F d`` and ``x`` (``feeds``: the inputs
    ``y`` depends on directly, ``"u"`` where ``D != 0`` and ``"d"`` where ``F != 0``; none by default).

    A switched plant (``switching``: its rule, :mod:`uiofmu.runtime.switching`) adds the Integer
    ``mode`` of the step from the current point: an output that depends on no input (rules
    ``threshold``, ``random``; ``random`` also has the Integer parameter ``seed``), or an input
    (rule ``input``). A plant of matrices (``mismatch``, :mod:`uiofmu.runtime.mismatch`) ends with the
    parameters ``mismatch`` (Real) and ``mismatch_seed`` (Integer), after every other port so that
    the value references of the others are those of a plant without them. A plant whose problem
    declares process noise (``[plant] W`` of ``r`` columns) has the input ``w_noise[1..r]`` after ``d``."""
    def port(key, size, **changes):
        return kernel_port("plant", key, size, **changes)

    ports = [port("x0", n)]
    if switching == "random":
        ports.append(port("seed", 1))
    ports += [PortSpec(name, 1, "parameter", f"physical parameter {what}") for name, what in parameters]
    ports += [port("u", m), port("d", q)]
    if r:
        ports.append(port("w_noise", r))
    if switching == "input":
        ports.append(port("mode", 1, causality="input"))
    ports += [port("y", p), port("x", n)]
    if feeds:                                        # y = C x + D u + F d
        ports = [replace(spec, depends=tuple(feeds)) if spec.key == "y" else spec for spec in ports]
    if switching in ("threshold", "random"):
        ports.append(port("mode", 1, causality="output"))
    if mismatch:
        ports += [port("mismatch", 1), port("mismatch_seed", 1)]
    return ports


def lpv_plant_ports(n: int, p: int, q: int, s: int, kind: str, feeds_d: bool) -> list:
    """The declaration of an LPV plant (:mod:`uiofmu.runtime.lpv`): parameter ``x0``, inputs ``d`` and,
    for ``kind = "input"``, ``theta``; outputs ``y`` (depending on ``d`` when ``D(theta)`` is not zero, and
    on an input ``theta``), ``x`` and, for ``kind = "state"``, ``theta = T x``."""
    def port(key, size, **changes):
        return kernel_port("lpv", key, size, **changes)

    depends = (("d",) if feeds_d else ()) + (("theta",) if kind == "input" else ())
    ports = [port("x0", n), port("u", 0), port("d", q)]
    if kind == "input":
        ports.append(port("theta", s, causality="input",
                          description="scheduling parameter over the step from the current point"))
    ports += [port("y", p, depends=depends), port("x", n)]
    if kind == "state":
        ports.append(port("theta", s, causality="output"))
    return ports


def parametric_plant_ports(n: int, m: int, p: int, n_theta: int) -> list:
    """The declaration of a plant with unknown parameters (:mod:`uiofmu.runtime.parametric_plant`):
    parameters ``x0`` and ``theta`` (the true values it simulates), input ``u``, outputs ``y``, its
    derivative ``ydot = C x'`` (depending on ``u``) and ``x``."""
    def port(key, size):
        return kernel_port("parametric", key, size)

    return [port("x0", n), port("theta", n_theta), port("u", m), port("y", p), port("ydot", p), port("x", n)]


def delayed_ports(n: int, m: int, p: int, n_theta: int) -> list:
    """The declaration of the delayed kernel (:mod:`uiofmu.runtime.delayed`): parameter ``xhat0``; inputs
    ``y``, ``ydot``, ``u``; outputs ``xhat``, ``thetahat``, ``r``, the rank margin ``sigma_min`` and the
    Integer ``valid`` (1 while the estimates are valid)."""
    def port(key, size):
        return kernel_port("delayed", key, size)

    return [port("xhat0", n), port("y", p), port("ydot", p), port("u", m), port("xhat", n), port("thetahat", n_theta),
            port("r", p), port("sigma_min", 1), port("valid", 1)]


def source_ports(sizes: dict) -> list:
    """The declaration of a signal source (``c/kernel_source.c``): one output per vector of ``sizes``
    (``{"u": m, "d": q, "theta": s, "mode": 1}``; a size 0 or a vector left out has no port), in the
    order of :data:`KERNEL_PORTS` ``["source"]``, which is also the order of the columns of its table.

    Raises
    ------
    ValueError
        For a vector the source does not play, or a ``mode`` of more than one element.
    """
    known = [port.key for port in KERNEL_PORTS["source"]]
    unknown = sorted(set(sizes) - set(known))
    if unknown:
        raise ValueError(f"a signal source plays {', '.join(known)}, not {', '.join(unknown)}")
    if sizes.get("mode", 0) > 1:
        raise ValueError(f"a signal source plays one mode, not {sizes['mode']}")
    return [kernel_port("source", key, int(sizes[key])) for key in known if sizes.get(key)]


def check_declared(declared, expected: list) -> None:
    """Refuse a card whose ``ports`` differ from what its kernel implements.

    Parameters
    ----------
    declared : object
        The card's ``ports`` entry (parsed JSON).
    expected : list of PortSpec

    Raises
    ------
    CardError
        Naming the first port that differs.
    """
    if not isinstance(declared, list):
        raise CardError(f"design card ports: expected a list of ports, found {type(declared).__name__}")
    want = [p.to_data() for p in expected]
    for i, (have, port) in enumerate(zip(declared, want)):
        if have != port:
            shown = {k: have.get(k) for k in port} if isinstance(have, dict) else have
            raise CardError(f"design card ports[{i}]: expected {port}, found {repr(shown)[:200]}")
    if len(declared) != len(want):
        raise CardError(f"design card ports: the kernel has {len(want)} ports "
                        f"({', '.join(p['name'] for p in want)}), the card declares {len(declared)}")
