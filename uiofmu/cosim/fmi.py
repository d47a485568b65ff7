"""Driving an FMU through fmpy: named vectors, captured log messages, typed errors.

Every FMI call goes through fmpy's ``FMU2Slave``; a call that returns fmi2Discard,
fmi2Error or fmi2Fatal raises :class:`FmuCallError` carrying the status and the log lines
the FMU wrote, so a master can say exactly what went wrong and where.

An FMU is checked against the limits below (entries, unpacked sizes, compression ratio; the model
description's size, elements, variables and dependency lists) before fmpy reads or extracts it, and a value
for an Integer input must be an fmi2Integer (:func:`first_non_integer`): fmpy would wrap it modulo 2**32.

Log lines reach the right instance through one logger for the whole process: fmpy's native
proxy (which formats the FMU's variadic message) holds a single Python callback, so each
instance passes its own key as ``componentEnvironment`` and the logger files the line there.
"""

from __future__ import annotations

import itertools
import os
import struct
import weakref
import zipfile
import ctypes
from ctypes import byref
from functools import lru_cache
from pathlib import Path
from xml.parsers import expat

import numpy as np

from ..runtime.card import MAX_DIM
from ..runtime.errors import FmuError
from ..runtime.files import MAX_INPUT_BYTES, parse_json
from . import fmu_cache
from .fmu_cache import release_python_state as _release_python_state  # noqa: F401 - also its name here

STATUS = ["ok", "warning", "discard", "error", "fatal", "pending"]

# -- what an FMU may hold -----------------------------------------------------------------------
# An FMU is checked on its zip directory before anything is extracted or parsed (:func:`open_archive`,
# :func:`check_archive`); an entry never unpacks to more than the size the directory declares (zipfile stops
# there and fails the CRC). The FMUs uiofmu builds have 13 to 41 entries and unpack to less than 1 MiB
# (``make fmus``); at the card schema's dimension bound (:data:`uiofmu.runtime.card.MAX_DIM`) their largest
# files are ``resources/model.json``, which is read only up to :data:`~uiofmu.runtime.files.MAX_INPUT_BYTES`
# (64 MiB), and the C source of the same numbers, about as large.

#: Most entries in an FMU (a pythonfmu FMU carries about 40: its runtime package).
MAX_ENTRIES = 10_000
#: Largest central directory (bytes): an entry's record is 46 bytes plus its name and extra field (a few
#: dozen bytes in an FMU; 512 on average leaves room for deep paths).
MAX_DIRECTORY_BYTES = MAX_ENTRIES * 512
#: Largest unpacked entry (bytes): twice the largest ``model.json`` uiofmu reads.
MAX_ENTRY_BYTES = 2 * MAX_INPUT_BYTES
#: Largest unpacked FMU (bytes): the card, its C source, the binaries and the runtime, with room to spare.
MAX_UNPACKED_BYTES = 4 * MAX_INPUT_BYTES
#: Highest compression ratio (unpacked over packed size) of an entry of more than :data:`RATIO_FLOOR` bytes:
#: binaries and numbers written as text deflate 1 to 5 times, the zeros of a zip bomb about 1000 times.
MAX_RATIO = 100
#: Entries up to this size (bytes) may deflate better than :data:`MAX_RATIO` (a small card of zeros does).
RATIO_FLOOR = 16 * 2**20
#: Largest ``modelDescription.xml`` (bytes): 100,000 variables of about 300 bytes with their dependencies.
MAX_DESCRIPTION_BYTES = 32 * 2**20
#: Most ScalarVariables in an FMU's model description. An FMU uiofmu builds has at most ten vectors (the
#: observer's ``xhat0``, ``y``, ``u``, ``ydot``, ``theta``, ``mode``, ``xhat``, ``r``, ``dhat``; the plant's ``x0``,
#: ``u``, ``d``, ``y``, ``x``, ...) of at most MAX_DIM = 1000 entries: 10,000 variables. A plant FMU from
#: another tool may add its local variables: ten times that. fmpy builds an object of about 2 kB per variable
#: (cosim took 2.5 GB and 25 s for 1,000,000).
MAX_VARIABLES = 100_000
#: Most ScalarVariables in an FMU that ``uiofmu validate`` checks (one uiofmu built: at most ten vectors of
#: MAX_DIM entries). fmpy's ``validate_fmu`` parses each name with its grammar, about 1.2 ms a variable.
MAX_OWN_VARIABLES = 16 * MAX_DIM
#: Most XML elements in a model description: a variable brings its type element and a few ModelStructure
#: entries.
MAX_ELEMENTS = 10 * MAX_VARIABLES
#: Most entries of all the ``dependencies`` and ``dependenciesKind`` lists of a model description together: an
#: output of an FMU uiofmu builds (at most 3 MAX_DIM of them: ``xhat``, ``r``, ``dhat``) depends on at most the
#: MAX_DIM measured outputs. fmpy spends about 1 us on an entry (15,000,000 in a 30 MB description took 16 s).
MAX_DEPENDENCIES = 3 * MAX_DIM**2


