"""FMU files unpacked once per process, found again by their content.

An :class:`~uiofmu.cosim.fmi.Fmu` takes a *copy* of its file here: the file's bytes extracted into a private
folder of the process (removed when it exits) and, once an instance was made from it, fmpy's loaded binary.
The copies of a file are found by the SHA-256 of its bytes, never by its name or time: the same bytes under
another name share them, other bytes under the same name do not. The bytes are hashed again on every use;
a file seen for the first time is copied into the private folder and hashed there, so what is unpacked is
always the content its digest names, whatever happens to the file meanwhile.

A copy serves one instance at a time:

- when its instance is freed, a copy keeps its binary loaded for the next instance of the same bytes (a new
  ``fmi2Instantiate`` of the loaded binary after ``fmi2FreeInstance``, as FMI 2 allows);
- the binary of an FMU whose model description says ``canBeInstantiatedOnlyOncePerProcess`` is unloaded when
  its instance is freed (its next instance loads it again, with fresh static data); its files stay;
- two instances of the same bytes alive at once (an observer and its noise-free twin) take two copies,
  each extracted into its own folder: two files are two libraries to the dynamic loader, so neither sees the
  other's static data, whatever the FMU declares.

At most :data:`MAX_FILES` files are kept: the least recently used one with no live instance is unloaded and
removed when another comes. A process started by ``fork`` starts its own cache.
"""

from __future__ import annotations

import atexit
import hashlib
import itertools
import os
import shutil
import stat
import tempfile
import threading
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path

from ..runtime.errors import FmuError

#: Most FMU files (distinct contents) whose copies a process keeps.
MAX_FILES = 16

#: Bytes read at a time when a file is hashed.
CHUNK = 1 << 20


@dataclass(eq=False)
class Unit:
    """One FMU content in this process: its digest, its model description, its private copy of the bytes
    and the copies with no live instance."""

    digest: str
    description: object
    archive: Path
    once: bool
    checked: tuple = ()
    free: list = field(default_factory=list)
    busy: int = 0
    pid: int = field(default_factory=os.getpid)


@dataclass(eq=False)
class Copy:
    """One extraction of a :class:`Unit` with, after its first instance, fmpy's ``FMU2Slave`` (binary loaded)."""

    unit: Unit
    folder: Path
    slave: object = None


_UNITS: "OrderedDict[str, Unit]" = OrderedDict()
_STATE = {"root": None, "closed": False}
_NAMES = itertools.count(1)
_LOCK = threading.RLock()          # instances may be made and freed from several threads


def _open_regular(path):
    """``path`` opened for reading as a regular file: a FIFO or a device is refused before a byte is read (it
    is opened without blocking and looked at by its descriptor), with the message every reader of an FMU
    gives (:func:`uiofmu.cosim.fmi.check_regular`)."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOCTTY", 0))
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise FmuError(f"{path}: an FMU is a regular file")
    return os.fdopen(fd, "rb")


def digest_of(path) -> str:
    """The SHA-256 of a regular file's bytes (hex)."""
    h = hashlib.sha256()
    with _open_regular(path) as f:
        while chunk := f.read(CHUNK):
            h.update(chunk)
    return h.hexdigest()


def _root() -> Path:
    """The process's private folder (made on first use, again if something removed it; removed at exit)."""
    if _STATE["root"] is None or not _STATE["root"].is_dir():
        _STATE["root"] = Path(tempfile.mkdtemp(prefix="uiofmu_fmus_"))
    return _STATE["root"]


def _add(path: Path, describe, checked: tuple) -> Unit:
    """The unit of the bytes ``path`` holds now: a private copy, checked and described as ``path``."""
    snapshot = _root() / f"new-{next(_NAMES)}.fmu"
    try:
        with _open_regular(path) as src, open(snapshot, "wb") as dst:
            shutil.copyfileobj(src, dst, CHUNK)
        digest = digest_of(snapshot)
    except OSError:
        snapshot.unlink(missing_ok=True)
        raise
    if digest in _UNITS:                            # the file changed into bytes already here
        snapshot.unlink()
        return _UNITS[digest]
    try:
        description = describe(path, source=snapshot)
    except BaseException:
        snapshot.unlink(missing_ok=True)
        _tidy()
        raise
    archive = snapshot.with_name(f"{digest}.fmu")
    snapshot.rename(archive)
    cs = getattr(description, "coSimulation", None)
    unit = Unit(digest, description, archive, bool(getattr(cs, "canBeInstantiatedOnlyOncePerProcess", False)),
                checked)
    _UNITS[digest] = unit
    return unit


def _tidy() -> None:
    """Remove the private folder while it holds nothing (a refused file leaves no trace)."""
    root = _STATE["root"]
    if root is not None and not _UNITS:
        try:
            root.rmdir()
        except OSError:
            return
        _STATE["root"] = None


def _extract(path: Path, unit: Unit) -> Copy:
    """A new extraction of ``unit`` (errors name ``path``)."""
    from fmpy import extract

    folder = Path(tempfile.mkdtemp(prefix="unit_", dir=_root()))
    try:
        extract(str(unit.archive), unzipdir=str(folder))
    except Exception as exc:  # noqa: BLE001 - zipfile and OS errors of a broken archive
        shutil.rmtree(folder, ignore_errors=True)
        text = str(exc).strip().splitlines()
        raise FmuError(f"{path}: cannot extract the FMU ({text[0][:300] if text else type(exc).__name__})") from None
    return Copy(unit, folder)


