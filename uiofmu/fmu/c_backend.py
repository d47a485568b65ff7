"""The C backend: a standalone native observer FMU (no Python in the importer).

The card's matrices become constant C data (``design_data.c``, with the variable table of the
card's ports) next to the card's kernel (``c/kernel_affine.c``: the observer maths) and the shared
FMI 2.0 Co-Simulation plumbing (``c/fmi2_plumbing.c``: states and legal calls, logging, get/set,
FMU states, status queries); the system C compiler builds ``binaries/linux64/<model>.so``. The
sources and the FMI headers travel in ``sources/`` with a ``<SourceFiles>`` list, so ``fmpy
compile`` rebuilds the binary on another platform. The interface (names, value references,
start values) is the one of the python backend, enumerated from the same ports.
"""

from __future__ import annotations

import json
import math
import platform
import shutil
import subprocess
import tempfile
import uuid
import zipfile
from dataclasses import dataclass
from pathlib import Path
from xml.etree.ElementTree import Element, SubElement, tostring

import numpy as np

from .. import __version__
from ..runtime.card import Card
from ..runtime.errors import CardError, FmuError
from ..runtime.files import atomic_output, check_output_file
from ..runtime.schedules import schedule_axes
from ..runtime.ports import model_structure, observer_experiment, write_experiment
from ..runtime.text import c_string
from ..runtime.tolerances import STEP_RTOL

HERE = Path(__file__).parent / "c"
MATRIX_ORDER = ("N", "L", "G", "c", "Xz", "Xy", "C", "Dy", "Yx", "Yu", "Yc")
KINDS = {"constant": "UIOFMU_CONSTANT", "interval": "UIOFMU_INTERVAL", "geometric": "UIOFMU_GEOMETRIC"}
POLICIES = {"error": "UIOFMU_POLICY_ERROR", "nearest": "UIOFMU_POLICY_NEAREST", "count": "UIOFMU_POLICY_COUNT"}

