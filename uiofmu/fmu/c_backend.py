"""The C backend: a standalone native observer FMU (no Python in the importer).

The card's matrices become constant C data (``design_data.c``, with the variable table of the
card's ports) next to the card's kernel (``c/kernel_affine.c``: the observer maths of every affine
card; ``c/kernel_window.c``: the window formula of a dead-beat functional observer;
``c/kernel_delayed.c``: the delayed UIO integrated inside the FMU), what the kernels
share (``c/kernel_util.c``: their checks of design data, inputs and steps, and the pieces of their
FMU state) and the shared FMI 2.0 Co-Simulation plumbing (``c/fmi2_plumbing.c``: states and legal
calls, logging, get/set, FMU states, status queries). Two headers are generated with it: the kernel's
ports (``kernel_<name>_ports.h``: ids, names, causalities, types, from :mod:`uiofmu.runtime.ports`)
and the refusals the kernels share with the Python runtime (``uiofmu_refusals.h``, from
:mod:`uiofmu.runtime.refusals`). The system C compiler builds
``binaries/linux64/<model>.so``. The sources and the FMI headers travel in ``sources/`` with a
``<SourceFiles>`` list, so ``fmpy compile`` rebuilds the binary on another platform. The interface
(names, value references, start values) is the one of the python backend, enumerated from the same
ports. The MuJoCo plant's kernel (``c/kernel_mujoco.c``) links a prebuilt library instead
(:class:`LinkedLibrary`: the mujoco wheel's libmujoco, shipped next to the binary, found through the run
path ``$ORIGIN``); :mod:`uiofmu.fmu.mujoco_c` builds it.
"""

from __future__ import annotations

import importlib.util
import json
import math
import platform
import shutil
import string
import subprocess
import tempfile
import uuid
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable
from xml.etree.ElementTree import Element, SubElement, fromstring, tostring

import numpy as np

from .. import __version__
from ..runtime.card import MAX_POWER, Card
from ..runtime.errors import CardError, FmuError
from ..runtime.files import atomic_output, check_output_file
from ..runtime.kernels import KERNELS
from ..runtime.plant_kinds import LINEAR, PLANT_KINDS, data_kind
from ..runtime.schedules import schedule_axes
from ..runtime.ports import (DESIGN_CAUSALITY, KERNEL_PORTS, lpv_plant_ports, model_structure, observer_experiment,
                             parametric_plant_ports, plant_ports, plant_spec, write_experiment)
from ..runtime.labels import apply_labels
from ..runtime.refusals import REFUSALS, fields
from ..runtime.text import c_string
from ..runtime.step_rules import StepRule, step_rule
from ..runtime.tolerances import STEP_RTOL, STEP_ULPS, STEP_ULPS_LIMIT

HERE = Path(__file__).parent / "c"
MATRIX_ORDER = ("N", "L", "G", "c", "Xz", "Xy", "C", "Dy", "Yx", "Yu", "Yc", "Xu", "Zx", "Lf")
KINDS = {"constant": "UIOFMU_CONSTANT", "interval": "UIOFMU_INTERVAL", "geometric": "UIOFMU_GEOMETRIC",
         "mode": "UIOFMU_MODE"}
POLICIES = {"error": "UIOFMU_POLICY_ERROR", "nearest": "UIOFMU_POLICY_NEAREST", "count": "UIOFMU_POLICY_COUNT"}

#: The shared FMI 2.0 plumbing (``c/fmi2_plumbing.c``: instance states and legal calls, logging, get/set
#: through the variable table, FMU state image, status queries) and its header (the model interface).
PLUMBING_SOURCES = ("fmi2_plumbing.c",)
PLUMBING_HEADERS = ("fmi2_plumbing.h",)
#: What every kernel shares (``c/kernel_util.c``: the checks of design data, inputs and steps every
#: kernel makes with the same log lines, and the pieces of a kernel's part of the FMU state).
KERNEL_UTIL_SOURCES = ("kernel_util.c",)
KERNEL_UTIL_HEADERS = ("kernel_util.h",)
FMI_HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
#: The generated header of the refusals the kernels share with the Python runtime (:func:`refusals_header`).
REFUSALS_HEADER = "uiofmu_refusals.h"
#: The printf conversion of each kind of field of a refusal (:data:`uiofmu.runtime.refusals.KINDS`): numbers
#: as the text ``uiofmu_num`` writes (Python's repr), integers, text, ``%g`` and a word in single quotes.
REFUSAL_CONVERSIONS = {"num": "%s", "int": "%d", "text": "%s", "g": "%g", "quoted": "'%s'"}
CAUSALITIES = {"parameter": "UIOFMU_PARAMETER", "input": "UIOFMU_INPUT", "output": "UIOFMU_OUTPUT"}
PORT_TYPES = {"Real": "UIOFMU_REAL", "Integer": "UIOFMU_INTEGER"}
#: The log categories the plumbing writes under and fmi2SetDebugLogging takes (fmi2OK lines of the
#: instance's state changes, then one per status); what ``<LogCategories>`` declares.
LOG_CATEGORIES = ("logEvents", "logStatusWarning", "logStatusDiscard", "logStatusError")


@dataclass(frozen=True)
class CKernel:
    """One C kernel: its model code and the ports it implements.

    Attributes
    ----------
    source, header : str
        Its files in ``c/`` (``kernel_<name>.c`` and ``.h``).
    symbol : str
        Its ``UiofmuKernel`` (what ``UIOFMU_FMU.kernel`` points at).
    ports : str
        Its ports: the key of :data:`uiofmu.runtime.ports.KERNEL_PORTS` (``"plant"``), whose entries,
        in order, are its port ids ``UIOFMU_<PORTS>_<KEY>`` (:func:`port_header`).
    physical : str or None
        The key of its port that holds the physical parameters, which a declaration names one port
        each (Real parameters of one element, keys of their own): their elements, in declaration
        order, are that port's (:func:`table_rows`). None: a kernel without them.
    too_large : callable or None
        ``too_large(card) -> str or None``: why it cannot take a card its descriptor names it for (a card
        beyond its bounds), or None; None when it takes every such card.
    """

    source: str
    header: str
    symbol: str
    ports: str
    physical: str | None = None
    too_large: Callable | None = None

    @property
    def ports_header(self) -> str:
        """The generated header of its ports (``kernel_<name>_ports.h``, :func:`port_header`), which its
        header includes."""
        return f"{Path(self.header).stem}_ports.h"

    @property
    def prefix(self) -> str:
        """The prefix of its port ids (``UIOFMU_PLANT``)."""
        return f"UIOFMU_{self.ports.upper()}"


#: What ``c/kernel_delayed.c`` takes (its ``MAX_AUGMENTED`` and ``MAX_BUFFER``): states, inputs and outputs of the
#: augmented system (``n (len(delays) + 1)``, ...), and numbers in the delay buffer (``(rows + 1) (1 + 2 p + m)``).
DELAYED_MAX_AUGMENTED = 512
DELAYED_MAX_BUFFER = 16_777_216


def _delayed_too_large(card: Card) -> str | None:
    """Why ``c/kernel_delayed.c`` cannot take a delayed-kernel card (:data:`DELAYED_MAX_AUGMENTED`,
    :data:`DELAYED_MAX_BUFFER`), or None."""
    from ..runtime.delayed import buffer_rows

    n, m, p = (int(card.dims[k]) for k in ("n", "m", "p"))
    c = len(card.schedule["delays"]) + 1
    rows, width = buffer_rows(card.schedule["delays"], card.schedule["step"]), 1 + 2 * p + m
    if max(n, m, p) * c <= DELAYED_MAX_AUGMENTED and (rows + 1) * width <= DELAYED_MAX_BUFFER:
        return None
    return (f"the C delayed kernel takes at most {DELAYED_MAX_AUGMENTED} states, inputs and outputs of the augmented "
            f"system and {DELAYED_MAX_BUFFER} numbers in its delay buffer; this card has (n, m, p) (len(delays) + 1) "
            f"= ({n * c}, {m * c}, {p * c}) and {rows + 1} x {width}")


#: The C kernels, by the card's ``kernel``.
C_KERNELS = {
    "affine": CKernel("kernel_affine.c", "kernel_affine.h", "UIOFMU_KERNEL_AFFINE", "affine"),
    "window": CKernel("kernel_window.c", "kernel_window.h", "UIOFMU_KERNEL_WINDOW", "window"),
    "delayed": CKernel("kernel_delayed.c", "kernel_delayed.h", "UIOFMU_KERNEL_DELAYED", "delayed",
                       too_large=_delayed_too_large),
}

