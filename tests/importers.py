"""Third-party FMI importers driving our FMUs: ecospy (a native co-simulation engine) and fmpy.

ecospy (pip ``ecospy``; its native library needs the Debian package ``libtbb12``) runs a fixed
communication step with a Jacobi scheme. Per step, from its sources (``src/ecos/simulation.cpp``,
``src/ecos/algorithm/fixed_step_algorithm.cpp``): the pre-step listeners run; every instance applies
its pending sets, ``fmi2DoStep(t_k, h)`` and reads its outputs (plant and observer in parallel threads);
then every connection copies its source's new value to its sink; then every instance applies the
sets and reads its outputs again; then the post-step listeners run. So at t_{k+1} the observer's
``xhat`` is read after the plant's ``y(t_{k+1})`` has been set on it, and the observer steps from t_k
with ``y(t_k)``: the order of our own master (:func:`uiofmu.cosim.master.cosimulate`).

The known and unknown inputs come from a pre-step listener: at each t_k it sets ``values(t_k)`` on
the plant's inputs and on the observer's inputs that no plant output feeds; ecospy applies them just
before ``fmi2DoStep(t_k, h)``. Our master sets them before it reads ``xhat(t_k)``; no observer output
depends on ``u`` (the model structures say ``xhat`` depends on ``y`` only), so the two agree.
One exception: a plant output that depends on ``u`` and feeds the observer (the ``ydot`` of a plant with
unknown parameters, seed 001) reaches the observer as ecospy read it after the plant's step, with the
previous ``u``; our master sets the new ``u`` first. The loops agree exactly only for a constant ``u``.

ecospy never reports a refused step to its caller: a doStep that returns fmi2Discard or fmi2Error is
logged and time advances anyway. Compare the result with a reference to notice one.

For the tests that drive one FMU through fmpy (:class:`uiofmu.cosim.fmi.Fmu`): :func:`call_error` (the
error a refused call raises) and :func:`check_state_round_trip` (fmi2GetFMUstate, restore, serialise).
"""

from __future__ import annotations

import ctypes
import re
import sys
import sysconfig
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

_NAME = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)\[([1-9][0-9]*)\]")


def ports(fmu, causality: str) -> dict:
    """The vector ports of an FMU: ``{"y": ["y[1]", ...], ...}`` for one causality.

    Parameters
    ----------
    fmu : str or Path
        The FMU.
    causality : str
        ``"input"``, ``"output"`` or ``"parameter"``.

    Returns
    -------
    dict of str to list of str
        Variable names ``name[i]`` grouped by ``name``, in order of ``i``.
    """
    from fmpy import read_model_description

    groups: dict[str, dict[int, str]] = {}
    for v in read_model_description(str(fmu)).modelVariables:
        m = _NAME.fullmatch(v.name)
        if v.causality == causality and m:
            groups.setdefault(m.group(1), {})[int(m.group(2))] = v.name
    return {k: [g[i] for i in sorted(g)] for k, g in groups.items()}


def integer_variables(fmu) -> set:
    """The names of the FMU's Integer variables (``mode[1]``, ``seed[1]``, ...).

    Parameters
    ----------
    fmu : str or Path

    Returns
    -------
    set of str
    """
    from fmpy import read_model_description

    return {v.name for v in read_model_description(str(fmu)).modelVariables if v.type == "Integer"}


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


def preload_libpython() -> str | None:
    """Make sure the interpreter's symbols are global, for pythonfmu FMUs loaded by ecospy.

    pythonfmu binaries leave the Py* symbols undefined and do not link libpython; ecospy's
    native library loads them in this process, where the symbols come from the interpreter. A
    static ``python3`` exports them, and so does a ``python3`` linked with ``libpython3.X.so``
    (this machine's: a library the executable needs is global). Only an interpreter that was
    itself loaded with ``RTLD_LOCAL`` (embedded in another program) hides them: reopening
    ``libpython3.X.so`` with ``RTLD_GLOBAL`` makes them visible there and changes nothing elsewhere.

    Returns
    -------
    str or None
        The library reopened, or None for a static interpreter.
    """
    if sysconfig.get_config_var("Py_ENABLE_SHARED"):
        name = sysconfig.get_config_var("LDLIBRARY")
        for folder in (sysconfig.get_config_var("LIBDIR"), str(Path(sys.executable).parent.parent / "lib")):
            path = Path(folder or "") / name
            if path.is_file():
                ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)
                return str(path)
    return None