#: The shared FMI 2.0 plumbing (``c/fmi2_plumbing.c``: instance states and legal calls, logging, get/set
#: through the variable table, FMU state image, status queries) and its header (the model interface).
PLUMBING_SOURCES = ("fmi2_plumbing.c",)
PLUMBING_HEADERS = ("fmi2_plumbing.h",)
FMI_HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
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
    ports : dict
        ``{port name: (C enum name, causality, type)}``: every port the kernel implements.
    """

    source: str
    header: str
    symbol: str
    ports: dict


#: The C kernels, by the card's ``kernel``.
C_KERNELS = {
    "affine": CKernel("kernel_affine.c", "kernel_affine.h", "UIOFMU_KERNEL_AFFINE", {
        "xhat0": ("UIOFMU_AFFINE_XHAT0", "parameter", "Real"),
        "h_prev0": ("UIOFMU_AFFINE_H_PREV0", "parameter", "Real"),
        "y": ("UIOFMU_AFFINE_Y", "input", "Real"),
        "u": ("UIOFMU_AFFINE_U", "input", "Real"),
        "xhat": ("UIOFMU_AFFINE_XHAT", "output", "Real"),
        "r": ("UIOFMU_AFFINE_R", "output", "Real"),
        "dhat": ("UIOFMU_AFFINE_DHAT", "output", "Real"),
    }),
}


def c_kernel(card: Card) -> CKernel:
    """The C kernel of a card; FmuError when there is none for its ``kernel``."""
    kernel = C_KERNELS.get(card.kernel)
    if kernel is None:
        raise FmuError(f"the C backend has no kernel {str(card.kernel)[:40]!r} (it has {', '.join(C_KERNELS)}); "
                       "use --backend python")
    return kernel


def c_sources(card: Card) -> list:
    """The C files of a card's FMU in the order they are compiled (plumbing, kernel, generated data)."""
    return [*PLUMBING_SOURCES, c_kernel(card).source, "design_data.c"]


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
    kernel = c_kernel(card)
    rows = []
    for port in card.ports:
        known = kernel.ports.get(port.name)
        if known is None:
            raise FmuError(f"the C {card.kernel} kernel has no port {str(port.name)[:40]!r} "
                           f"(it implements {', '.join(kernel.ports)})")
        enum, causality, kind = known
        if (port.causality, port.type) != (causality, kind):
            article = {"parameter": "a", "input": "an", "output": "an"}
            raise FmuError(f"port {port.name}: declared {article.get(port.causality, 'a')} {str(port.causality)[:20]} "
                           f"{str(port.type)[:20]}, the C {card.kernel} kernel implements {article[causality]} "
                           f"{causality} {kind}")
        if not isinstance(port.size, int) or isinstance(port.size, bool) or not 0 <= port.size <= 1 << 24:
            raise FmuError(f"port {port.name}: size {str(port.size)[:20]} is not a count")
        rows += [f"    {{{enum}, {i}, {CAUSALITIES[causality]}, {PORT_TYPES[kind]}}}," for i in range(port.size)]
    return rows


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
    d = card.dims
    sched = card.schedule
    kind = sched["kind"]
    kernel = c_kernel(card)
    table = variable_table(card)
    lines = ["/* Generated by uiofmu from a design card. */", f'#include "{kernel.header}"', ""]
    fields = []
    axes = schedule_axes(sched)
    for name in MATRIX_ORDER:
        if name not in card.matrices:
            fields.append(f"        [M_{name}] = {{0, 0, 0, 0, 0}},")
            continue
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
    lines += ["", "const UiofmuDesign UIOFMU_DESIGN = {",
              f"    .n = {int(d['n'])}, .m = {int(d['m'])}, .p = {int(d['p'])}, .q = {int(d['q'])}, "
              f".nz = {int(d['nz'])}, .has_dhat = {int(card.has_dhat)},",
              f"    .kind = {KINDS[kind]}, .policy = {POLICIES[sched.get('step_policy', 'error')]},",
              f"    .dt = {_double(dt, 'schedule.dt')}, .alpha = {_double(sched.get('alpha', 0.0), 'schedule.alpha')}, "
              f".h_prev0 = {_double(sched.get('h_prev0', dt), 'schedule.h_prev0')}, "
              f".step_rtol = {_double(sched.get('step_rtol', STEP_RTOL), 'schedule.step_rtol')},",
              f"    .nintervals = {len(intervals)}, .intervals = intervals, "
              ".intervals_length = UIOFMU_LENGTH(intervals),",
              "    .xhat0 = xhat0, .xhat0_length = UIOFMU_LENGTH(xhat0),",
              "    .mat = {", *fields, "    },", "};", "",
              "/* value reference i: {port, element, causality, type} */",
              "static const UiofmuVariable variables[] = {", *(table or ["    {0, 0, 0, 0},"]), "};", "",
              "const UiofmuFmu UIOFMU_FMU = {",
              f"    .guid = {c_string('{' + guid + '}')},",
              f"    .model = {c_string(identifier)},",
              f"    .kernel = &{kernel.symbol},",
              f"    .nvariables = {len(table)}, .variables = variables, .variables_length = UIOFMU_LENGTH(variables),",
              "};", ""]
    return "\n".join(lines)


def write_variables(root, ports) -> None:
    """``<ModelVariables>`` and ``<ModelStructure>`` of a declaration (value references in its order).

    Parameters are ``fixed`` and ``exact`` with their start values; inputs ``continuous`` with
    theirs; outputs ``calculated`` (their first values follow from the parameters and, for those
    that declare it, the inputs; :func:`uiofmu.runtime.ports.model_structure`).
    """
    variables = SubElement(root, "ModelVariables")
    index = 0
    for port in ports:
        for i in range(port.size):
            attrs = {"name": f"{port.name}[{i + 1}]", "valueReference": str(index), "causality": port.causality,
                     "description": port.description}
            start = {"start": repr(float(port.values[i]))}
            if port.causality == "parameter":
                attrs.update(variability="fixed", initial="exact")
            elif port.causality == "output":
                attrs.update(variability="continuous", initial="calculated")
                start = {}
            else:
                attrs["variability"] = "continuous"
            SubElement(SubElement(variables, "ScalarVariable", attrs), "Real", start)
            index += 1
    model_structure(root, ports)