_PLANT = CKernel("kernel_plant.c", "kernel_plant.h", "UIOFMU_KERNEL_PLANT", "plant")
_LPV = CKernel("kernel_lpv.c", "kernel_lpv.h", "UIOFMU_KERNEL_LPV", "lpv")
#: The kernel of MuJoCo plants (``c/kernel_mujoco.c``, built by :mod:`uiofmu.fmu.mujoco_c`): the physical
#: parameters are the elements of its port ``params``.
MUJOCO_KERNEL = CKernel("kernel_mujoco.c", "kernel_mujoco.h", "UIOFMU_KERNEL_MUJOCO", "mujoco", physical="params")
_PARAMETRIC = CKernel("kernel_parametric.c", "kernel_parametric.h", "UIOFMU_KERNEL_PARAMETRIC", "parametric")

#: The C kernels of plants, by plant kind: linear, and switched by rule (one kernel,
#: ``c/kernel_plant.c``, whose Integer port ``mode`` is an input for rule ``input``, else an output),
#: and LPV by the kind of its theta (one kernel, ``c/kernel_lpv.c``, whose port ``theta`` is an input
#: for kind ``input``, else the output ``T x``): the causality each declaration gives them
#: (:data:`uiofmu.runtime.ports.DESIGN_CAUSALITY`), which the kernel checks against its design; plants with
#: unknown parameters (``c/kernel_parametric.c``: RK4 substeps and the output ``ydot``); and MuJoCo plants
#: (``c/kernel_mujoco.c``, which links MuJoCo's library: :mod:`uiofmu.fmu.mujoco_c` builds it).
PLANT_KERNELS = {
    "linear": _PLANT,
    "parametric": _PARAMETRIC,
    **{f"switched-{rule}": _PLANT for rule in ("threshold", "input", "random")},
    **{f"lpv-{kind}": _LPV for kind in ("state", "input")},
    "mujoco": MUJOCO_KERNEL,
}
TIMES = {"discrete": "UIOFMU_DISCRETE", "continuous": "UIOFMU_CONTINUOUS"}
RULES = {"threshold": "UIOFMU_RULE_THRESHOLD", "input": "UIOFMU_RULE_INPUT", "random": "UIOFMU_RULE_RANDOM"}
THETA_KINDS = {"state": "UIOFMU_THETA_STATE", "input": "UIOFMU_THETA_INPUT"}

#: Why the C backend has no kernel for these models (what ``--backend c`` says, and the note of the default),
#: by kernel and by plant kind (:attr:`uiofmu.runtime.kernels.Kernel.python_only`,
#: :attr:`uiofmu.runtime.plant_kinds.PlantKind.python_only`).
PYTHON_ONLY = {d.name: d.python_only for d in (*KERNELS.values(), *PLANT_KINDS.values()) if d.python_only}


def c_refusal(model) -> str | None:
    """Why the C backend cannot pack ``model``, or None when it can.

    Parameters
    ----------
    model : Card or plant or dict
        A design card, a plant (with ``to_data``) or a plant's data.

    Returns
    -------
    str or None
        One sentence naming what the C backend lacks (:data:`PYTHON_ONLY`).
    """
    if isinstance(model, Card):
        kernel = model.stepper
        if kernel.c_kernel in C_KERNELS:
            bounds = C_KERNELS[kernel.c_kernel].too_large
            return bounds(model) if bounds else None
        return kernel.python_only or (f"the C backend has no kernel {kernel.name[:40]!r} "
                                      f"(it has {', '.join(C_KERNELS)})")
    data = model if isinstance(model, dict) else model.to_data()
    kind = data_kind(data)
    return None if kind.c_kernel is not None else kind.python_only


def c_kernel(card: Card) -> CKernel:
    """The C kernel of a card; FmuError when there is none for its ``kernel``."""
    kernel = C_KERNELS.get(card.stepper.c_kernel)
    if kernel is None:
        raise FmuError(f"--backend c: {c_refusal(card)}; use --backend python (or leave --backend out: the "
                       "default picks python for this card)")
    return kernel


def c_sources(card: Card) -> list:
    """The C files of a card's FMU in the order they are compiled (plumbing, what the kernels share, kernel,
    generated data)."""
    return kernel_sources(c_kernel(card))


def kernel_sources(kernel: CKernel) -> list:
    """The C files of an FMU of ``kernel`` in the order they are compiled."""
    return [*PLUMBING_SOURCES, *KERNEL_UTIL_SOURCES, kernel.source, "design_data.c"]


def variable_table(card: Card) -> list:
    """The C initialisers of the variable table: one ``{port, index, causality, type}`` per value
    reference, in the order of ``card.ports`` (value references from 0, element by element).

    Raises
    ------
    FmuError
        For a port the card's kernel does not implement in C, or one declared with another
        causality or type than the kernel's (nothing of the card's text reaches the source: only
        the kernel's own identifiers and numbers).
    """
    return table_rows(c_kernel(card), str(card.kernel), card.ports)


def table_rows(kernel: CKernel, label: str, ports) -> list:
    """The variable table of a declaration ``ports`` (PortSpecs) for ``kernel`` (``label`` names it
    in messages): see :func:`variable_table`."""
    rows, physical = [], 0
    for port in _checked_ports(kernel, label, ports):
        if _is_physical(kernel, port):
            rows.append(f"    {{{kernel.prefix}_{kernel.physical.upper()}, {physical}, {CAUSALITIES['parameter']}, "
                        f"{PORT_TYPES['Real']}}},")
            physical += 1
            continue
        enum = f"{kernel.prefix}_{port.key.upper()}"
        rows += [f"    {{{enum}, {i}, {CAUSALITIES[port.causality]}, {PORT_TYPES[port.type]}}},"
                 for i in range(port.size)]
    return rows


def _is_physical(kernel: CKernel, port) -> bool:
    """Whether ``port`` is one of the physical parameters a kernel with :attr:`CKernel.physical` holds in that
    port: a key that is none of the kernel's ports, a Real parameter of one element."""
    known = {p.key for p in KERNEL_PORTS[kernel.ports]}
    return (kernel.physical is not None and port.key not in known and port.causality == "parameter"
            and port.type == "Real" and port.size == 1)


def _checked_ports(kernel: CKernel, label: str, ports) -> list:
    """``ports`` when each is one of the kernel's (:data:`uiofmu.runtime.ports.KERNEL_PORTS`, by key)
    with its name, type and causality (or one of :data:`uiofmu.runtime.ports.DESIGN_CAUSALITY`), a
    count of elements, and declared once; else FmuError naming the first that is not."""
    known = {port.key: port for port in KERNEL_PORTS[kernel.ports]}
    seen = set()
    for port in ports:
        want = known.get(port.key)
        if _is_physical(kernel, port):
            continue
        if want is None or port.key == kernel.physical:
            raise FmuError(f"the C {label} kernel has no port {str(port.name)[:40]!r} "
                           f"(it implements {', '.join(p.name for p in known.values())})")
        causalities = DESIGN_CAUSALITY.get((kernel.ports, port.key), (want.causality,))
        if port.causality not in causalities or port.type != want.type:
            article = {"parameter": "a", "input": "an", "output": "an"}
            raise FmuError(f"port {port.name}: declared {article.get(port.causality, 'a')} {str(port.causality)[:20]} "
                           f"{str(port.type)[:20]}, the C {label} kernel implements "
                           f"{' or '.join(f'{article[c]} {c}' for c in causalities)} {want.type}")
        if port.name != want.name or port.key in seen:
            raise FmuError(f"port {str(port.name)[:40]!r}: the C {label} kernel's port {port.key} is named "
                           f"{want.name!r} and declared once")
        if not isinstance(port.size, int) or isinstance(port.size, bool) or not 0 <= port.size <= 1 << 24:
            raise FmuError(f"port {port.name}: size {str(port.size)[:20]} is not a count")
        seen.add(port.key)
    return list(ports)


