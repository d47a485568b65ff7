"""The co-simulation master: FMUs loaded with fmpy, communication-step sequences, input tables,
metrics, reports and the validation of an FMU against the reference runtime.

``from uiofmu.cosim import cosimulate, step_sequence, write_outputs`` (:mod:`uiofmu.cosim.master`,
:mod:`uiofmu.cosim.steps`).
"""

from .master import cosimulate, write_outputs  # noqa: F401
from .steps import step_sequence  # noqa: F401