def limits() -> tuple:
    """The limits above as they are now: a file checked under others is checked again
    (:mod:`uiofmu.cosim.fmu_cache`)."""
    return (MAX_ENTRIES, MAX_DIRECTORY_BYTES, MAX_ENTRY_BYTES, MAX_UNPACKED_BYTES, MAX_RATIO, RATIO_FLOOR,
            MAX_DESCRIPTION_BYTES, MAX_VARIABLES, MAX_OWN_VARIABLES, MAX_ELEMENTS, MAX_DEPENDENCIES)


#: The range of an fmi2Integer (a C int of 32 bits).
FMI2_INTEGER = (-2**31, 2**31 - 1)


def first_non_integer(values) -> int:
    """The flat index of the first value that is not an fmi2Integer, -1 when every value is one.

    Parameters
    ----------
    values : array_like of float

    Returns
    -------
    int
        The index of the first value that is not finite, not integral or outside :data:`FMI2_INTEGER`
        (fmpy would wrap it modulo 2**32, or fail), or -1.
    """
    v = np.asarray(values, dtype=float).ravel()
    low, high = FMI2_INTEGER
    good = np.isfinite(v) & (v == np.floor(v)) & (v >= low) & (v <= high)
    return -1 if good.all() else int(np.argmin(good))


def not_an_integer(where: str, value: float) -> str:
    """The message for ``value`` at ``where`` that is not an fmi2Integer (see :func:`first_non_integer`)."""
    low, high = FMI2_INTEGER
    return f"{where}: {float(value)!r} is not an fmi2Integer (expected an integer from {low} to {high})"


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


def refused_step(who: str, k: int, t: float, h: float, exc: FmuCallError) -> FmuError:
    """The error of a master whose ``who`` FMU (``"plant"``, ``"observer"``, ...) refused step ``k`` from
    ``t`` over ``h``: its last log line, or the call's status without one."""
    return FmuError(f"the {who} FMU refused step {k} (t = {t:g} s, h = {h:g} s): "
                    + (exc.messages[-1] if exc.messages else str(exc)))


def _over(path, found: str, limit: int, name: str) -> FmuError:
    """The refusal of an FMU beyond one of the limits above: what was found, the limit and its name."""
    return FmuError(f"{path}: {found}, more than the limit of {limit} (uiofmu.cosim.fmi.{name})")


#: The end record of a zip archive: signature, two disk numbers, entries on this disk, entries in all,
#: directory size and offset, comment length.
_END = struct.Struct("<4s4H2LH")


def _declared_entries(path: Path) -> tuple[int, int]:
    """The number of entries and the size in bytes of the central directory that the end record of a zip
    archive declares, read without the directory (which zipfile loads whole, an object per entry);
    (0, 0) when there is no end record (zipfile then refuses the file)."""
    with open(path, "rb") as f:
        size = f.seek(0, 2)
        f.seek(max(0, size - _END.size - 0xFFFF))
        tail = f.read()
        at = tail.rfind(b"PK\x05\x06")
        if at < 0 or len(tail) - at < _END.size:
            return 0, 0
        entries, directory = _END.unpack_from(tail, at)[4:6]
        if (entries == 0xFFFF or directory == 0xFFFFFFFF) and at >= 20 and tail[at - 20:at - 16] == b"PK\x06\x07":
            f.seek(struct.unpack_from("<Q", tail, at - 12)[0])          # zip64: its own end record
            record = f.read(56)
            if record[:4] == b"PK\x06\x06" and len(record) == 56:
                entries, directory = struct.unpack_from("<QQ", record, 32)
    return entries, directory