def model_description(card: Card, guid: str, identifier: str, sources: list[str]) -> bytes:
    """``modelDescription.xml`` with the ports of the python backend."""
    from ..runtime.fmu_model import ObserverModel

    model = ObserverModel({"card": card.data})
    model.refresh()
    root = Element("fmiModelDescription", {
        "fmiVersion": "2.0", "modelName": identifier, "guid": f"{{{guid}}}",
        "description": f"{card.family} unknown-input observer of {card.name} (uiofmu {__version__}, C backend)",
        "generationTool": f"uiofmu {__version__}", "variableNamingConvention": "structured",
        "numberOfEventIndicators": "0"})
    cs = SubElement(root, "CoSimulation", {
        "modelIdentifier": identifier, "needsExecutionTool": "false",
        "canHandleVariableCommunicationStepSize": "true", "canInterpolateInputs": "false",
        "canBeInstantiatedOnlyOncePerProcess": "false", "canNotUseMemoryManagementFunctions": "true",
        "canGetAndSetFMUstate": "true", "canSerializeFMUstate": "true"})
    files = SubElement(cs, "SourceFiles")
    for name in sources:
        SubElement(files, "File", {"name": name})
    cats = SubElement(root, "LogCategories")
    for name in LOG_CATEGORIES:
        SubElement(cats, "Category", {"name": name})
    write_experiment(root, observer_experiment(card))
    write_variables(root, model.ports)
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + tostring(root, encoding="utf-8")


def compile_binary(src: Path, identifier: str, out: Path, extra_flags=(), sources=None) -> Path:
    """Compile the C files ``sources`` (names in ``src``; default: every ``*.c`` there) into
    ``out/<identifier>.so`` with the system compiler."""
    cc = c_compiler()
    if cc is None:
        raise FmuError("--backend c needs a C compiler (cc or gcc) on PATH; use --backend python")
    out.mkdir(parents=True, exist_ok=True)
    lib = out / f"{identifier}.so"
    files = [str(src / name) for name in sources] if sources is not None else sorted(map(str, src.glob("*.c")))
    cmd = [cc, "-std=c99", "-O2", "-shared", "-fPIC", "-fvisibility=hidden", "-Wall", "-Wextra",
           f"-I{src}", *extra_flags, "-o", str(lib), *files, "-lm"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise FmuError(f"the C compiler failed on the generated observer: {proc.stderr.strip()[:2000]}")
    return lib


def fmi_headers() -> Path:
    """The FMI 2.0 headers that fmpy ships."""
    import fmpy

    return Path(fmpy.__file__).parent / "c-code"


def build_c_observer(card: Card, output, identifier: str, call_floor: bool = False) -> Path:
    """Write the C observer FMU of ``card`` to ``output``.

    ``call_floor`` builds a benchmark variant whose fmi2DoStep returns at once (the cost of the
    FMI call itself); never use it for anything else.
    """
    output = check_output_file(output, "FMU", ".fmu")
    if platform.system() != "Linux" or platform.machine() not in ("x86_64", "AMD64"):
        raise FmuError("--backend c builds linux64 binaries only; the FMU's sources/ rebuild elsewhere")
    guid = str(uuid.uuid5(uuid.NAMESPACE_URL, "uiofmu:" + json.dumps(card.data, sort_keys=True)))
    with tempfile.TemporaryDirectory(prefix="uiofmu_c_") as tmp:
        src = Path(tmp) / "sources"
        src.mkdir()
        kernel = c_kernel(card)
        sources = c_sources(card)
        for name in (*PLUMBING_SOURCES, *PLUMBING_HEADERS, kernel.source, kernel.header):
            shutil.copy2(HERE / name, src / name)
        for name in FMI_HEADERS:
            shutil.copy2(fmi_headers() / name, src / name)
        (src / "design_data.c").write_text(design_source(card, guid, identifier))
        lib = compile_binary(src, identifier, Path(tmp) / "binaries" / "linux64",
                             ["-DUIOFMU_CALL_FLOOR"] if call_floor else [], sources)
        with atomic_output(output, "FMU") as part, zipfile.ZipFile(part, "w", zipfile.ZIP_DEFLATED) as z:
            z.writestr("modelDescription.xml", model_description(card, guid, identifier, sources))
            z.write(lib, f"binaries/linux64/{identifier}.so")
            for f in sorted(src.iterdir()):
                z.write(f, f"sources/{f.name}")
            z.writestr("resources/model.json", json.dumps({"kind": "observer", "card": card.data}))
    return output


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