@dataclass
class EcospyRun:
    """One ecospy co-simulation, row k at the communication point t_k.

    Attributes
    ----------
    times : ndarray, shape (K + 1,)
        ecospy's clock (t_{k+1} = t_k + h).
    x : ndarray, shape (K + 1, n)
        The plant's ``x[i]``.
    xhat : ndarray, shape (K + 1, n)
        The observer's ``xhat[i]`` (or the output named by ``estimate``: ``gx[i]`` of a functional observer).
    connections : list of (str, str)
        The connections made, ``("plant::y[1]", "observer::y[1]")``, ...
    seconds : dict
        Wall time of ``build`` (loading both FMUs), ``init`` and ``steps``.
    """

    times: np.ndarray
    x: np.ndarray
    xhat: np.ndarray
    connections: list = field(default_factory=list)
    seconds: dict = field(default_factory=dict)


def run_ecospy(plant_fmu, observer_fmu, step: float, t_end: float, inputs=None, estimate: str = "xhat") -> EcospyRun:
    """Co-simulate a plant FMU and an observer FMU in ecospy at a fixed communication step.

    Every observer input named like a plant output (``y``; ``mode``, ``theta``, ``ydot`` where the
    plant has them) is connected element by element (``plant::y[i]`` to ``observer::y[i]``), by an
    Integer connection where the variables are Integer (``mode``).

    Parameters
    ----------
    plant_fmu, observer_fmu : str or Path
        FMI 2.0 Co-Simulation FMUs: C FMUs, or pythonfmu FMUs (they run in this interpreter,
        see :func:`preload_libpython`).
    step : float
        The communication step h.
    t_end : float
        The stop time: K = round(t_end / h) steps are taken.
    inputs : object, optional
        With ``values(t)`` returning ``{"u": array, "d": array, ...}`` (the interface of
        :class:`uiofmu.cosim.inputs.SignalInputs`): at each t_k these are set on the plant's
        inputs and on the observer's inputs that no plant output feeds, held over the step.
        By default nothing is set: every input keeps its start value (u = 0, d = 0).
    estimate : str, optional
        The observer output recorded as ``xhat`` (``"gx"`` for a functional observer).

    Returns
    -------
    EcospyRun

    Raises
    ------
    Exception
        ecospy's own, with its last error message (an FMU that does not load, a variable
        that does not exist).
    """
    from ecospy import EcosSimulation, EcosSimulationStructure, SimulationListener

    preload_libpython()
    K = int(round(t_end / step))
    plant_out, plant_in = ports(plant_fmu, "output"), ports(plant_fmu, "input")
    obs_out, obs_in = ports(observer_fmu, "output"), ports(observer_fmu, "input")
    if "x" not in plant_out or estimate not in obs_out:
        raise ValueError(f"the plant needs outputs x[i] and the observer outputs {estimate}[i]")
    integers = {"plant": integer_variables(plant_fmu), "observer": integer_variables(observer_fmu)}
    fed = [name for name in obs_in if name in plant_out]
    sinks = [("plant", name, plant_in[name]) for name in plant_in]
    sinks += [("observer", name, obs_in[name]) for name in obs_in if name not in fed]
    x_ids = [f"plant::{v}" for v in plant_out["x"]]
    xhat_ids = [f"observer::{v}" for v in obs_out[estimate]]
    connections = [(f"plant::{a}", f"observer::{b}") for name in fed for a, b in zip(plant_out[name], obs_in[name])]

    seconds = {}
    t0 = time.perf_counter()
    with EcosSimulationStructure() as ss:
        ss.add_model("plant", Path(plant_fmu).resolve())
        ss.add_model("observer", Path(observer_fmu).resolve())
        for source, sink in connections:
            if source.split("::", 1)[1] in integers["plant"]:
                ss.make_int_connection(source, sink)
            else:
                ss.make_real_connection(source, sink)
        with EcosSimulation(structure=ss, step_size=float(step)) as sim:
            seconds["build"] = time.perf_counter() - t0
            T, X, XH = np.zeros(K + 1), np.zeros((K + 1, len(x_ids))), np.zeros((K + 1, len(xhat_ids)))
            errors: list[BaseException] = []

            def set_inputs(t: float) -> None:
                if inputs is None:
                    return
                values = inputs.values(t)
                for who, name, names in sinks:
                    for v, value in zip(names, np.ravel(values[name])):
                        if v in integers[who]:
                            sim.set_integer(f"{who}::{v}", int(round(float(value))))
                        else:
                            sim.set_real(f"{who}::{v}", float(value))

            def record(k: int) -> None:
                T[k] = sim.get_time()
                X[k] = [sim.get_real(i) for i in x_ids]
                XH[k] = [sim.get_real(i) for i in xhat_ids]

            class Listener(SimulationListener):
                # Exceptions must not cross the native frames of ecospy's callbacks: keep them.
                def pre(self, info):
                    try:
                        set_inputs(info.time)
                    except BaseException as exc:  # noqa: BLE001 - re-raised after the step
                        errors.append(exc)

                def post(self, info):
                    try:
                        record(info.iterations)
                    except BaseException as exc:  # noqa: BLE001
                        errors.append(exc)

            set_inputs(0.0)
            t0 = time.perf_counter()
            if not sim.init(0.0):
                from ecospy import EcosLib

                raise RuntimeError(f"ecospy init failed: {EcosLib.get_last_error()}")
            record(0)
            seconds["init"] = time.perf_counter() - t0
            sim.add_listener("uiofmu", Listener())
            t0 = time.perf_counter()
            sim.step(K)
            seconds["steps"] = time.perf_counter() - t0
            if errors:
                raise errors[0]
            sim.terminate()
    return EcospyRun(T, X, XH, connections, seconds)