def take(path, describe, checked: tuple = ()) -> Copy:
    """A copy of the FMU file ``path`` for one instance: a free one of its bytes, else a new extraction.

    Parameters
    ----------
    path : str or Path
        A regular file.
    describe : callable
        ``describe(path, source=file)``: the model description of an FMU file seen for the first time, read
        from ``file`` (the private copy of its bytes) and checked against the limits, with errors naming
        ``path`` (:func:`uiofmu.cosim.fmi.read_description`).
    checked : tuple, optional
        The limits ``describe`` checks against (:func:`uiofmu.cosim.fmi.limits`): bytes checked under other
        limits are described again.

    Returns
    -------
    Copy
        Its ``unit.description`` is fmpy's model description (shared: read it, do not change it), its
        ``folder`` the extraction and its ``slave`` fmpy's ``FMU2Slave`` with its binary loaded, or None
        (the caller loads it and sets ``slave``). Give it back with :func:`give_back` (or :func:`drop`).

    Raises
    ------
    FmuError
        From ``describe``, for a file that cannot be read and for an FMU fmpy cannot extract.
    """
    path = Path(path)
    with _LOCK:
        try:
            unit = _UNITS.get(digest_of(path))
            if unit is not None and not unit.archive.is_file():     # its files were removed under it
                _remove(unit)
                unit = None
            if unit is not None and unit.checked != checked:
                unit.description, unit.checked = describe(path, source=unit.archive), checked
            unit = unit or _add(path, describe, checked)
        except OSError as exc:
            raise FmuError(f"{path}: not a readable FMU ({exc.strerror or type(exc).__name__})") from None
        _UNITS.move_to_end(unit.digest)
        copy = None
        while unit.free and copy is None:
            copy = unit.free.pop()
            if not copy.folder.is_dir():            # removed under it: unloaded and forgotten
                _forget_copy(copy)
                copy = None
        copy = copy or _extract(path, unit)
        unit.busy += 1
        _evict()                                    # after the count: this unit is in use, it stays
        return copy


def give_back(copy: Copy) -> None:
    """Return a copy whose instance was freed: kept for the next instance of its bytes (its binary unloaded
    first for an FMU that can be instantiated only once per process)."""
    unit = copy.unit
    if unit.pid != os.getpid():                     # the parent's, inherited through fork: the parent's to remove
        return
    with _LOCK:
        unit.busy -= 1
        if copy.slave is not None and (unit.once or _STATE["closed"]):
            _unload(copy)
        if _STATE["closed"] or _UNITS.get(unit.digest) is not unit:
            shutil.rmtree(copy.folder, ignore_errors=True)
            return
        unit.free.append(copy)
        _evict()


def drop(copy: Copy) -> None:
    """Return a copy that must not serve again (its binary failed to load or to instantiate): unloaded and
    removed."""
    if copy.unit.pid != os.getpid():
        return
    with _LOCK:
        copy.unit.busy -= 1
        _forget_copy(copy)


def release_python_state(dll) -> None:
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


def _unload(copy: Copy) -> None:
    """Release a pythonfmu binary's interpreter state, then unload the binary."""
    slave, copy.slave = copy.slave, None
    try:
        release_python_state(slave.dll)
    finally:
        slave.freeLibrary()


def _forget_copy(copy: Copy) -> None:
    """Unload a copy's binary (if loaded) and remove its folder."""
    try:
        if copy.slave is not None:
            _unload(copy)
    finally:
        shutil.rmtree(copy.folder, ignore_errors=True)


def _remove(unit: Unit) -> None:
    """Unload and remove the free copies of a unit and its bytes (its busy copies go when given back)."""
    _UNITS.pop(unit.digest, None)
    while unit.free:
        _forget_copy(unit.free.pop())
    unit.archive.unlink(missing_ok=True)


def _evict() -> None:
    """Remove the least recently used units with no live instance while more than :data:`MAX_FILES` are kept."""
    for unit in list(_UNITS.values()):
        if len(_UNITS) <= MAX_FILES:
            return
        if unit.busy == 0:
            _remove(unit)


def files() -> list[str]:
    """The digests of the FMU contents this process keeps, least recently used first."""
    return list(_UNITS)


def folder() -> Path | None:
    """The process's private folder (None before the first FMU)."""
    return _STATE["root"]


@atexit.register
def _close() -> None:
    """At exit: unload every free copy and remove the private folder (a copy still in use is unloaded and
    removed when it is given back)."""
    with _LOCK:
        _STATE["closed"] = True
        for unit in list(_UNITS.values()):
            try:
                _remove(unit)
            except Exception:  # noqa: BLE001 - at exit, the rest must still go
                pass
        if _STATE["root"] is not None:
            shutil.rmtree(_STATE["root"], ignore_errors=True)


def _forget() -> None:
    """In a child started by ``fork``: a cache of its own (the parent's folder and binaries stay the parent's)."""
    global _LOCK
    _LOCK = threading.RLock()                       # a lock held by another thread at the fork stays held
    _UNITS.clear()
    _STATE.update(root=None, closed=False)


os.register_at_fork(after_in_child=_forget)


__all__ = ["CHUNK", "MAX_FILES", "Copy", "Unit", "digest_of", "drop", "files", "folder", "give_back",
           "release_python_state", "take"]