def _check_entries(path: Path, infos: list) -> None:
    """Refuse an archive beyond :data:`MAX_ENTRIES`, :data:`MAX_ENTRY_BYTES`, :data:`MAX_UNPACKED_BYTES` or
    :data:`MAX_RATIO`, from the sizes its directory declares."""
    if len(infos) > MAX_ENTRIES:
        raise _over(path, f"the FMU has {len(infos)} entries", MAX_ENTRIES, "MAX_ENTRIES")
    total = 0
    for info in infos:
        name = repr(info.filename[:80])
        if info.file_size > MAX_ENTRY_BYTES:
            raise _over(path, f"the FMU's entry {name} unpacks to {info.file_size} bytes", MAX_ENTRY_BYTES,
                        "MAX_ENTRY_BYTES")
        ratio = info.file_size / max(info.compress_size, 1)
        if info.file_size > RATIO_FLOOR and ratio > MAX_RATIO:
            raise _over(path, f"the FMU's entry {name} unpacks to {info.file_size} bytes from {info.compress_size}, "
                        f"a compression ratio of {ratio:.0f} for an entry of more than {RATIO_FLOOR} bytes",
                        MAX_RATIO, "MAX_RATIO")
        total += info.file_size
    if total > MAX_UNPACKED_BYTES:
        raise _over(path, f"the FMU unpacks to {total} bytes", MAX_UNPACKED_BYTES, "MAX_UNPACKED_BYTES")


def open_archive(path, source=None) -> zipfile.ZipFile:
    """An FMU's zip archive, opened after its entry count and declared sizes were checked against the limits.

    Parameters
    ----------
    path : str or Path
        A regular file.
    source : str or Path, optional
        The file to open in its place, named ``path`` in the messages (a private copy of its bytes).

    Returns
    -------
    zipfile.ZipFile
        Open (the caller closes it).

    Raises
    ------
    FmuError
        For a missing or non-regular file, and for an archive beyond :data:`MAX_ENTRIES`,
        :data:`MAX_ENTRY_BYTES`, :data:`MAX_UNPACKED_BYTES` or :data:`MAX_RATIO`, naming the limit and the numbers.
    OSError, zipfile.BadZipFile
        For a file that is not a zip archive.
    """
    path = Path(path)
    if source is None:
        check_regular(path)
    source = path if source is None else Path(source)
    declared, directory = _declared_entries(source)
    if declared > MAX_ENTRIES:
        raise _over(path, f"the FMU declares {declared} entries", MAX_ENTRIES, "MAX_ENTRIES")
    if directory > MAX_DIRECTORY_BYTES:          # a directory whose end record understates its entries
        raise _over(path, f"the FMU's central directory has {directory} bytes", MAX_DIRECTORY_BYTES,
                    "MAX_DIRECTORY_BYTES")
    archive = zipfile.ZipFile(source)
    try:
        _check_entries(path, archive.infolist())
    except FmuError:
        archive.close()
        raise
    return archive


class _DescriptionCounter:
    """Counts a model description's elements, ScalarVariables and dependency entries as expat reads it,
    raising :class:`FmuError` as soon as one passes its limit (nothing is kept: no tree is built)."""

    def __init__(self, path: Path, own: bool):
        self.path = path
        self.limit = ("MAX_OWN_VARIABLES", MAX_OWN_VARIABLES) if own else ("MAX_VARIABLES", MAX_VARIABLES)
        self.elements = self.variables = self.dependencies = 0

    def start(self, tag: str, attributes: dict) -> None:
        """expat's start-element handler."""
        self.elements += 1
        if self.elements > MAX_ELEMENTS:
            raise _over(self.path, f"modelDescription.xml has {self.elements} elements", MAX_ELEMENTS, "MAX_ELEMENTS")
        if tag == "ScalarVariable":
            self.variables += 1
            if self.variables > self.limit[1]:
                raise self.too_many(f"modelDescription.xml has {self.variables} ScalarVariables")
        for key in ("dependencies", "dependenciesKind"):
            # fmpy splits the list at once: at most one entry per variable (counted as fmpy counts them)
            entries = attributes[key].strip().count(" ") + 1 if key in attributes else 0
            if entries > self.limit[1]:
                raise self.too_many(f"a {key} list of modelDescription.xml has {entries} entries")
            self.dependencies += entries
            if self.dependencies > MAX_DEPENDENCIES:
                raise _over(self.path, f"the dependency lists of modelDescription.xml have at least "
                            f"{self.dependencies} entries", MAX_DEPENDENCIES, "MAX_DEPENDENCIES")

    def too_many(self, found: str) -> FmuError:
        """The refusal of a count beyond the variable limit."""
        return _over(self.path, found, self.limit[1], self.limit[0])


