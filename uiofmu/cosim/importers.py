"""Third-party FMI importers driving our FMUs: fmpy's ``simulate_fmu`` and ecospy (a native co-simulation engine).

:func:`run_fmpy_default` runs one FMU alone with fmpy and its ``<DefaultExperiment>``;
:func:`run_ecospy` runs the loop of a plant FMU and an observer FMU in ecospy. ``make fmus``
(:mod:`uiofmu.catalogue`) and the tests (``tests/importers.py``) use both.

ecospy (pip ``ecospy``, optional: :func:`import_ecospy`; its native library needs ``libtbb.so.12``, which
the PyPI wheel ``tbb`` ships and :func:`import_ecospy` loads first, so no system package is needed) runs
a fixed communication step with a Jacobi scheme. Per step, from its sources
(``src/ecos/simulation.cpp``, ``src/ecos/algorithm/fixed_step_algorithm.cpp``): the pre-step listeners
run; every instance applies its pending sets, ``fmi2DoStep(t_k, h)`` and reads its outputs (plant and
observer in parallel threads); then every connection copies its source's new value to its sink; then
every instance applies the sets and reads its outputs again; then the post-step listeners run. So at
t_{k+1} the observer's ``xhat`` is read after the plant's ``y(t_{k+1})`` has been set on it, and the
observer steps from t_k with ``y(t_k)``: the order of our own master (:func:`uiofmu.cosim.master.cosimulate`).

The known and unknown inputs come from a pre-step listener: at each t_k it sets ``values(t_k)`` on
the plant's inputs and on the observer's inputs that no plant output feeds; ecospy applies them just
before ``fmi2DoStep(t_k, h)``. Our master sets them before it reads ``xhat(t_k)``; no observer output
depends on ``u`` (the model structures say ``xhat`` depends on ``y`` only), so the two agree.
One exception: a plant output that depends on ``u`` and feeds the observer (the ``ydot`` of a plant with
unknown parameters, seed 001) reaches the observer as ecospy read it after the plant's step, with the
previous ``u``; our master sets the new ``u`` first. The loops agree exactly only for a constant ``u``.

ecospy never reports a refused step to its caller: a doStep that returns fmi2Discard or fmi2Error is
logged and time advances anyway. Compare the result with a reference to notice one.
"""

from __future__ import annotations

import ctypes
import math
import re
import sys
import sysconfig
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

_NAME = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)\[([1-9][0-9]*)\]")
#: What :func:`import_ecospy` says when ecospy's native library does not load.
ECOSPY_HINT = "install the wheel tbb, which ships libtbb.so.12: pip install tbb (it is in the test extra)"


def _description(fmu):
    """fmpy's model description of an FMU, or ``fmu`` itself when it is one already."""
    if hasattr(fmu, "modelVariables"):
        return fmu
    from fmpy import read_model_description

    return read_model_description(str(fmu))


def ports(fmu, causality: str) -> dict:
    """The vector ports of an FMU: ``{"y": ["y[1]", ...], ...}`` for one causality.

    Parameters
    ----------
    fmu : str or Path or fmpy.model_description.ModelDescription
        The FMU, or its model description.
    causality : str
        ``"input"``, ``"output"`` or ``"parameter"``.

    Returns
    -------
    dict of str to list of str
        Variable names ``name[i]`` grouped by ``name``, in order of ``i``.
    """
    groups: dict[str, dict[int, str]] = {}
    for v in _description(fmu).modelVariables:
        m = _NAME.fullmatch(v.name)
        if v.causality == causality and m:
            groups.setdefault(m.group(1), {})[int(m.group(2))] = v.name
    return {k: [g[i] for i in sorted(g)] for k, g in groups.items()}


def integer_variables(fmu) -> set:
    """The names of the FMU's Integer variables (``mode[1]``, ``seed[1]``, ...).

    Parameters
    ----------
    fmu : str or Path or fmpy.model_description.ModelDescription
        The FMU, or its model description.

    Returns
    -------
    set of str
    """
    return {v.name for v in _description(fmu).modelVariables if v.type == "Integer"}


