"""Driving an FMU through fmpy: named vectors, captured log messages, typed errors.

Every FMI call goes through fmpy's ``FMU2Slave``; a call that returns fmi2Discard,
fmi2Error or fmi2Fatal raises :class:`FmuCallError` carrying the status and the log lines
the FMU wrote, so a master can say exactly what went wrong and where.

Log lines reach the right instance through one logger for the whole process: fmpy's native
proxy (which formats the FMU's variadic message) holds a single Python callback, so each
instance passes its own key as ``componentEnvironment`` and the logger files the line there.
"""

from __future__ import annotations

import itertools
import shutil
import tempfile
import weakref
import zipfile
import ctypes
from ctypes import byref
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..runtime.errors import FmuError
from ..runtime.files import MAX_INPUT_BYTES, parse_json

STATUS = ["ok", "warning", "discard", "error", "fatal", "pending"]


class FmuCallError(FmuError):
    """An FMI call that did not return fmi2OK or fmi2Warning.

    Attributes
    ----------
    status : int
        The FMI status (2 discard, 3 error, 4 fatal).
    messages : list of str
        The log lines the FMU wrote during the call.
    """

    def __init__(self, function: str, status: int, messages: list[str]):
        self.status = status
        self.function = function
        self.messages = messages
        label = STATUS[status] if 0 <= status < len(STATUS) else "illegal"
        detail = f": {messages[-1]}" if messages else ""
        super().__init__(f"{function} returned fmi2{label.capitalize()}{detail}")


def read_model_json(path) -> dict:
    """The uiofmu model (``resources/model.json``) packed in an FMU built by uiofmu.

    Parameters
    ----------
    path : str or Path
        A regular file; its ``resources/model.json`` is read only up to
        :data:`uiofmu.runtime.files.MAX_INPUT_BYTES` and nested at most :data:`uiofmu.runtime.files.MAX_DEPTH` deep.

    Returns
    -------
    dict
    """
    path = Path(path)
    if not path.is_file():
        raise FmuError(f"{path}: no such FMU" if not path.exists() else f"{path}: an FMU is a regular file")
    try:
        with zipfile.ZipFile(path) as z:
            info = z.getinfo("resources/model.json")
            if info.file_size > MAX_INPUT_BYTES:
                raise FmuError(f"{path}: resources/model.json has {info.file_size} bytes, more than {MAX_INPUT_BYTES}")
            text = z.read(info).decode("utf-8")
    except (KeyError, OSError, zipfile.BadZipFile, UnicodeDecodeError, RuntimeError, NotImplementedError):
        raise FmuError(f"{path}: not an FMU built by uiofmu (no readable resources/model.json)") from None
    spec = parse_json(text, f"{path}: resources/model.json", error=FmuError)
    if not isinstance(spec, dict):
        raise FmuError(f"{path}: resources/model.json is not a uiofmu model")
    return spec


#: fmpy's exception for a failed call (bound when the first FMU is loaded: fmpy is imported lazily).
_FMPY_ERROR: list = [Exception]

_INSTANCES: "weakref.WeakValueDictionary[int, Fmu]" = weakref.WeakValueDictionary()
_KEYS = itertools.count(1)


def _log(environment, instance, status, category, message) -> None:
    """File a log line with the instance whose key the FMU passed back as its environment."""
    fmu = _INSTANCES.get(environment or 0)
    if fmu is not None:
        fmu.messages.append(message.decode("utf-8", "replace") if message else "")


@lru_cache(maxsize=None)
def _logger():
    """The process's one logger callback, created on first use and kept for good (fmpy's
    proxy may call it as long as any FMU lives)."""
    from fmpy.fmi2 import fmi2CallbackLoggerTYPE

    return fmi2CallbackLoggerTYPE(_log)


def _release_python_state(dll) -> None:
    """Release a pythonfmu binary's interpreter state while the library is still loaded.

    pythonfmu 0.7.0 keeps it in a static ``shared_ptr`` and resets that pointer again in a
    library destructor. For the first copy of the library in a process (which the dynamic
    loader keeps until exit) the static is destroyed first, and the destructor then writes
    into the freed block: glibc aborts at exit ("corrupted double-linked list") when a later
    exit handler meets that heap chunk. Resetting the pointer here, through the library's own
    exported ``finalizePythonInterpreter``, leaves nothing for either to free; the host's
    Python is not touched (the state owns the interpreter only when the library started it).
    Other binaries do not export the function and are left alone.
    """
    try:
        finalize = dll.finalizePythonInterpreter
    except AttributeError:
        return
    finalize.argtypes, finalize.restype = [], None
    finalize()


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0][:300] if text else type(exc).__name__