def check_description(path, archive: zipfile.ZipFile, own: bool = False) -> None:
    """Refuse a model description larger than uiofmu needs, before fmpy parses it.

    The ``modelDescription.xml`` of ``archive`` must have at most :data:`MAX_DESCRIPTION_BYTES` bytes,
    :data:`MAX_ELEMENTS` elements and :data:`MAX_VARIABLES` (``own``: :data:`MAX_OWN_VARIABLES`) ScalarVariables,
    no dependency list longer than that and at most :data:`MAX_DEPENDENCIES` dependency entries in all (a
    streaming count with expat, stopped at the first limit passed).

    Parameters
    ----------
    path : str or Path
        The FMU, for the messages.
    archive : zipfile.ZipFile
        Its archive (:func:`open_archive`).
    own : bool
        An FMU that uiofmu built (``uiofmu validate``): the tighter :data:`MAX_OWN_VARIABLES`.

    Raises
    ------
    FmuError
        Naming the limit and the numbers, or the line where the XML is not well-formed.
    """
    try:
        info = archive.getinfo("modelDescription.xml")
    except KeyError:
        return                          # fmpy's message says the file is missing
    if info.file_size > MAX_DESCRIPTION_BYTES:
        raise _over(path, f"modelDescription.xml has {info.file_size} bytes", MAX_DESCRIPTION_BYTES,
                    "MAX_DESCRIPTION_BYTES")
    counter = _DescriptionCounter(Path(path), own)
    parser = expat.ParserCreate()
    parser.StartElementHandler = counter.start
    try:
        with archive.open(info) as f:
            parser.ParseFile(f)
    except expat.ExpatError as exc:
        raise FmuError(f"{path}: modelDescription.xml is not well-formed XML ({exc})") from None


def check_regular(path) -> None:
    """Refuse a path that is not a regular file, the way every reader of an FMU says it.

    Raises
    ------
    FmuError
        ``PATH: no such FMU`` or ``PATH: an FMU is a regular file``.
    """
    path = Path(path)
    if not path.is_file():
        raise FmuError(f"{path}: no such FMU" if not path.exists() else f"{path}: an FMU is a regular file")


def check_archive(path, own: bool = False, source=None) -> None:
    """Refuse an FMU larger than uiofmu needs (:func:`open_archive`, :func:`check_description`) before
    anything of it is extracted or parsed.

    Parameters
    ----------
    path : str or Path
        The FMU.
    own : bool
        An FMU that uiofmu built (:func:`check_description`).
    source : str or Path, optional
        The file to read in its place (:func:`open_archive`).

    Raises
    ------
    FmuError
        For an FMU beyond a limit, naming it and the numbers, and for a file that is not a zip archive.
    """
    try:
        with open_archive(path, source) as archive:
            check_description(path, archive, own)
    except (OSError, zipfile.BadZipFile, RuntimeError, NotImplementedError) as exc:
        raise FmuError(f"{path}: not a readable FMU ({_first_line(exc)})") from None


def read_description(path, source=None):
    """fmpy's model description of an FMU that passed :func:`check_archive`.

    Parameters
    ----------
    path : str or Path
        The FMU.
    source : str or Path, optional
        The file to read in its place, named ``path`` in the messages (:func:`open_archive`).

    Returns
    -------
    fmpy.model_description.ModelDescription

    Raises
    ------
    FmuError
        For an FMU beyond a limit of :func:`check_archive`, or one fmpy cannot read.
    """
    from fmpy import read_model_description

    check_archive(path, source=source)
    try:
        return read_model_description(str(path if source is None else source))
    except Exception as exc:  # noqa: BLE001 - fmpy raises plain exceptions for broken archives
        raise FmuError(f"{path}: not a readable FMU ({_first_line(exc)})") from None


def read_model_text(path) -> str:
    """The text of ``resources/model.json`` packed in an FMU built by uiofmu (see :func:`read_model_json`)."""
    path = Path(path)
    try:
        with open_archive(path) as z:
            info = z.getinfo("resources/model.json")
            if info.file_size > MAX_INPUT_BYTES:
                raise FmuError(f"{path}: resources/model.json has {info.file_size} bytes, more than {MAX_INPUT_BYTES}")
            return z.read(info).decode("utf-8")
    except (KeyError, OSError, zipfile.BadZipFile, UnicodeDecodeError, RuntimeError, NotImplementedError):
        raise FmuError(f"{path}: not an FMU built by uiofmu (no readable resources/model.json)") from None