def port_header(kernel: CKernel, ports=(), label: str | None = None) -> str:
    """``kernel_<name>_ports.h`` (:attr:`CKernel.ports_header`): the kernel's ports as its code refers
    to them, generated from :data:`uiofmu.runtime.ports.KERNEL_PORTS`.

    One id per port in the order of its entries (``enum { UIOFMU_PLANT_X0, ..., UIOFMU_PLANT_PORTS }``)
    and, by id, their names, causalities and types as C initialisers (``UIOFMU_PLANT_PORT_NAMES``,
    ``_CAUSALITIES``, ``_TYPES``). A port of the declaration ``ports`` (checked as
    :func:`table_rows` checks it) gives its causality (a switched plant's ``mode`` is an input under
    rule ``input``); the others keep their entry's. Only the names, keys and words that module defines
    reach the text: never a card's or a problem's.
    """
    label = label or kernel.ports
    declared = {port.key: port for port in _checked_ports(kernel, label, ports)}
    entries = [declared.get(port.key, port) for port in KERNEL_PORTS[kernel.ports]]
    for port in entries:
        if not port.key.isidentifier() or not port.key.isascii() or port.key.upper() in (
                "PORTS", "PORT_NAMES", "PORT_CAUSALITIES", "PORT_TYPES"):
            raise FmuError(f"the {label} kernel's port {port.name!r}: its key {port.key!r} is no C identifier")
    prefix, guard = kernel.prefix, f"UIOFMU_{kernel.ports_header[:-2].upper()}_H"
    ids = [f"{prefix}_{port.key.upper()}" for port in entries]
    if len(set(ids)) != len(ids):
        raise FmuError(f"the {label} kernel's port keys are not unique: {', '.join(ids)}")

    def initialiser(values) -> str:
        return "{" + ", ".join(values) + "}"

    return "\n".join([
        f"/* Generated by uiofmu from uiofmu/runtime/ports.py (KERNEL_PORTS, {kernel.ports}): the ports of "
        f"{kernel.source}, */",
        "/* their ids (the variable table's port) and, by id, their names, causalities and types. */",
        f"#ifndef {guard}", f"#define {guard}", "",
        "enum {", *(f"    {name}," for name in ids), f"    {prefix}_PORTS", "};", "",
        f"#define {prefix}_PORT_NAMES {initialiser(c_string(port.name) for port in entries)}",
        f"#define {prefix}_PORT_CAUSALITIES {initialiser(CAUSALITIES[port.causality] for port in entries)}",
        f"#define {prefix}_PORT_TYPES {initialiser(PORT_TYPES[port.type] for port in entries)}", "",
        "#endif", ""])


def refusals_header() -> str:
    """``uiofmu_refusals.h``: each refusal of :data:`uiofmu.runtime.refusals.REFUSALS` as a printf format
    ``UIOFMU_REFUSAL_<KEY>`` (a literal ``%`` doubled, each field its :data:`REFUSAL_CONVERSIONS`), with
    its fields in the order the C code passes them. Only the catalogue's own text reaches it."""
    lines = ["/* Generated by uiofmu from uiofmu/runtime/refusals.py: the refusals the C kernels share with the",
             "   Python runtime, as printf formats; the arguments are the fields named above each, in order. */",
             "#ifndef UIOFMU_REFUSALS_H", "#define UIOFMU_REFUSALS_H", ""]
    for key, text in REFUSALS.items():
        if not key.isidentifier() or not key.isascii():
            raise FmuError(f"refusal {key!r}: its key is no C identifier")
        fmt = "".join(literal.replace("%", "%%") + (REFUSAL_CONVERSIONS[kind] if name is not None else "")
                      for literal, name, kind, _ in string.Formatter().parse(text))
        lines += [f"/* {key}: {', '.join(f'{name} ({kind})' for name, kind in fields(key))} */",
                  f"#define UIOFMU_REFUSAL_{key.upper()} {c_string(fmt)}"]
    return "\n".join([*lines, "", "#endif", ""])


def c_compiler() -> str | None:
    """The system C compiler (``cc`` or ``gcc``), or None."""
    for name in ("cc", "gcc", "clang"):
        path = shutil.which(name)
        if path:
            return path
    return None


def _double(value, key: str) -> str:
    """A finite float as C source (repr reads back bit-identical)."""
    v = float(value)
    if not math.isfinite(v):
        raise CardError(f"design card {key}: expected a finite number, found {v!r}")
    return repr(v)


def _doubles(values, key: str, size: int) -> str:
    """A C initialiser of ``size`` finite doubles (``{0.0}`` for an empty array)."""
    flat = np.asarray(values, dtype=float).ravel()
    if flat.size != size:
        raise CardError(f"design card {key}: expected {size} numbers, found {flat.size}")
    return "{" + ", ".join(_double(v, key) for v in flat) + "}" if flat.size else "{0.0}"


