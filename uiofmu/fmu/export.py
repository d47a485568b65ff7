"""Packing observers and plants as FMI 2.0 Co-Simulation FMUs.

Backend ``python`` (pythonfmu): one generic slave (``templates/pythonfmu_slave.py.tmpl``) plus the
model as data (``resources/model.json``) plus a copy of the numpy-only runtime, in the
shape of pythonfmu's csv builder. The host Python needs numpy and nothing else of uiofmu.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import sys
import tempfile
from pathlib import Path

from .. import __version__
from . import pythonfmu_guard
from ..runtime.card import Card
from ..runtime.errors import FmuError
from ..runtime.files import atomic_output, check_output_file
from ..plant import Plant
from ..plant_kinds import plant_kind as kind_of
from ..runtime.ports import observer_experiment, plant_experiment, plant_spec
from ..runtime.step_rules import step_rule
from ..runtime.text import fill_template, identifier, py_string

#: What an FMU carries: the package :mod:`uiofmu.runtime`, copied whole (numpy only).
RUNTIME = Path(__file__).resolve().parents[1] / "runtime"
BACKENDS = ("c", "python")


def runtime_files() -> list[Path]:
    """The files of :data:`RUNTIME`, in a fixed order (every ``.py`` file of the folder)."""
    return sorted(RUNTIME.glob("*.py"))


def runtime_package() -> str:
    """Name of the runtime copy inside an FMU: it changes with the runtime's source, so FMUs built
    by different uiofmu versions load side by side in one process without sharing modules."""
    digest = hashlib.sha256()
    for path in runtime_files():
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    return f"uiofmu_rt_{digest.hexdigest()[:12]}"


def model_identifier(name: str, role: str) -> str:
    """The FMU's model identifier (``two_room_building_observer``): ASCII letters, digits and
    underscores only, at most :data:`uiofmu.runtime.text.MAX_IDENTIFIER` characters."""
    return identifier(name, role)


def _build_python(spec: dict, ident: str, description: str, output: Path, extra_files=()) -> Path:
    from pythonfmu.builder import FmuBuilder

    here = Path(__file__).parent
    output = check_output_file(output, "FMU", ".fmu")
    module = f"{ident}_slave"
    package = runtime_package()
    with tempfile.TemporaryDirectory(prefix="uiofmu_build_") as tmp:
        src = Path(tmp) / "src"
        src.mkdir()
        pkg = src / package
        pkg.mkdir()
        for path in runtime_files():                  # its __init__ imports every module at once
            shutil.copy2(path, pkg / path.name)
        (src / "model.json").write_text(json.dumps(spec), encoding="utf-8")
        text = fill_template((here / "templates" / "pythonfmu_slave.py.tmpl").read_text(encoding="utf-8"),
                             {"runtime": package, "class_name": ident},
                             {"description": py_string(description)})
        script = src / f"{module}.py"
        script.write_text(text, encoding="utf-8")
        try:
            built = FmuBuilder.build_FMU(script, dest=Path(tmp) / "out" / f"{ident}.fmu",
                                         project_files=[pkg, src / "model.json", *map(Path, extra_files)],
                                         canGetAndSetFMUstate=True, canSerializeFMUstate=True,
                                         canHandleVariableCommunicationStepSize=step_rule(spec).variable)
        finally:
            for key in [k for k in sys.modules if k == module or k.split(".")[0] == package]:
                sys.modules.pop(key)
            while str(src) in sys.path:
                sys.path.remove(str(src))
        if pythonfmu_guard.available():       # a native guard in front of pythonfmu's binary (see its module)
            pythonfmu_guard.guard_fmu(built)
        with atomic_output(output, "FMU") as part:
            shutil.copyfile(built, part)
    return output


def default_backend(model=None) -> str:
    """``c`` where a C compiler is found and the C backend has a kernel for ``model``, else ``python``.

    Parameters
    ----------
    model : Card or plant, optional
        What is to be packed (:func:`uiofmu.fmu.c_backend.c_refusal`); without it, only the compiler decides.

    Returns
    -------
    str
    """
    return choose_backend(model)[0]


def choose_backend(model=None, requested: str | None = None) -> tuple[str, str | None]:
    """The backend that packs ``model``, and why the default is not ``c`` when a compiler is there.

    Parameters
    ----------
    model : Card or plant, optional
    requested : {"c", "python"}, optional
        The ``--backend`` given: it is returned as it is (``c`` for a model without a C kernel is
        refused later, by the C backend, with its reason).

    Returns
    -------
    (str, str or None)
        The backend, and a one-line note when the default picked ``python`` because the C backend
        has no kernel for ``model`` (None otherwise).
    """
    from .c_backend import c_compiler, c_refusal

    if requested:
        return requested, None
    reason = c_refusal(model) if model is not None else None
    if reason:
        return "python", f"{reason}: building with the python backend (pythonfmu) instead"
    return ("c" if c_compiler() else "python"), None


def build_observer(card: Card, output, backend: str | None = None) -> Path:
    """Pack the observer of a design card as an FMU.

    Parameters
    ----------
    card : Card
        A verified design card.
    output : str or Path
        The ``.fmu`` file to write.
    backend : {"c", "python"}, optional
        ``c``: a standalone native binary plus its sources (the default where a C compiler
        is found and the C backend has the card's kernel: not ``delayed``); ``python``: pythonfmu
        (the host needs Python with numpy).

    Returns
    -------
    Path
    """
    backend = backend or default_backend(card)
    if backend not in BACKENDS:
        raise FmuError(f"--backend: expected one of {', '.join(BACKENDS)}, found {backend!r}")
    ident = model_identifier(card.name, "observer")
    if backend == "c":
        from .c_backend import build_c_observer

        return build_c_observer(card, output, ident)
    desc = f"{card.family} unknown-input observer of {card.name} (uiofmu {__version__})"
    return _build_python({"kind": "observer", "card": card.data, "experiment": observer_experiment(card)},
                         ident, desc, output)


def plant_kind(plant) -> str:
    """What a plant is, for FMU descriptions: ``linear plant``, ``switched linear plant (2 modes, rule
    threshold)`` or ``LPV plant (1 scheduling component, theta from the state)``: its kind's
    :attr:`~uiofmu.plant_kinds.PlantKind.describe`."""
    return kind_of(plant).describe(plant)


def build_plant(plant: Plant, name: str, output, step: float | None = None, backend: str | None = None,
                experiment_steps: int | None = None, labels: dict | None = None) -> Path:
    """Pack a plant as an FMU (a linear one exact between communication points).

    Parameters
    ----------
    plant : Plant, SwitchedPlant, LpvPlant or ParametricPlant
        A switched plant (:class:`uiofmu.switched_plant.SwitchedPlant`) adds the Integer ``mode``
        of its switching rule (:mod:`uiofmu.runtime.switching`); a plant with unknown parameters
        (:class:`uiofmu.parametric_plant.ParametricPlant`) has the parameter ``theta`` and the output
        ``ydot`` and is integrated with RK4 substeps (:mod:`uiofmu.runtime.parametric_plant`; pythonfmu only).
    name : str
        Model name (the FMU's model identifier is ``NAME_plant``).
    output : str or Path
        The ``.fmu`` file to write.
    step : float, optional
        The step of its ``<DefaultExperiment>`` (default: a discrete plant's ``dt``; a
        continuous plant without it has none).
    backend : {"c", "python"}, optional
        ``c``: a standalone native binary plus its sources (``c/kernel_plant.c``; the default
        where a C compiler is found, except for a plant with unknown parameters, which has no C
        kernel); ``python``: pythonfmu (the host needs Python with numpy).
    experiment_steps : int, optional
        The length of that experiment in steps (a problem's ``[experiment] steps``; default
        :data:`uiofmu.runtime.ports.PLANT_EXPERIMENT_STEPS`).
    labels : dict, optional
        Names and units of its states, inputs and outputs (a problem's ``labels``,
        :mod:`uiofmu.runtime.labels`): the descriptions and units of its variables.

    Returns
    -------
    Path
    """
    backend = backend or default_backend(plant)
    if backend not in BACKENDS:
        raise FmuError(f"--backend: expected one of {', '.join(BACKENDS)}, found {backend!r}")
    ident = model_identifier(name, "plant")
    step = plant.dt if step is None else step
    experiment = plant_experiment(step, experiment_steps) if step else None
    desc = f"{plant.time} {plant_kind(plant)} {name} (uiofmu {__version__}"
    if backend == "c":
        from .c_backend import build_c_plant

        return build_c_plant(plant, output, ident, experiment, desc + ", C backend)", labels=labels)
    desc += ")"
    return _build_python(plant_spec(plant.to_data(), experiment, labels), ident, desc, output)