def read_model_json(path, text: str | None = None) -> dict:
    """The uiofmu model (``resources/model.json``) packed in an FMU built by uiofmu.

    Parameters
    ----------
    path : str or Path
        A regular file within the limits of :func:`open_archive`; its ``resources/model.json`` is read only up to
        :data:`uiofmu.runtime.files.MAX_INPUT_BYTES` and nested at most :data:`uiofmu.runtime.files.MAX_DEPTH` deep.
    text : str, optional
        That file's text, already read (:func:`read_model_text`).

    Returns
    -------
    dict
    """
    text = read_model_text(path) if text is None else text
    spec = parse_json(text, f"{Path(path)}: resources/model.json", error=FmuError)
    if not isinstance(spec, dict):
        raise FmuError(f"{Path(path)}: resources/model.json is not a uiofmu model")
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
        fmu.logged.value = len(fmu.messages)


@lru_cache(maxsize=None)
def _logger():
    """The process's one logger callback, created on first use and kept for good (fmpy's
    proxy may call it as long as any FMU lives)."""
    from fmpy.fmi2 import fmi2CallbackLoggerTYPE

    return fmi2CallbackLoggerTYPE(_log)


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
        from fmpy import calloc, free
        from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                               fmi2CallbackFunctions)
        from fmpy.fmi1 import FMICallException
        from fmpy.logging import addLoggerProxy

        _FMPY_ERROR[0] = FMICallException

        self.path = Path(path)
        check_regular(self.path)
        self._copy = fmu_cache.take(self.path, read_description, limits())   # checked against the limits, extracted
        self.description = self._copy.unit.description
        if self.description.coSimulation is None:
            fmu_cache.give_back(self._copy)
            raise FmuError(f"{self.path}: not a Co-Simulation FMU")
        self.messages: list[str] = []
        self.logged = ctypes.c_int64(0)        # len(messages), where the native loop reads it
        self._refs = {v.name: v.valueReference for v in self.description.modelVariables}
        self._types = {v.name: v.type for v in self.description.modelVariables}
        self._vectors: dict = {}
        self._unzipdir = str(self._copy.folder)

        self._key = next(_KEYS)
        _INSTANCES[self._key] = self
        self._callbacks = fmi2CallbackFunctions()
        self._callbacks.logger = _logger()
        self._callbacks.componentEnvironment = self._key
        self._callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        self._callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        addLoggerProxy(byref(self._callbacks))
        cwd = os.getcwd()
        if self._copy.slave is None:          # a new copy: load its binary (a kept one has it loaded)
            try:
                self._copy.slave = FMU2Slave(guid=self.description.guid, unzipDirectory=self._unzipdir,
                                             modelIdentifier=self.description.coSimulation.modelIdentifier,
                                             instanceName=instance_name)
            except Exception as exc:  # noqa: BLE001 - fmpy raises plain exceptions for a missing binary
                os.chdir(cwd)         # fmpy enters the binary's folder to load it, and stays there when that fails
                fmu_cache.drop(self._copy)
                _INSTANCES.pop(self._key, None)
                raise FmuError(f"{self.path}: its binary for this platform cannot be loaded "
                               f"({_first_line(exc)})") from None
        self.slave = self._copy.slave
        self.slave.instanceName = instance_name
        try:
            self.slave.instantiate(callbacks=self._callbacks, loggingOn=True)
        except Exception:  # noqa: BLE001 - fmpy raises a bare Exception here
            fmu_cache.drop(self._copy)
            _INSTANCES.pop(self._key, None)
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
        """Set the vector ``name`` (Real, or Integer: each value must be an fmi2Integer, see
        :func:`first_non_integer`; another raises :class:`~uiofmu.runtime.errors.FmuError` naming it)."""
        refs = self.refs(name)
        if refs and self.integer(name):
            try:
                values = np.asarray(values, dtype=float).ravel()
            except OverflowError:
                raise FmuError(f"{self.path}: the Integer input {name}: a value too large for a float") from None
            bad = first_non_integer(values)
            if bad >= 0:
                raise FmuError(not_an_integer(f"{self.path}: the Integer input {name}[{bad + 1}]", values[bad]))
            self._call("setInteger", refs, [int(v) for v in values])
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
        """Terminate and free the instance; its copy of the FMU goes back to :mod:`uiofmu.cosim.fmu_cache`
        for the next instance of the same bytes."""
        if not self._alive:
            return
        self._alive = False
        try:
            self.slave.terminate()
        except Exception:  # noqa: BLE001 - an instance in error state may refuse terminate
            pass
        try:
            self.slave.fmi2FreeInstance(self.slave.component)
        except BaseException:
            fmu_cache.drop(self._copy)             # an instance that could not be freed: its binary goes too
            raise
        else:
            fmu_cache.give_back(self._copy)
        finally:
            _INSTANCES.pop(self._key, None)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