class FmpyStalled(RuntimeError):
    """fmpy.simulate_fmu repeated a refused step without advancing time."""


def run_fmpy_default(fmu, *, steps: int | None = None, max_stalls: int = 20, timeout: float = 600.0):
    """Run an FMU alone with ``fmpy.simulate_fmu`` and its ``<DefaultExperiment>``, to its stop time.

    fmpy takes the default experiment's ``stepSize`` as its output interval, doubled while
    (stopTime - startTime) / interval > 1000. After fmi2Discard it asks
    ``fmi2GetBooleanStatus(fmi2Terminated)``: on true it stops (returning the result so far), on
    false it repeats the same step, for ever if the FMU refuses that step each time (uiofmu's FMUs
    answer true after a refused step; a third party's may not). This run stops such a loop and says
    so, and checks that the run reached its stop time with finite outputs.

    Parameters
    ----------
    fmu : str or Path
        The FMU.
    steps : int, optional
        Stop after this many steps of ``stepSize`` instead of at ``stopTime``.
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
    RuntimeError
        When the run stopped before the stop time, or an output is not finite.
    fmpy.fmi2.FMICallException
        fmpy's, when a call returns fmi2Error or fmi2Fatal (or fmi2Discard outside doStep).
    """
    import fmpy

    state = {"time": None, "stalls": 0}

    def step_finished(t, recorder) -> bool:
        state["stalls"] = state["stalls"] + 1 if t == state["time"] else 0
        state["time"] = t
        return state["stalls"] < max_stalls

    de = fmpy.read_model_description(str(fmu)).defaultExperiment
    stop = None if steps is None else steps * float(de.stepSize)
    result = fmpy.simulate_fmu(str(fmu), stop_time=stop, step_finished=step_finished, timeout=timeout)
    if state["stalls"] >= max_stalls:
        raise FmpyStalled(f"{Path(fmu).name}: fmpy repeated the step at t = {state['time']!r} {max_stalls} times "
                          f"(the FMU refused it with fmi2Discard and answered fmi2Terminated = false, so fmpy "
                          f"retried the same step)")
    stop = float(de.stopTime) if stop is None else stop
    if len(result) < 2 or not math.isclose(float(result["time"][-1]), stop, rel_tol=1e-9):
        raise RuntimeError(f"fmpy stopped at t = {float(result['time'][-1])!r}, before the stop time {stop!r}")
    for name in result.dtype.names:
        if not np.all(np.isfinite(result[name])):
            raise RuntimeError(f"fmpy: {name} is not finite")
    return result


class EcospyUnavailable(ImportError):
    """ecospy is installed but its native library does not load."""


def import_ecospy(*, required: bool = False):
    """ecospy, or None when it is not importable (not installed, or its native library does not load).

    Parameters
    ----------
    required : bool, optional
        Raise instead of returning None: ImportError when ecospy is not installed,
        :class:`EcospyUnavailable` (saying what to install) when its native library does not load.

    Returns
    -------
    module or None
        ``ecospy``.

    Raises
    ------
    ImportError
        With ``required``, as above.
    """
    preload_tbb()
    try:
        import ecospy
    except ImportError:
        if required:
            raise
        return None
    except OSError as exc:  # libecosc.so: libtbb.so.12: cannot open shared object file
        if required:
            raise EcospyUnavailable(f"ecospy's native library does not load ({exc}); {ECOSPY_HINT}") from exc
        return None
    return ecospy


