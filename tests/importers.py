"""Third-party FMI importers driving our FMUs: ecospy (a native co-simulation engine) and fmpy.

The runners live in the package, :mod:`uiofmu.cosim.importers` (``make fmus`` runs them too), and are
re-exported here: :func:`run_ecospy` (the loop of a plant and an observer in ecospy, a native Jacobi
engine; its module docstring says in which order ecospy steps, sets and reads), :func:`run_fmpy_default`
(fmpy's ``simulate_fmu`` at the default experiment), :func:`ports`, :func:`integer_variables` and
:func:`preload_libpython`. Added here for the tests: :func:`import_ecospy` (a failed test with a precise
message when ecospy's native library does not load), :func:`default_step`, :class:`TableInputs` and
:func:`ecospy_equals_master`.

For the tests that drive one FMU through fmpy (:class:`uiofmu.cosim.fmi.Fmu`): :func:`call_error` (the
error a refused call raises) and :func:`check_state_round_trip` (fmi2GetFMUstate, restore, serialise);
:func:`debug_logging_status` (the status of fmi2SetDebugLogging, fmi2Warning included); :class:`Slave` (one
instance through fmpy's ``FMU2Slave`` with its log lines in :data:`LINES`).
"""

from __future__ import annotations

from ctypes import byref

import numpy as np
import pytest
from fmpy import calloc, extract, free, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE, fmi2CallbackFunctions,
                       fmi2CallbackLoggerTYPE)

from uiofmu.cosim.importers import (EcospyRun, EcospyUnavailable, FmpyStalled, integer_variables,  # noqa: F401
                                    ports, preload_libpython, run_ecospy, run_fmpy_default)
from uiofmu.cosim.importers import import_ecospy as _import_ecospy


#: Every line any :class:`Slave` logged: (instance, status, category, message). fmpy's native
#: proxy, which formats the FMU's variadic message, holds one Python callback for the process; this
#: one stays alive with the module (the next uiofmu Fmu points the proxy back at its own).
LINES: list = []


def _log(environment, instance, status, category, message):
    LINES.append((instance.decode(), status, category.decode(), message.decode("utf-8", "replace")))


_LOGGER = fmi2CallbackLoggerTYPE(_log)


class Slave:
    """One FMU instance driven through fmpy's FMU2Slave, its log lines kept with their categories."""

    def __init__(self, path, name: str, logging_on: bool = True):
        from fmpy.logging import addLoggerProxy

        self.name = name
        self.md = read_model_description(str(path))
        self.refs = {v.name: v.valueReference for v in self.md.modelVariables}
        self.callbacks = fmi2CallbackFunctions()
        self.callbacks.logger = _LOGGER
        self.callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        self.callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        addLoggerProxy(byref(self.callbacks))
        self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=extract(str(path)),
                             modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=name)
        self.fmu.instantiate(callbacks=self.callbacks, loggingOn=logging_on)

    def vector(self, name):
        refs, i = [], 1
        while f"{name}[{i}]" in self.refs:
            refs.append(self.refs[f"{name}[{i}]"])
            i += 1
        return refs

    def lines(self):
        return [line[1:] for line in LINES if line[0] == self.name]

    def status(self, call, *args):
        """(fmi2 status, value) of a call that may raise (fmpy raises above fmi2Warning: a warning is 0)."""
        try:
            return 0, getattr(self.fmu, call)(*args)
        except FMICallException as exc:
            return exc.status, None

    def close(self):
        self.fmu.freeInstance()


def default_step(fmu) -> float:
    """The ``stepSize`` of the FMU's ``<DefaultExperiment>``.

    Parameters
    ----------
    fmu : str or Path

    Returns
    -------
    float

    Raises
    ------
    ValueError
        When the FMU declares no default step.
    """
    from fmpy import read_model_description

    de = read_model_description(str(fmu)).defaultExperiment
    if de is None or de.stepSize is None:
        raise ValueError(f"{fmu}: no <DefaultExperiment stepSize>")
    return float(de.stepSize)


def debug_logging_status(slave, on: bool, categories) -> int:
    """The status fmi2SetDebugLogging returns to an fmpy ``FMU2Slave`` (fmpy raises only above fmi2Warning).

    Parameters
    ----------
    slave : fmpy.fmi2.FMU2Slave
        An instantiated FMU.
    on : bool
        ``loggingOn``.
    categories : list of str

    Returns
    -------
    int
        The fmi2Status (0 fmi2OK, 1 fmi2Warning, 3 fmi2Error).
    """
    from fmpy.fmi2 import fmi2String

    names = (fmi2String * max(1, len(categories)))(*[c.encode("utf-8") for c in categories])
    return int(slave.dll.fmi2SetDebugLogging(slave.component, 1 if on else 0, len(categories), names))


def call_error(fn, *args):
    """The :class:`uiofmu.cosim.fmi.FmuCallError` that ``fn(*args)`` raises (the test fails if it returns).

    Parameters
    ----------
    fn : callable
        A call into an FMU through :class:`uiofmu.cosim.fmi.Fmu` (fmpy), ``fmu.step`` say.
    *args
        Its arguments.

    Returns
    -------
    FmuCallError
        The error, with the FMI status, the function and the FMU's log lines.
    """
    from uiofmu.cosim.fmi import FmuCallError

    with pytest.raises(FmuCallError) as info:
        fn(*args)
    return info.value


