"""What ships inside every FMU: the card schema, the observer and plant runtimes, the FMU models.

numpy only (``mujoco_runtime`` also imports mujoco, on first use). The folder is copied whole into
each pythonfmu FMU, under a name derived from its content, and imports nothing from the rest of
uiofmu; ``tests/test_runtime_package.py`` holds it to that. Every module is imported here, at
once: FMUs of one runtime share the package in a process, and the folder it was first loaded
from may be gone by the time a later module would be needed.
"""

from . import (card, checks, delayed, errors, files, fmu_model, kernels, lpv, matrices, models,  # noqa: F401
               mujoco_runtime, observer, observer_models, parametric_plant, plant_kinds, plant_runtime, registry,
               schedules, state, step_rules, stepping, switching, text, tolerances, window)
from .observer import Runtime, RuntimeInputError  # noqa: F401