def preload_tbb() -> str | None:
    """Load ``libtbb.so.12`` from the PyPI wheel ``tbb`` with ``RTLD_GLOBAL``, for ecospy's native library.

    ``libecosc.so`` needs ``libtbb.so.12`` and finds it by the dynamic loader's search path only; the
    wheel installs it into ``<prefix>/lib``, which is not on that path. A library loaded globally
    first satisfies the dependency by its soname, so ecospy loads without the system's ``libtbb12``.

    Returns
    -------
    str or None
        The path loaded, or None when the wheel is not installed (a system copy may still serve).
    """
    from importlib import metadata

    try:
        files = metadata.files("tbb") or []
    except metadata.PackageNotFoundError:
        return None
    for f in files:
        if f.name == "libtbb.so.12":
            path = Path(f.locate()).resolve()
            if path.is_file():
                ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)
                return str(path)
    return None


def preload_libpython() -> str | None:
    """Make sure the interpreter's symbols are global, for pythonfmu FMUs loaded by ecospy.

    pythonfmu binaries leave the Py* symbols undefined and do not link libpython; ecospy's
    native library loads them in this process, where the symbols come from the interpreter. A
    static ``python3`` exports them, and so does a ``python3`` linked with ``libpython3.X.so``
    (a library the executable needs is global). Only an interpreter that was itself loaded with
    ``RTLD_LOCAL`` (embedded in another program) hides them: reopening ``libpython3.X.so`` with
    ``RTLD_GLOBAL`` makes them visible there and changes nothing elsewhere.

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


def run_ecospy(plant_fmu, observer_fmu, step: float, steps: int, inputs=None, *, estimate: str = "xhat") -> EcospyRun:
    """Co-simulate a plant FMU and an observer FMU in ecospy at a fixed communication step (Jacobi, as our master).

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
    steps : int
        The number of communication steps K.
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
    ValueError
        When the plant has no outputs ``x[i]`` or the observer none named ``estimate``.
    Exception
        ecospy's own, with its last error message (an FMU that does not load, a variable
        that does not exist).
    """
    from ecospy import EcosSimulation, EcosSimulationStructure

    preload_libpython()
    K = int(steps)
    wiring = _wiring(plant_fmu, observer_fmu, estimate)
    seconds = {}
    t0 = time.perf_counter()
    with EcosSimulationStructure() as ss:
        ss.add_model("plant", Path(plant_fmu).resolve())
        ss.add_model("observer", Path(observer_fmu).resolve())
        for source, sink in wiring.connections:
            if source.split("::", 1)[1] in wiring.integers["plant"]:
                ss.make_int_connection(source, sink)
            else:
                ss.make_real_connection(source, sink)
        with EcosSimulation(structure=ss, step_size=float(step)) as sim:
            seconds["build"] = time.perf_counter() - t0
            recorder = _Recorder(sim, wiring, inputs, K)
            seconds.update(recorder.run(K))
            sim.terminate()
    return EcospyRun(recorder.T, recorder.X, recorder.XH, wiring.connections, seconds)


@dataclass
class _Wiring:
    """How :func:`run_ecospy` connects the plant and observer FMUs and what it sets and records.

    Attributes
    ----------
    integers : dict
        ``{"plant": names, "observer": names}`` of the Integer variables.
    sinks : list of (str, str, list)
        ``(FMU, input, its variables)`` that the inputs set: every plant input, and the observer's
        that no plant output feeds.
    x_ids, xhat_ids : list of str
        The variables recorded as ``x`` and ``xhat``.
    connections : list of (str, str)
        Plant outputs to the observer inputs of the same name, element by element.
    """

    integers: dict
    sinks: list
    x_ids: list
    xhat_ids: list
    connections: list


def _wiring(plant_fmu, observer_fmu, estimate: str) -> _Wiring:
    """The :class:`_Wiring` of two FMUs, read from their model descriptions."""
    md = {"plant": _description(plant_fmu), "observer": _description(observer_fmu)}
    plant_out, plant_in = ports(md["plant"], "output"), ports(md["plant"], "input")
    obs_out, obs_in = ports(md["observer"], "output"), ports(md["observer"], "input")
    if "x" not in plant_out or estimate not in obs_out:
        raise ValueError(f"the plant needs outputs x[i] and the observer outputs {estimate}[i]")
    integers = {who: integer_variables(m) for who, m in md.items()}
    fed = [name for name in obs_in if name in plant_out]
    sinks = [("plant", name, plant_in[name]) for name in plant_in]
    sinks += [("observer", name, obs_in[name]) for name in obs_in if name not in fed]
    x_ids = [f"plant::{v}" for v in plant_out["x"]]
    xhat_ids = [f"observer::{v}" for v in obs_out[estimate]]
    connections = [(f"plant::{a}", f"observer::{b}") for name in fed for a, b in zip(plant_out[name], obs_in[name])]
    return _Wiring(integers, sinks, x_ids, xhat_ids, connections)


class _Recorder:
    """The inputs set before each ecospy step and ``x`` and the estimate recorded after it (rows of ``T``,
    ``X``, ``XH``); an exception raised in ecospy's callbacks is kept in ``errors`` and raised after the
    step (exceptions must not cross the native frames of ecospy's callbacks)."""

    def __init__(self, sim, wiring: _Wiring, inputs, K: int):
        self.sim, self.wiring, self.inputs = sim, wiring, inputs
        self.T, self.X = np.zeros(K + 1), np.zeros((K + 1, len(wiring.x_ids)))
        self.XH = np.zeros((K + 1, len(wiring.xhat_ids)))
        self.errors: list[BaseException] = []

    def set_inputs(self, t: float) -> None:
        """Set the inputs' values at ``t`` on the sinks (nothing without inputs)."""
        if self.inputs is None:
            return
        values = self.inputs.values(t)
        for who, name, names in self.wiring.sinks:
            for v, value in zip(names, np.ravel(values[name])):
                if v in self.wiring.integers[who]:
                    self.sim.set_integer(f"{who}::{v}", int(round(float(value))))
                else:
                    self.sim.set_real(f"{who}::{v}", float(value))

    def record(self, k: int) -> None:
        """Record row ``k``: ecospy's time, ``x`` and the estimate."""
        self.T[k] = self.sim.get_time()
        self.X[k] = [self.sim.get_real(i) for i in self.wiring.x_ids]
        self.XH[k] = [self.sim.get_real(i) for i in self.wiring.xhat_ids]

    def listener(self):
        """An ecospy ``SimulationListener`` that sets the inputs before each step and records after it."""
        from ecospy import SimulationListener

        recorder = self

        class Listener(SimulationListener):
            # Exceptions must not cross the native frames of ecospy's callbacks: keep them.
            def pre(self, info):
                try:
                    recorder.set_inputs(info.time)
                except BaseException as exc:  # noqa: BLE001 - re-raised after the step
                    recorder.errors.append(exc)

            def post(self, info):
                try:
                    recorder.record(info.iterations)
                except BaseException as exc:  # noqa: BLE001
                    recorder.errors.append(exc)

        return Listener()

    def run(self, K: int) -> dict:
        """Initialise the simulation at t = 0 and take ``K`` steps; the wall time of ``init`` and ``steps``."""
        seconds = {}
        self.set_inputs(0.0)
        t0 = time.perf_counter()
        if not self.sim.init(0.0):
            from ecospy import EcosLib

            raise RuntimeError(f"ecospy init failed: {EcosLib.get_last_error()}")
        self.record(0)
        seconds["init"] = time.perf_counter() - t0
        self.sim.add_listener("uiofmu", self.listener())
        t0 = time.perf_counter()
        self.sim.step(K)
        seconds["steps"] = time.perf_counter() - t0
        if self.errors:
            raise self.errors[0]
        return seconds

__all__ = ["EcospyRun", "EcospyUnavailable", "FmpyStalled", "import_ecospy", "integer_variables", "ports",
           "preload_libpython", "preload_tbb", "run_ecospy", "run_fmpy_default"]