def check_state_round_trip(a, b, drive, first, rest, h: float):
    """Save an FMU's state after ``first``, and check that restoring it gives the same run of ``rest``.

    ``a`` and ``b`` (two instances of one FMU) are initialised at t = 0; ``a`` is driven over ``first``
    and its state saved and serialised; then ``a`` runs ``rest``, the state is restored in ``a`` and
    deserialised in ``b``: both run ``rest`` again identically, and both states serialise to the
    same bytes.

    Parameters
    ----------
    a, b : uiofmu.cosim.fmi.Fmu
        Two instances, not initialised.
    drive : callable
        ``drive(fmu, inputs, t0, h)``: sets each step's inputs, steps, and returns the outputs.
    first, rest : tuple of ndarray
        The inputs before and after the save, one row per step.
    h : float
        The communication step.

    Returns
    -------
    state : object
        ``a``'s saved state (restored in ``a`` at the end).
    blob : bytes
        Its serialisation.
    once : ndarray
        The outputs over ``rest``.
    """
    a.initialize(0.0)
    b.initialize(0.0)
    drive(a, first, 0.0, h)
    state = a.get_state()
    blob = a.serialize(state)
    t = len(first[0]) * h
    once = drive(a, rest, t, h)
    a.set_state(state)
    assert a.serialize(a.get_state()) == blob
    np.testing.assert_array_equal(drive(a, rest, t, h), once)
    b.set_state(b.deserialize(blob))
    assert b.serialize(b.get_state()) == blob
    np.testing.assert_array_equal(drive(b, rest, t, h), once)
    return state, blob, once


def import_ecospy():
    """ecospy, or a failed test with a precise message when its native library cannot load.

    Returns
    -------
    module
        ``ecospy``.
    """
    try:
        return _import_ecospy(required=True)
    except EcospyUnavailable as exc:
        pytest.fail(str(exc))


class TableInputs:
    """Inputs held per communication step from arrays (the master's and ecospy's input source).

    Parameters
    ----------
    h : float
        The communication step.
    table : dict of str to ndarray
        ``{name: values}``, one row per communication point t_k = k h.
    """

    def __init__(self, h: float, table: dict):
        self.h, self.table = h, table
        self.sizes = {name: values.shape[1] for name, values in table.items()}

    def values(self, t: float) -> dict:
        """The rows of the communication point nearest to ``t``."""
        k = min(int(round(t / self.h)), len(next(iter(self.table.values()))) - 1)
        return {name: values[k] for name, values in self.table.items()}


def ecospy_equals_master(plant_fmu, observer_fmu, step: float, steps: int, inputs, *, fed: dict | None = None,
                         estimate: str = "xhat", what: str = ""):
    """Run the plant and observer loop in ecospy and in our master, and assert that the two agree.

    Both run ``steps`` communication steps of ``step`` with the same ``inputs``. Asserted: ecospy made
    exactly the connections ``fed`` names, in order (``plant::y[1]`` to ``observer::y[1]``, ...); both
    clocks are the same ``steps + 1`` points; ``x`` and the estimate agree to 1e-12 (relative, and
    absolute against the largest value of ours); the estimate moved and is finite (a refused step,
    which ecospy logs and steps over, makes our master raise instead).

    Parameters
    ----------
    plant_fmu, observer_fmu : str or Path
        The FMUs (see :func:`run_ecospy`).
    step : float
        The communication step h.
    steps : int
        The number of steps K.
    inputs : object
        The input source of both masters (``values(t)``, ``sizes``: :class:`TableInputs`).
    fed : dict of str to int, optional
        The plant outputs connected to the observer and their sizes, in order; by default
        ``{"y": p}`` with p the plant outputs of our master's run.
    estimate : str, optional
        The observer output compared: ``"xhat"``, or a functional observer's ``"gx"``.
    what : str, optional
        Names the run in the messages of failed assertions.

    Returns
    -------
    ours : CosimResult
        Our master's run.
    theirs : EcospyRun
        ecospy's run.
    """
    from uiofmu.cosim.master import cosimulate

    import_ecospy()
    ours = cosimulate(plant_fmu, observer_fmu, np.full(steps, step), inputs, show_progress=False)
    theirs = run_ecospy(plant_fmu, observer_fmu, step, steps, inputs, estimate=estimate)
    fed = {"y": ours.y.shape[1]} if fed is None else fed
    assert theirs.connections == [(f"plant::{name}[{i}]", f"observer::{name}[{i}]") for name, size in fed.items()
                                  for i in range(1, size + 1)]
    assert theirs.times.shape == ours.times.shape == (steps + 1,)
    np.testing.assert_array_equal(theirs.times, ours.times, err_msg=what)
    mine = ours.xhat if estimate == "xhat" else ours.functional[estimate]
    for name, a, b in (("x", theirs.x, ours.x), (estimate, theirs.xhat, mine)):
        scale = max(float(np.max(np.abs(b))), 1e-300)
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * scale, err_msg=f"{what}: {name}" if what else name)
    assert np.ptp(theirs.xhat) > 0 and np.all(np.isfinite(theirs.xhat))
    return ours, theirs