def _count(value, key: str) -> int:
    """A small non-negative integer as C source (no bool, no float)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 0 <= int(value) <= 1 << 24:
        raise CardError(f"design card {key}: expected an integer from 0 to {1 << 24}, found {str(value)[:40]!r}")
    return int(value)


def design_source(card: Card, guid: str, identifier: str) -> str:
    """``design_data.c``: the card as one constant ``UiofmuDesign`` (the kernel's data), its
    variable table and ``UIOFMU_FMU`` (GUID, model identifier, kernel, table; ``c/fmi2_plumbing.h``).

    Only numbers, the GUID, the model identifier and the kernel's own identifiers reach the
    source: every float is written by :func:`repr` after a finiteness check, every array with its
    length checked against the dims, the two strings as escaped C literals
    (:func:`uiofmu.runtime.text.c_string`), the variable table from ``card.ports`` as the kernel's
    port enum names (:func:`variable_table`: a port the kernel does not implement is refused). No
    text of the card (its name, description or problem) is ever written into it.

    The structs are written with designated initialisers, and every array with its length as the
    C compiler counts it (``UIOFMU_LENGTH``), so the runtime checks each matrix's
    ``count x rows x cols`` and the table against the data actually compiled in before it reads
    any of it.

    Parameters
    ----------
    card : Card
        A checked design card.
    guid : str
        The FMU's GUID without braces.
    identifier : str
        The model identifier (an ASCII identifier).

    Returns
    -------
    str
        The C source.
    """
    c_kernel(card)                                  # FmuError for a kernel the C backend lacks
    return _OBSERVER_SOURCES[card.stepper.c_kernel](card, guid, identifier)


def _affine_source(card: Card, guid: str, identifier: str) -> str:
    """``design_data.c`` of an affine-kernel card (:func:`design_source`)."""
    d = card.dims
    sched = card.schedule
    kind = sched["kind"]
    kernel = c_kernel(card)
    table = variable_table(card)
    lines = ["/* Generated by uiofmu from a design card. */", f'#include "{kernel.header}"', ""]
    fields = []
    axes = schedule_axes(sched)
    for name in MATRIX_ORDER:
        if name not in card.matrices:       # an absent matrix is all zero (designated initialisers), so the data
            continue                        # of a card without the newer matrices (Zx) builds with older kernels
        arr = card.matrices[name]
        lead = axes.get(name, 0)
        count = int(np.prod(arr.shape[:lead])) if lead else 1
        shape = arr.shape[lead:]
        rows, cols = (shape[0], 1) if len(shape) == 1 else shape
        lines.append(f"static const double m_{name}[] = {_doubles(arr, f'matrices.{name}', count * rows * cols)};")
        fields.append(f"        [M_{name}] = {{{int(count)}, {int(rows)}, {int(cols)}, m_{name}, "
                      f"UIOFMU_LENGTH(m_{name})}},")
    intervals = sched.get("intervals", [])
    lines.append(f"static const double intervals[] = {_doubles(intervals, 'schedule.intervals', len(intervals))};")
    lines.append(f"static const double xhat0[] = {_doubles(card.data['initial']['xhat0'], 'initial.xhat0', d['n'])};")
    dt = sched.get("dt") or 0.0
    modes = _count(sched.get("modes", 0), "schedule.modes") if kind == "mode" else 0
    mode_prev0 = _count(sched.get("mode_prev0", 1), "schedule.mode_prev0") if kind == "mode" else 0
    lines += ["", "const UiofmuDesign UIOFMU_DESIGN = {",
              f"    .n = {int(d['n'])}, .m = {int(d['m'])}, .p = {int(d['p'])}, .q = {int(d['q'])}, "
              f".nz = {int(d['nz'])}, .has_dhat = {int(card.has_dhat)},"
              + (f" .nf = {int(d['nf'])}," if "nf" in d else ""),     # absent (0): the data builds with older kernels
              f"    .kind = {KINDS[kind]}, .policy = {POLICIES[sched.get('step_policy', 'error')]},",
              f"    .dt = {_double(dt, 'schedule.dt')}, .alpha = {_double(sched.get('alpha', 0.0), 'schedule.alpha')}, "
              f".h_prev0 = {_double(sched.get('h_prev0', dt), 'schedule.h_prev0')}, "
              f".step_rtol = {_double(sched.get('step_rtol', STEP_RTOL), 'schedule.step_rtol')},",
              f"    .nintervals = {len(intervals)}, .intervals = intervals, "
              ".intervals_length = UIOFMU_LENGTH(intervals),",
              f"    .modes = {modes}, .mode_prev0 = {mode_prev0},",
              "    .xhat0 = xhat0, .xhat0_length = UIOFMU_LENGTH(xhat0),",
              "    .mat = {", *fields, "    },", "};", "",
              *fmu_table(guid, identifier, kernel, table)]
    return "\n".join(lines)


def _window_source(card: Card, guid: str, identifier: str) -> str:
    """``design_data.c`` of a window-kernel card (a dead-beat functional observer): one constant
    ``UiofmuWindow`` (``c/kernel_window.h``: ``F`` as terms x d x p L doubles, ``Fexp`` as terms x L x s
    integer powers, the window length, delay and period), its variable table and ``UIOFMU_FMU``;
    numbers only, as :func:`design_source`."""
    kernel = c_kernel(card)
    table = variable_table(card)
    sched = card.schedule
    F, exps = np.asarray(card.matrices["F"], dtype=float), np.asarray(card.matrices["Fexp"])
    p = _count(card.dims["p"], "dims.p")
    L = _count(sched["length"], "schedule.length")
    s = _count(sched["theta"], "schedule.theta")
    delay = _count(sched["delay"], "schedule.delay")
    if F.ndim != 3 or exps.ndim != 3 or F.shape[2] != p * L or exps.shape != (F.shape[0], L, s):
        raise CardError(f"design card matrices: F {F.shape} and Fexp {exps.shape} do not fit p = {p}, L = {L}, "
                        f"s = {s}")
    terms, rows = F.shape[0], F.shape[1]
    powers = [int(e) for e in exps.ravel()]
    if any(e != v or not 0 <= e <= MAX_POWER for e, v in zip(powers, exps.ravel())):
        raise CardError(f"design card matrices.Fexp: expected integer powers from 0 to {MAX_POWER}")
    uses_theta = sched.get("uses_theta")
    if not isinstance(uses_theta, bool):
        raise CardError(f"design card schedule.uses_theta: expected true or false, found {str(uses_theta)[:40]!r}")
    lines = ["/* Generated by uiofmu from a design card. */", f'#include "{kernel.header}"', "",
             f"static const double m_F[] = {_doubles(F, 'matrices.F', terms * rows * p * L)};",
             "static const int m_Fexp[] = {" + (", ".join(map(str, powers)) if powers else "0") + "};", "",
             "const UiofmuWindow UIOFMU_WINDOW = {",
             f"    .p = {p}, .d = {int(rows)}, .s = {s}, .length = {L}, .delay = {delay}, "
             f".uses_theta = {int(uses_theta)}, .terms = {int(terms)},",
             f"    .dt = {_double(sched['dt'], 'schedule.dt')}, "
             f".step_rtol = {_double(sched.get('step_rtol', STEP_RTOL), 'schedule.step_rtol')},",
             "    .F = m_F, .Fexp = m_Fexp, .F_length = UIOFMU_LENGTH(m_F), .Fexp_length = UIOFMU_LENGTH(m_Fexp),",
             "};", "", *fmu_table(guid, identifier, kernel, table)]
    return "\n".join(lines)


def _delayed_source(card: Card, guid: str, identifier: str) -> str:
    """``design_data.c`` of a delayed-kernel card (the delayed UIO of seed 001): one constant ``UiofmuDelayed``
    (``c/kernel_delayed.h``: the plant's ``Abar, Bbar, Cbar, D0, Dy``, the gain ``K``, the delays, the
    default ``xhat0``, the schedule's numbers and the buffer's rows, :func:`uiofmu.runtime.delayed.buffer_rows`),
    its variable table and ``UIOFMU_FMU``; numbers only, as :func:`design_source`."""
    from ..runtime.delayed import buffer_rows

    kernel = c_kernel(card)
    table = variable_table(card)
    sched, mats = card.schedule, card.matrices
    n, m, p = (_count(card.dims[k], f"dims.{k}") for k in ("n", "m", "p"))
    delays = [float(t) for t in sched["delays"]]
    c = len(delays) + 1
    D0 = np.asarray(mats["D0"], dtype=float)
    nt = _count(D0.shape[1] if D0.ndim == 2 else -1, "matrices.D0 columns")
    too_large = _delayed_too_large(card)
    if too_large:
        raise FmuError(f"--backend c: {too_large}; use --backend python")
    rows = buffer_rows(delays, sched["step"])
    arrays = (("A", mats["Abar"], n * n), ("B", mats["Bbar"], n * m), ("C", mats["Cbar"], p * n), ("D0", D0, n * nt),
              ("Dy", mats["Dy"], p * n * nt), ("K", mats["K"], n * c * p * c), ("delays", delays, len(delays)),
              ("xhat0", card.data["initial"].get("xhat0", [0.0] * n), n))
    gamma = float(sched.get("gamma_bound", math.inf))
    lines = ["/* Generated by uiofmu from a design card. */", f'#include "{kernel.header}"', "",
             *(f"static const double m_{key}[] = {_doubles(values, f'matrices.{key}', size)};"
               for key, values, size in arrays), "",
             "const UiofmuDelayed UIOFMU_DELAYED = {",
             f"    .n = {n}, .m = {m}, .p = {p}, .nt = {nt}, .ndelays = {len(delays)}, "
             f".rows = {rows},",
             f"    .max_substep = {_double(sched['max_substep'], 'schedule.max_substep')}, "
             f".sigma_bound = {_double(sched['sigma_bound'], 'schedule.sigma_bound')},",
             f"    .valid_from = {_double(sched.get('valid_from', max(delays)), 'schedule.valid_from')}, "
             f".gamma_bound = {_double(gamma if math.isfinite(gamma) else 0.0, 'schedule.gamma_bound')}, "
             f".has_gamma_bound = {int(math.isfinite(gamma))},",
             "    " + ", ".join(f".{key} = m_{key}, .{key}_length = UIOFMU_LENGTH(m_{key})" for key, _, _ in arrays)
             + ",", "};", "", *fmu_table(guid, identifier, kernel, table)]
    return "\n".join(lines)


#: The generator of ``design_data.c`` of each observer C kernel (the keys of :data:`C_KERNELS`).
_OBSERVER_SOURCES = {"affine": _affine_source, "window": _window_source, "delayed": _delayed_source}


def fmu_table(guid: str, identifier: str, kernel: CKernel, table: list) -> list:
    """The lines of ``design_data.c`` after the kernel's data: the variable table and ``UIOFMU_FMU``
    (the GUID and model identifier as escaped C literals, the kernel's symbol)."""
    return ["/* value reference i: {port, element, causality, type} */",
            "static const UiofmuVariable variables[] = {", *(table or ["    {0, 0, 0, 0},"]), "};", "",
            "const UiofmuFmu UIOFMU_FMU = {",
            f"    .guid = {c_string('{' + guid + '}')},",
            f"    .model = {c_string(identifier)},",
            f"    .kernel = &{kernel.symbol},",
            f"    .nvariables = {len(table)}, .variables = variables, .variables_length = UIOFMU_LENGTH(variables),",
            "    .steps = &UIOFMU_STEPS,",
            "};", ""]


def steps_source(spec: dict) -> str:
    """The end of ``design_data.c``: ``UIOFMU_STEPS``, the :class:`~uiofmu.runtime.step_rules.StepRule` of the
    FMU's ``model.json`` ``spec`` (the plumbing applies it before the kernel sees a step, as the python
    backend's slave does)."""
    return rule_source(step_rule(spec))


def rule_source(rule: StepRule) -> str:
    """``UIOFMU_STEPS`` of a :class:`~uiofmu.runtime.step_rules.StepRule` (see :func:`steps_source`)."""
    steps = list(rule.steps)
    return "\n".join(["", "/* the steps it takes (uiofmu/runtime/step_rules.py) */",
                      f"static const double admissible_steps[] = {_doubles(steps, 'steps', len(steps))};",
                      "const UiofmuSteps UIOFMU_STEPS = {",
                      f"    .tiny = {_double(rule.tiny, 'tiny')}, .ulps = {_double(STEP_ULPS, 'ulps')}, "
                      f".ulps_limit = {_double(STEP_ULPS_LIMIT, 'ulps_limit')}, .nsteps = {len(steps)},",
                      "    .steps = admissible_steps, .steps_length = UIOFMU_LENGTH(admissible_steps),",
                      "};", ""])


def plant_kernel(data: dict) -> CKernel:
    """The C kernel of a plant's data: its kind's (:attr:`uiofmu.runtime.plant_kinds.PlantKind.c_kernel`), completed
    by the value its :attr:`~uiofmu.runtime.plant_kinds.PlantKind.variant` names (``switched-<rule>``,
    ``lpv-<kind of theta>``); FmuError for a plant kind without one (:data:`PYTHON_ONLY`)."""
    kind = data_kind(data)
    if kind.c_kernel is None:
        raise FmuError(f"--backend c: {kind.python_only}; use --backend python (or leave --backend out: "
                       "the default picks python for this plant)")
    if kind.variant is None:
        return PLANT_KERNELS[kind.c_kernel]
    table, key = kind.variant
    value = data.get(table, {}).get(key) if isinstance(data.get(table), dict) else None
    prefix = f"{kind.c_kernel}-"
    options = tuple(name[len(prefix):] for name in PLANT_KERNELS if name.startswith(prefix))
    if value not in options:
        raise FmuError(f"plant {table}.{key}: expected one of {', '.join(options)}, found {str(value)[:40]!r}")
    return PLANT_KERNELS[prefix + value]


def _switched_source(data: dict, guid: str, identifier: str) -> str:
    """``design_data.c`` of a switched plant (:meth:`uiofmu.switched_plant.SwitchedPlant.to_data`): see
    :func:`plant_source`. Every mode's ``A, B, E, w`` as one block of each array, mode i the block
    i - 1; the rule as its numbers (the cumulative probabilities summed here, as the reference
    runtime sums them, so both draw the same modes)."""
    kernel = plant_kernel(data)
    sw = data["switching"]
    rule = sw["rule"]
    modes = data["modes"]
    if not isinstance(modes, list) or not 1 <= len(modes) <= 4096:
        raise FmuError("plant modes: expected a list of 1 to 4096 modes")
    if data.get("time") != "discrete":
        raise FmuError(f"plant time: a switched plant is discrete, found {str(data.get('time'))[:40]!r}")
    C = np.asarray(data["C"], dtype=float)
    if C.ndim != 2 or not C.shape[1]:
        raise FmuError(f"plant C: expected a matrix, found shape {C.shape}")
    p, n = C.shape
    A = [np.asarray(md["A"], dtype=float) for md in modes]
    B = [np.asarray(md.get("B") if md.get("B") is not None else np.zeros((n, 0)), dtype=float).reshape(n, -1)
         for md in modes]
    E = [np.asarray(md["E"], dtype=float).reshape(n, -1) for md in modes]
    w = [np.asarray(md.get("w") or np.zeros(n), dtype=float) for md in modes]
    m, q, N = B[0].shape[1], E[0].shape[1], len(modes)
    if any(b.shape[1] != m for b in B) or any(e.shape[1] != q for e in E):
        raise FmuError("plant modes: every mode needs the same numbers of known and unknown inputs")
    x0 = np.asarray(data.get("x0") or np.zeros(n), dtype=float)
    thresholds = list(sw.get("thresholds", [])) if rule == "threshold" else []
    cumulative = np.cumsum(sw.get("probabilities", [1.0])).tolist() if rule == "random" else []
    state = _count(sw.get("state", 1), "plant switching.state") - 1 if rule == "threshold" else 0
    mode0 = _count(sw.get("mode0", 1), "plant switching.mode0") if rule == "input" else 1
    seed = sw.get("seed", 0) if rule == "random" else 0
    if isinstance(seed, bool) or not isinstance(seed, int) or not -2 ** 31 <= seed < 2 ** 31:
        raise FmuError(f"plant switching.seed: expected an fmi2Integer, found {str(seed)[:40]!r}")
    table = table_rows(kernel, "switched plant", plant_ports(n, m, p, q, (), rule))
    arrays = (("A", A, N * n * n), ("B", B, N * n * m), ("E", E, N * n * q), ("C", C, p * n), ("w", w, N * n),
              ("x0", x0, n), ("W", [], 0), ("thresholds", thresholds, len(thresholds)),
              ("cumulative", cumulative, len(cumulative)), ("D", np.zeros((p, m)), p * m),
              ("F", np.zeros((p, q)), p * q))
    switching = (f".modes = {N}, .rule = {RULES[rule]}, .state = {state}, .nthresholds = {len(thresholds)}, "
                 f".mode0 = {mode0}, .seed = {int(seed)},")
    return _plant_data_source("a switched plant", kernel, "UiofmuPlant UIOFMU_PLANT", arrays,
                              f".n = {n}, .m = {m}, .p = {p}, .q = {q}, .time = UIOFMU_DISCRETE,",
                              data.get("dt") or 0.0, [switching], guid, identifier, table)


def _lpv_source(data: dict, guid: str, identifier: str) -> str:
    """``design_data.c`` of an LPV plant (:meth:`uiofmu.lpv_plant.LpvPlant.to_data`): see
    :func:`plant_source`. Each of ``A, E, C, D`` as ``1 + s`` blocks, block 0 the constant part and
    block i the part of theta^(i); ``T`` (kind ``state``; zeros for ``input``) and ``x0``; the
    variable table from :func:`uiofmu.runtime.ports.lpv_plant_ports`."""
    kernel = plant_kernel(data)
    kind = data["theta"]["kind"]
    if data.get("time", "discrete") != "discrete":
        raise FmuError(f"plant time: an LPV plant is discrete, found {str(data.get('time'))[:40]!r}")
    parts = data["scheduling"]
    if not isinstance(parts, list) or not 1 <= len(parts) <= 2048:
        raise FmuError("plant scheduling: expected a list of 1 to 2048 components")
    A = np.asarray(data["A"], dtype=float)
    if A.ndim != 2 or A.shape[0] != A.shape[1] or not A.shape[0]:
        raise FmuError(f"plant A: expected a square matrix, found shape {A.shape}")
    n, s = A.shape[0], len(parts)
    C = np.asarray(data["C"], dtype=float).reshape(-1, n)
    E = np.asarray(data["E"], dtype=float).reshape(n, -1)
    p, q = C.shape[0], E.shape[1]
    D = np.asarray(data.get("D") if data.get("D") is not None else np.zeros((p, q)), dtype=float).reshape(p, q)
    shapes = {"A": (n, n), "E": (n, q), "C": (p, n), "D": (p, q)}
    blocks = {"A": [A], "E": [E], "C": [C], "D": [D]}
    for i, part in enumerate(parts):
        if not isinstance(part, dict):
            raise FmuError(f"plant scheduling[{i}]: expected a table of parts")
        for name, shape in shapes.items():
            value = part.get(name)
            arr = np.zeros(shape) if value is None else np.asarray(value, dtype=float)
            if arr.size != shape[0] * shape[1]:
                raise FmuError(f"plant scheduling[{i}].{name}: expected {shape[0]} x {shape[1]}, found shape "
                               f"{arr.shape}")
            blocks[name].append(arr.reshape(shape))
    T = np.asarray(data["theta"].get("T", np.zeros((s, n))) if kind == "state" else np.zeros((s, n)), dtype=float)
    if T.size != s * n:
        raise FmuError(f"plant theta.T: expected {s} x {n}, found shape {T.shape}")
    x0 = np.asarray(data.get("x0") or np.zeros(n), dtype=float)
    feeds_d = bool(any(np.any(b) for b in blocks["D"]))
    table = table_rows(kernel, "LPV plant", lpv_plant_ports(n, p, q, s, kind, feeds_d))
    arrays = (("A", blocks["A"], (s + 1) * n * n), ("E", blocks["E"], (s + 1) * n * q),
              ("C", blocks["C"], (s + 1) * p * n), ("D", blocks["D"], (s + 1) * p * q), ("T", T, s * n), ("x0", x0, n))
    return _plant_data_source("an LPV plant", kernel, "UiofmuLpv UIOFMU_LPV", arrays,
                              f".n = {n}, .p = {p}, .q = {q}, .s = {s}, .kind = {THETA_KINDS[kind]},",
                              data.get("dt") or 0.0, [], guid, identifier, table)


def plant_source(data: dict, guid: str, identifier: str) -> str:
    """``design_data.c`` of a plant (``Plant.to_data()``, or a switched plant's data with ``modes``
    and ``switching``, or an LPV plant's with ``scheduling``: :func:`_lpv_source`): one constant
    ``UiofmuPlant`` (``c/kernel_plant.h``), its variable table
    (from :func:`uiofmu.runtime.ports.plant_ports`) and ``UIOFMU_FMU``. Numbers only (every float
    by :func:`repr` after a finiteness check, every array with its length checked against the dims
    and compiled with ``UIOFMU_LENGTH``), and the GUID and model identifier as escaped C literals:
    no text of the problem reaches the source."""
    return _PLANT_SOURCES[data_kind(data).c_kernel](data, guid, identifier)


def _linear_source(data: dict, guid: str, identifier: str) -> str:
    """``design_data.c`` of a linear plant (:func:`plant_source`)."""
    kernel = PLANT_KERNELS[LINEAR.c_kernel]
    time = data.get("time")
    if time not in TIMES:
        raise FmuError(f"plant time: expected discrete or continuous, found {str(time)[:40]!r}")
    A = np.asarray(data["A"], dtype=float)
    if A.ndim != 2 or A.shape[0] != A.shape[1] or not A.shape[0]:
        raise FmuError(f"plant A: expected a square matrix, found shape {A.shape}")
    n = A.shape[0]
    C = np.asarray(data["C"], dtype=float).reshape(-1, n)
    B = np.asarray(data.get("B") if data.get("B") is not None else np.zeros((n, 0)), dtype=float).reshape(n, -1)
    E = np.asarray(data["E"], dtype=float).reshape(n, -1)
    w = np.asarray(data.get("w") or np.zeros(n), dtype=float)
    x0 = np.asarray(data.get("x0") or np.zeros(n), dtype=float)
    W = np.asarray(data.get("W") or np.zeros((n, 0)), dtype=float).reshape(n, -1)
    m, q, p, r = B.shape[1], E.shape[1], C.shape[0], W.shape[1]
    D, F = (np.asarray(data[k], dtype=float).reshape(p, cols) if data.get(k) else np.zeros((p, cols))
            for k, cols in (("D", m), ("F", q)))
    dt = float(data.get("dt") or 0.0) if time == "discrete" else 0.0
    feeds = tuple(name for name, M in (("u", D), ("d", F)) if np.any(M))
    table = table_rows(kernel, "linear plant", plant_ports(n, m, p, q, r=r, feeds=feeds))
    arrays = (("A", A, n * n), ("B", B, n * m), ("E", E, n * q), ("C", C, p * n), ("w", w, n), ("x0", x0, n),
              ("W", W, n * r), ("thresholds", [], 0), ("cumulative", [], 0), ("D", D, p * m), ("F", F, p * q))
    return _plant_data_source("a linear plant", kernel, "UiofmuPlant UIOFMU_PLANT", arrays,
                              f".n = {n}, .m = {m}, .p = {p}, .q = {q}, .r = {r}, .time = {TIMES[time]},", dt,
                              [".modes = 0, .rule = UIOFMU_RULE_NONE, .mode0 = 1,"], guid, identifier, table)


def _parametric_source(data: dict, guid: str, identifier: str) -> str:
    """``design_data.c`` of a plant with unknown parameters (:meth:`uiofmu.parametric_plant.ParametricPlant.to_data`):
    see :func:`plant_source`. ``Dy`` dense (``p x n x n_theta``, zero for an output without an entry, as the
    runtime builds it) and the parts of the plant's rate that do not depend on theta as numpy computes them
    (:func:`uiofmu.runtime.parametric_plant.rate`), so both runtimes take the same substeps."""
    kernel = plant_kernel(data)
    if data.get("time") != "continuous":
        raise FmuError("plant time: a plant with unknown parameters is continuous, found "
                       f"{str(data.get('time'))[:40]!r}")
    A = np.asarray(data["A"], dtype=float)
    if A.ndim != 2 or A.shape[0] != A.shape[1] or not A.shape[0]:
        raise FmuError(f"plant A: expected a square matrix, found shape {A.shape}")
    n = A.shape[0]
    B = np.asarray(data["B"], dtype=float).reshape(n, -1)
    C = np.asarray(data["C"], dtype=float).reshape(-1, n)
    par = data["parameters"]
    theta = np.asarray(par["theta"], dtype=float).ravel()
    D0 = np.asarray(par["D0"], dtype=float).reshape(n, theta.size)
    m, p, nt = B.shape[1], C.shape[0], theta.size
    Dy = np.zeros((p, n, nt))
    for entry in par["Dy"]:
        output = _count(entry["output"], "plant parameters.Dy.output")
        if not 1 <= output <= p:
            raise FmuError(f"plant parameters.Dy: output {output} is not one of 1..{p}")
        Dy[output - 1] = np.asarray(entry["D"], dtype=float).reshape(n, nt)
    x0 = np.asarray(data.get("x0") or np.zeros(n), dtype=float)
    table = table_rows(kernel, "plant with unknown parameters", parametric_plant_ports(n, m, p, nt))
    arrays = (("A", A, n * n), ("B", B, n * m), ("C", C, p * n), ("D0", D0, n * nt), ("Dy", Dy, p * n * nt),
              ("x0", x0, n), ("theta", theta, nt))
    rate = (f".norm_A = {_double(np.linalg.norm(A, 2), 'norm_A')}, "
            f".norm_C = {_double(np.linalg.norm(C, 2), 'norm_C')}, "
            f".sum_Dy = {_double(np.abs(Dy).sum(), 'sum_Dy')}, .sum_D0 = {_double(np.abs(D0).sum(), 'sum_D0')},")
    lines = ["/* Generated by uiofmu from a plant with unknown parameters. */", f'#include "{kernel.header}"', "",
             *(f"static const double m_{key}[] = {_doubles(arr, f'plant.{key}', size)};" for key, arr, size in arrays),
             "", "const UiofmuParametric UIOFMU_PARAMETRIC = {", f"    .n = {n}, .m = {m}, .p = {p}, .nt = {nt},",
             f"    {rate}",
             "    " + ", ".join(f".{k} = m_{k}, .{k}_length = UIOFMU_LENGTH(m_{k})" for k, _, _ in arrays) + ",",
             "};", "", *fmu_table(guid, identifier, kernel, table)]
    return "\n".join(lines)


#: The generator of ``design_data.c`` of each plant C kernel (:attr:`uiofmu.runtime.plant_kinds.PlantKind.c_kernel`).
_PLANT_SOURCES = {"linear": _linear_source, "switched": _switched_source, "lpv": _lpv_source,
                  "parametric": _parametric_source}


def _plant_data_source(what: str, kernel: CKernel, declaration: str, arrays, dims: str, dt: float, fields: list,
                       guid: str, identifier: str, table: list) -> str:
    """The text of a plant's ``design_data.c`` (every plant kind): each ``(key, values, size)`` of
    ``arrays`` as ``m_<key>`` (:func:`_doubles`: finite, ``size`` numbers), the constant
    ``declaration`` (``"UiofmuPlant UIOFMU_PLANT"``) of the field lines ``dims``, the period ``dt``
    with :data:`STEP_RTOL`, ``fields`` and every array with its length, then :func:`fmu_table`."""
    lines = [f"/* Generated by uiofmu from {what}. */", f'#include "{kernel.header}"', "",
             *(f"static const double m_{key}[] = {_doubles(arr, f'plant.{key}', size)};" for key, arr, size in arrays)]
    lengths = ", ".join(f".{k} = m_{k}, .{k}_length = UIOFMU_LENGTH(m_{k})" for k, _, _ in arrays)
    lines += ["", f"const {declaration} = {{", f"    {dims}",
              f"    .dt = {_double(dt, 'plant.dt')}, .step_rtol = {_double(STEP_RTOL, 'step_rtol')},",
              *(f"    {line}" for line in fields), f"    {lengths},", "};", "",
              *fmu_table(guid, identifier, kernel, table)]
    return "\n".join(lines)


def write_variables(root, ports) -> None:
    """``<ModelVariables>`` and ``<ModelStructure>`` of a declaration (value references in its order).

    Parameters are ``fixed`` and ``exact`` with their start values; inputs ``continuous`` with
    theirs (an Integer input ``discrete``: FMI 2.0 has no continuous Integer); outputs
    ``calculated`` (their first values follow from the parameters and, for those that declare
    it, the inputs; :func:`uiofmu.runtime.ports.model_structure`). Integer ports (modes) are
    written as ``<Integer>`` with integral start values.
    """
    variables = SubElement(root, "ModelVariables")
    index = 0
    for port in ports:
        for i in range(port.size):
            attrs = {"name": f"{port.name}[{i + 1}]", "valueReference": str(index), "causality": port.causality,
                     "description": port.description}
            integer = getattr(port, "spec", port).type == "Integer"
            variability = "discrete" if integer else "continuous"
            if port.causality == "output":           # no start value: a declaration of outputs only has none
                attrs.update(variability=variability, initial="calculated")
                start = {}
            else:
                start = {"start": str(int(port.values[i])) if integer else repr(float(port.values[i]))}
                if port.causality == "parameter":
                    attrs.update(variability="fixed", initial="exact")
                else:
                    attrs["variability"] = variability
            SubElement(SubElement(variables, "ScalarVariable", attrs), "Integer" if integer else "Real", start)
            index += 1
    model_structure(root, ports)


def model_description(card: Card, guid: str, identifier: str, sources: list[str]) -> bytes:
    """``modelDescription.xml`` with the ports of the python backend."""
    from ..runtime.fmu_model import make_model

    model = make_model({"kind": "observer", "card": card.data})
    model.refresh()
    return description_xml(identifier, guid, f"{card.family} unknown-input observer of {card.name} "
                           f"(uiofmu {__version__}, C backend)", sources, observer_experiment(card), model.ports,
                           model.labels, step_rule({"kind": "observer", "card": card.data}).variable)


def plant_model_description(spec: dict, description: str, guid: str, identifier: str, sources: list[str]) -> bytes:
    """``modelDescription.xml`` of a C plant FMU of ``spec`` (its ``resources/model.json``): the ports and the
    names and units of the python backend's plant."""
    from ..runtime.fmu_model import make_model

    model = make_model(spec)
    model.refresh()
    return description_xml(identifier, guid, description, sources, spec.get("experiment"), model.ports, model.labels,
                           step_rule(spec).variable)


def description_xml(identifier: str, guid: str, description: str, sources: list[str], experiment: dict | None,
                    ports, labels: dict | None = None, variable_steps: bool = True) -> bytes:
    """The ``modelDescription.xml`` of every C FMU: Co-Simulation without an execution tool, its
    ``<SourceFiles>`` (none when ``sources`` is empty), the plumbing's ``<LogCategories>``,
    ``<DefaultExperiment>`` (when given), the variables and structure of ``ports`` (:func:`write_variables`)
    and their names and units (``labels``: :func:`uiofmu.runtime.labels.apply_labels`);
    ``canHandleVariableCommunicationStepSize`` is ``variable_steps``
    (:attr:`uiofmu.runtime.step_rules.StepRule.variable`)."""
    root = Element("fmiModelDescription", {
        "fmiVersion": "2.0", "modelName": identifier, "guid": f"{{{guid}}}",
        "description": description,
        "generationTool": f"uiofmu {__version__}", "variableNamingConvention": "structured",
        "numberOfEventIndicators": "0"})
    cs = SubElement(root, "CoSimulation", {
        "modelIdentifier": identifier, "needsExecutionTool": "false",
        "canHandleVariableCommunicationStepSize": "true" if variable_steps else "false",
        "canInterpolateInputs": "false",
        "canBeInstantiatedOnlyOncePerProcess": "false", "canNotUseMemoryManagementFunctions": "true",
        "canGetAndSetFMUstate": "true", "canSerializeFMUstate": "true"})
    if sources:                                        # FMI 2.0: a <SourceFiles> lists one file at least
        files = SubElement(cs, "SourceFiles")
        for name in sources:
            SubElement(files, "File", {"name": name})
    cats = SubElement(root, "LogCategories")
    for name in LOG_CATEGORIES:
        SubElement(cats, "Category", {"name": name})
    if experiment:
        write_experiment(root, experiment)
    write_variables(root, ports)
    apply_labels(root, ports, labels or {})
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + tostring(root, encoding="utf-8")


def compile_binary(src: Path, identifier: str, out: Path, extra_flags=(), sources=None, libraries=()) -> Path:
    """Compile the C files ``sources`` (names in ``src``; default: every ``*.c`` there) into
    ``out/<identifier>.so`` with the system compiler, linked with ``libraries`` (linker arguments, after the
    sources)."""
    cc = c_compiler()
    if cc is None:
        raise FmuError("--backend c needs a C compiler (cc or gcc) on PATH; use --backend python")
    out.mkdir(parents=True, exist_ok=True)
    lib = out / f"{identifier}.so"
    files = [str(src / name) for name in sources] if sources is not None else sorted(map(str, src.glob("*.c")))
    cmd = [cc, "-std=c99", "-O2", "-shared", "-fPIC", "-fvisibility=hidden", "-Wall", "-Wextra",
           f"-I{src}", *extra_flags, "-o", str(lib), *files, *libraries, "-lm"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise FmuError(f"the C compiler failed on the generated FMU: {proc.stderr.strip()[:2000]}")
    return lib


def fmi_headers() -> Path:
    """The FMI 2.0 headers that fmpy ships (found without importing fmpy)."""
    spec = importlib.util.find_spec("fmpy")
    if spec is None or not spec.submodule_search_locations:
        raise FmuError("--backend c needs the FMI 2.0 headers that fmpy ships: install fmpy")
    return Path(next(iter(spec.submodule_search_locations))) / "c-code"


def _check_platform() -> None:
    if platform.system() != "Linux" or platform.machine() not in ("x86_64", "AMD64"):
        raise FmuError("--backend c builds linux64 binaries only; the FMU's sources/ rebuild elsewhere")


def guid_of(data) -> str:
    """The GUID of a model's data (a name-based UUID of its JSON: equal data, equal GUID)."""
    return str(uuid.uuid5(uuid.NAMESPACE_URL, "uiofmu:" + json.dumps(data, sort_keys=True)))


def declaration(spec: dict) -> list:
    """The ports (PortSpecs) of the model of ``spec`` (``resources/model.json``: an observer's card or a
    plant's data), as the python backend declares them."""
    from ..runtime.fmu_model import make_model

    return [port.spec for port in make_model(spec).ports]


def pack_c_fmu(output: Path, identifier: str, kernel: CKernel, design: str, description, spec: dict,
               extra_flags=(), *, ports=None, rule: StepRule | None = None, resources: dict | None = None,
               linked=None) -> Path:
    """Compile and zip one C FMU: the plumbing, what the kernels share, ``kernel`` with its port header
    (:func:`port_header` of the ports of ``spec``'s model, the ones ``modelDescription.xml`` declares) and
    the generated ``design`` (the text of ``design_data.c``) into ``binaries/linux64/<identifier>.so``,
    those sources and the FMI headers into ``sources/``, ``description(sources)`` (the bytes of
    ``modelDescription.xml``) and ``spec`` as ``resources/model.json``; written atomically to ``output``.

    A model that is neither an observer nor a plant (a signal source) gives its declaration ``ports``,
    its step ``rule`` and its data files ``resources`` (``{name: bytes}``, written to ``resources/``).
    ``linked`` (a :class:`LinkedLibrary`) adds a prebuilt shared library: its headers to the compiler,
    the library to the link with the run path ``$ORIGIN``, the library itself next to the binary and
    its ``resources`` (name -> file) into ``resources/``, its ``ports`` as the declaration; ``description``
    then gets no source list (the sources alone do not rebuild the FMU)."""
    if ports is None:
        ports = linked.ports if linked is not None else declaration(spec)
    header = port_header(kernel, ports)
    with tempfile.TemporaryDirectory(prefix="uiofmu_c_") as tmp:
        src = Path(tmp) / "sources"
        src.mkdir()
        sources = kernel_sources(kernel)
        for name in (*PLUMBING_SOURCES, *PLUMBING_HEADERS, *KERNEL_UTIL_SOURCES, *KERNEL_UTIL_HEADERS,
                     kernel.source, kernel.header):
            shutil.copy2(HERE / name, src / name)
        for name in FMI_HEADERS:
            shutil.copy2(fmi_headers() / name, src / name)
        (src / kernel.ports_header).write_text(header)
        (src / REFUSALS_HEADER).write_text(refusals_header())
        (src / "design_data.c").write_text(design + (steps_source(spec) if rule is None else rule_source(rule)))
        flags, libraries = list(extra_flags), []
        if linked is not None:
            flags.append(f"-I{linked.include}")
            libraries = [f"-L{linked.library.parent}", f"-l:{linked.library.name}", "-Wl,-rpath,$ORIGIN"]
        lib = compile_binary(src, identifier, Path(tmp) / "binaries" / "linux64", flags, sources, libraries)
        with atomic_output(output, "FMU") as part, zipfile.ZipFile(part, "w", zipfile.ZIP_DEFLATED) as z:
            z.writestr("modelDescription.xml", description(sources if linked is None else []))
            z.write(lib, f"binaries/linux64/{identifier}.so")
            if linked is not None:
                z.write(linked.library, f"binaries/linux64/{linked.library.name}")
                for name, file in linked.resources.items():
                    z.write(file, f"resources/{name}")
            for f in sorted(src.iterdir()):
                z.write(f, f"sources/{f.name}")
            z.writestr("resources/model.json", json.dumps(spec))
            for name, data in sorted((resources or {}).items()):
                z.writestr(f"resources/{name}", data)
    return output


def rebuild_c_fmu(fmu, output, replace: dict | None = None) -> Path:
    """Rebuild the binary of a C FMU from the sources it carries (``sources/``, the files its
    ``<SourceFiles>`` lists compiled as :func:`compile_binary` does), with the files of ``replace``
    (``{name: text}``, only names it has) in place of its own; that FMU written to ``output``.

    Other C sources of the same generated design data (the plumbing and kernels of another version,
    say) run through the same FMU this way.
    """
    output = check_output_file(output, "FMU", ".fmu")
    with zipfile.ZipFile(fmu) as z:
        members = {name: z.read(name) for name in z.namelist() if not name.endswith("/")}
    cs = fromstring(members["modelDescription.xml"]).find("CoSimulation")
    if cs is None or cs.find("SourceFiles") is None:
        raise FmuError(f"{fmu}: not an FMU with C sources (no CoSimulation SourceFiles)")
    identifier = cs.get("modelIdentifier")
    sources = [f.get("name") for f in cs.find("SourceFiles").findall("File")]
    unknown = sorted(set(replace or {}) - {name[len("sources/"):] for name in members if name.startswith("sources/")})
    if unknown:
        raise FmuError(f"{fmu}: has no sources/{unknown[0]} to replace")
    with tempfile.TemporaryDirectory(prefix="uiofmu_c_") as tmp:
        src = Path(tmp) / "sources"
        src.mkdir()
        for name, data in members.items():
            if name.startswith("sources/"):
                (src / name[len("sources/"):]).write_bytes(data)
        for name, text in (replace or {}).items():
            (src / name).write_text(text)
        lib = compile_binary(src, identifier, Path(tmp) / "binaries", sources=sources)
        members[f"binaries/linux64/{identifier}.so"] = lib.read_bytes()
        for name, text in (replace or {}).items():
            members[f"sources/{name}"] = text.encode()
        with atomic_output(output, "FMU") as part, zipfile.ZipFile(part, "w", zipfile.ZIP_DEFLATED) as z:
            for name, data in members.items():
                z.writestr(name, data)
    return output


@dataclass(frozen=True)
class LinkedLibrary:
    """A prebuilt shared library a C FMU links with and ships (:func:`pack_c_fmu`).

    Attributes
    ----------
    library : Path
        The library file (``libmujoco.so.4.0.0``), copied into ``binaries/linux64/`` under its name,
        which must be its soname.
    include : Path
        The folder of its headers (given to the compiler with ``-I``).
    resources : dict
        Files the kernel reads at run time: name in ``resources/`` -> file.
    ports : list
        The FMU's ports (PortSpecs, as ``modelDescription.xml`` declares them): its model reads files
        that :func:`declaration` does not have.
    """

    library: Path
    include: Path
    resources: dict
    ports: list


def build_c_observer(card: Card, output, identifier: str, call_floor: bool = False) -> Path:
    """Write the C observer FMU of ``card`` to ``output``.

    ``call_floor`` builds a benchmark variant whose fmi2DoStep returns at once (the cost of the
    FMI call itself); never use it for anything else.
    """
    output = check_output_file(output, "FMU", ".fmu")
    c_kernel(card)                         # a card the C backend has no kernel for is refused first
    _check_platform()
    guid = guid_of(card.data)
    return pack_c_fmu(output, identifier, c_kernel(card), design_source(card, guid, identifier),
                      lambda sources: model_description(card, guid, identifier, sources),
                      {"kind": "observer", "card": card.data}, ["-DUIOFMU_CALL_FLOOR"] if call_floor else [])


def build_c_plant(plant, output, identifier: str, experiment: dict | None = None,
                  description: str | None = None, call_floor: bool = False, labels: dict | None = None) -> Path:
    """Write the C FMU of a plant to ``output`` (``c/kernel_plant.c``: exact zero-order hold for
    any step of a continuous plant, dt only for a discrete one; a switched plant in its current
    mode, picked by its rule; ``c/kernel_lpv.c``: an LPV plant at its theta, from the state or
    the input ``theta``; ``c/kernel_parametric.c``: a plant with unknown parameters, RK4 substeps).

    Parameters
    ----------
    plant : Plant, SwitchedPlant, LpvPlant or ParametricPlant
        A checked linear, switched or LPV plant (:mod:`uiofmu.plant`, :mod:`uiofmu.switched_plant`,
        :mod:`uiofmu.lpv_plant`) or a plant with unknown parameters (:mod:`uiofmu.parametric_plant`).
    output : str or Path
        The ``.fmu`` file to write.
    identifier : str
        The model identifier (an ASCII identifier).
    experiment : dict, optional
        Its ``<DefaultExperiment>`` (:func:`uiofmu.runtime.ports.plant_experiment`).
    description : str, optional
        The ``description`` attribute of the model description.
    call_floor : bool, optional
        A benchmark variant whose fmi2DoStep returns at once (as :func:`build_c_observer`).
    labels : dict, optional
        Names and units of its states, inputs and outputs (a problem's ``labels``): descriptions and
        units of its variables, never in its sources.

    Returns
    -------
    Path
    """
    output = check_output_file(output, "FMU", ".fmu")
    data = plant.to_data()
    plant_kernel(data)                     # a plant the C backend has no kernel for is refused first
    _check_platform()
    spec = plant_spec(data, experiment, labels)
    guid = guid_of({"backend": "c", **spec})
    what = data_kind(data).what
    text = description or f"{plant.time} {what} (uiofmu {__version__}, C backend)"
    return pack_c_fmu(output, identifier, plant_kernel(data), plant_source(data, guid, identifier),
                      lambda sources: plant_model_description(spec, text, guid, identifier, sources),
                      spec, ["-DUIOFMU_CALL_FLOOR"] if call_floor else [])


def build_host(out_dir) -> Path:
    """Compile uiofmu's minimal C host (``c/fmu_host.c``: dlopen, no Python) into ``out_dir``."""
    cc = c_compiler()
    if cc is None:
        raise FmuError("building the C host needs a C compiler (cc or gcc) on PATH")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    exe = out_dir / "fmu_host"
    proc = subprocess.run([cc, "-std=c99", "-O2", "-g", "-Wall", f"-I{fmi_headers()}", "-o", str(exe),
                           str(HERE / "fmu_host.c"), "-ldl"], capture_output=True, text=True)
    if proc.returncode != 0:
        raise FmuError(f"the C compiler failed on fmu_host.c: {proc.stderr.strip()[:2000]}")
    return exe