def vector_sizes(variables, causality: str) -> dict:
    """The vectors ``name[1..k]`` among fmpy model variables of one causality (``"input"``,
    ``"output"``, ``"parameter"``), as ``{name: k}`` in the order of the model description."""
    out: dict = {}
    for v in variables:
        if v.causality == causality and v.name.endswith("]") and "[" in v.name:
            name = v.name[:v.name.index("[")]
            out[name] = out.get(name, 0) + 1
    return out


class Fmu:
    """One instance of a Co-Simulation FMU, driven by fmpy.

    Parameters
    ----------
    path : str or Path
        The ``.fmu`` file.
    instance_name : str
        Instance name (several instances of one FMU may live in one process).

    Examples
    --------
    >>> with Fmu("obs.fmu", "observer") as obs:          # doctest: +SKIP
    ...     obs.initialize(0.0)
    ...     obs.set("y", [1.0]); xhat = obs.get("xhat"); obs.step(0.0, 0.1)
    """

    def __init__(self, path, instance_name: str):
        from fmpy import calloc, extract, free, read_model_description
        from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                               fmi2CallbackFunctions)
        from fmpy.fmi1 import FMICallException
        from fmpy.logging import addLoggerProxy

        _FMPY_ERROR[0] = FMICallException

        self.path = Path(path)
        if not self.path.is_file():
            raise FmuError(f"{self.path}: no such FMU")
        try:
            self.description = read_model_description(str(self.path))
        except Exception as exc:  # fmpy raises plain exceptions for broken archives
            raise FmuError(f"{self.path}: not a readable FMU ({exc})") from None
        if self.description.coSimulation is None:
            raise FmuError(f"{self.path}: not a Co-Simulation FMU")
        self.messages: list[str] = []
        self._refs = {v.name: v.valueReference for v in self.description.modelVariables}
        self._types = {v.name: v.type for v in self.description.modelVariables}
        self._vectors: dict = {}
        self._unzipdir = tempfile.mkdtemp(prefix="uiofmu_fmu_")
        try:
            extract(str(self.path), unzipdir=self._unzipdir)
        except Exception as exc:  # noqa: BLE001 - zipfile and OS errors of a broken archive
            shutil.rmtree(self._unzipdir, ignore_errors=True)
            raise FmuError(f"{self.path}: cannot extract the FMU ({_first_line(exc)})") from None

        self._key = next(_KEYS)
        _INSTANCES[self._key] = self
        self._callbacks = fmi2CallbackFunctions()
        self._callbacks.logger = _logger()
        self._callbacks.componentEnvironment = self._key
        self._callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        self._callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        addLoggerProxy(byref(self._callbacks))
        try:
            self.slave = FMU2Slave(guid=self.description.guid, unzipDirectory=self._unzipdir,
                                   modelIdentifier=self.description.coSimulation.modelIdentifier,
                                   instanceName=instance_name)
        except Exception as exc:  # noqa: BLE001 - fmpy raises plain exceptions for a missing binary
            shutil.rmtree(self._unzipdir, ignore_errors=True)
            _INSTANCES.pop(self._key, None)
            raise FmuError(f"{self.path}: its binary for this platform cannot be loaded ({_first_line(exc)})") from None
        try:
            self.slave.instantiate(callbacks=self._callbacks, loggingOn=True)
        except Exception:  # noqa: BLE001 - fmpy raises a bare Exception here
            self._unload()
            why = self.messages[-1] if self.messages else "no message"
            raise FmuError(f"{self.path}: fmi2Instantiate failed ({why})") from None
        self.slave.setDebugLogging(True, [])
        self._alive = True

    # -- calls -------------------------------------------------------------------------
    def _call(self, function: str, *args):
        start = len(self.messages)
        try:
            return getattr(self.slave, function)(*args)
        except _FMPY_ERROR[0] as exc:
            raise FmuCallError(exc.function, exc.status, self.messages[start:]) from None

    def function(self, name: str):
        """fmpy's ctypes function of the binary's ``fmi2...`` function ``name`` (its argument types
        set by fmpy; it returns the FMI status), for a master's loop on preallocated buffers."""
        function = getattr(self.slave.dll, name)
        if function.argtypes is None:        # fmpy sets them all when it loads the binary
            raise FmuError(f"{self.path}: fmpy did not load {name}")
        return function

    @property
    def component(self):
        """The instance's fmi2Component (an address)."""
        return self.slave.component

    def value_references(self, names) -> "ctypes.Array":
        """The value references of the vectors ``names``, concatenated, as an fmi2ValueReference array."""
        refs = [r for name in names for r in self.refs(name)]
        return (ctypes.c_uint * len(refs))(*refs)

    def refs(self, name: str) -> list[int]:
        """Value references of the vector ``name[1..k]`` (empty when the FMU has none)."""
        if name not in self._vectors:
            refs = []
            while f"{name}[{len(refs) + 1}]" in self._refs:
                refs.append(self._refs[f"{name}[{len(refs) + 1}]"])
            self._vectors[name] = refs
        return self._vectors[name]

    def ports(self, causality: str) -> dict:
        """The vectors ``name[1..k]`` of one causality, as ``{name: k}`` (:func:`vector_sizes`)."""
        return vector_sizes(self.description.modelVariables, causality)

    @property
    def resources(self) -> str:
        """The extracted ``resources`` folder."""
        return str(Path(self._unzipdir) / "resources")

    def has(self, name: str) -> bool:
        """Whether the FMU has the vector ``name``."""
        return bool(self.refs(name))

    def initialize(self, start_time: float = 0.0, parameters: dict | None = None) -> None:
        """setupExperiment, parameters, enter and exit initialisation mode."""
        self._call("setupExperiment", None, start_time)
        self._call("enterInitializationMode")
        for name, values in (parameters or {}).items():
            self.set(name, values)
        self._call("exitInitializationMode")

    def integer(self, name: str) -> bool:
        """Whether the vector ``name`` is of type Integer (a mode)."""
        return self._types.get(f"{name}[1]") == "Integer"

    def set(self, name: str, values) -> None:
        """Set the vector ``name`` (Real, or Integer: values are rounded to the nearest integer)."""
        refs = self.refs(name)
        if refs and self.integer(name):
            self._call("setInteger", refs, [int(round(float(v))) for v in np.ravel(values)])
        elif refs:
            self._call("setReal", refs, [float(v) for v in np.ravel(values)])

    def get(self, name: str) -> np.ndarray:
        """Read the vector ``name`` (as floats, whatever its type)."""
        refs = self.refs(name)
        if not refs:
            return np.zeros(0)
        return np.array(self._call("getInteger" if self.integer(name) else "getReal", refs), dtype=float)

    def step(self, t: float, h: float) -> None:
        """fmi2DoStep(t, h); raises :class:`FmuCallError` on discard, error or fatal."""
        self._call("doStep", t, h)

    def get_state(self):
        """fmi2GetFMUstate."""
        return self._call("getFMUstate")

    def set_state(self, state) -> None:
        """fmi2SetFMUstate."""
        self._call("setFMUstate", state)

    def serialize(self, state) -> bytes:
        """fmi2SerializeFMUstate."""
        return bytes(self._call("serializeFMUstate", state))

    def deserialize(self, data: bytes):
        """fmi2DeSerializeFMUstate."""
        return self._call("deSerializeFMUstate", data)

    def reset(self) -> None:
        """fmi2Reset (back to the instantiated state)."""
        self._call("reset")

    def close(self) -> None:
        """Terminate, free the instance and remove the extracted files."""
        if not self._alive:
            return
        self._alive = False
        try:
            self.slave.terminate()
        except Exception:  # noqa: BLE001 - an instance in error state may refuse terminate
            pass
        try:
            self.slave.fmi2FreeInstance(self.slave.component)
        finally:
            self._unload()

    def _unload(self) -> None:
        """Release a pythonfmu binary's state, unload the library, remove the extracted files."""
        try:
            _release_python_state(self.slave.dll)
        finally:
            self.slave.freeLibrary()
            shutil.rmtree(self._unzipdir, ignore_errors=True)
            _INSTANCES.pop(self._key, None)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