def import_ecospy():
    """ecospy, or a failed test with a precise message when its native library cannot load.

    Returns
    -------
    module
        ``ecospy``.
    """
    try:
        import ecospy
    except OSError as exc:  # libecosc.so: libtbb.so.12: cannot open shared object file
        pytest.fail(f"ecospy's native library does not load ({exc}); install libtbb12: apt-get install -y libtbb12")
    return ecospy


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
    theirs = run_ecospy(plant_fmu, observer_fmu, step, steps * step, inputs, estimate=estimate)
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


class FmpyStalled(RuntimeError):
    """fmpy.simulate_fmu repeated a refused step without advancing time."""


def run_fmpy_default(fmu, *, max_stalls: int = 20, timeout: float = 120.0):
    """Run an FMU alone with ``fmpy.simulate_fmu`` and its ``<DefaultExperiment>``.

    fmpy takes the default experiment's ``stepSize`` as its output interval, doubled while
    (stopTime - startTime) / interval > 1000. After fmi2Discard it asks
    ``fmi2GetBooleanStatus(fmi2Terminated)``: on true it stops (returning the result so far), on
    false it repeats the same step, for ever if the FMU refuses that step each time. This run
    stops such a loop and says so.

    Parameters
    ----------
    fmu : str or Path
    max_stalls : int, optional
        Consecutive steps without progress of time after which the run is stopped.
    timeout : float, optional
        fmpy's own limit on the wall time of the run, in seconds.

    Returns
    -------
    numpy structured array
        fmpy's result: ``time`` and every output, one row per output point.

    Raises
    ------
    FmpyStalled
        When time did not advance for ``max_stalls`` consecutive steps.
    fmpy.fmi2.FMICallException
        fmpy's, when a call returns fmi2Error or fmi2Fatal (or fmi2Discard outside doStep).
    """
    import fmpy

    state = {"time": None, "stalls": 0}

    def step_finished(t, recorder) -> bool:
        state["stalls"] = state["stalls"] + 1 if t == state["time"] else 0
        state["time"] = t
        return state["stalls"] < max_stalls

    result = fmpy.simulate_fmu(str(fmu), step_finished=step_finished, timeout=timeout)
    if state["stalls"] >= max_stalls:
        raise FmpyStalled(f"{Path(fmu).name}: fmpy repeated the step at t = {state['time']!r} {max_stalls} times "
                          f"(the FMU refused it with fmi2Discard and answered fmi2Terminated = false, so fmpy "
                          f"retried the same step)")
    return result
