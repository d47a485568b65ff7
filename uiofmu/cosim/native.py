"""The co-simulation loop in C: the master's FMI calls of every step made from a small C driver.

Each FMI call from Python costs about half a microsecond of ctypes, and a step of two FMUs makes six of
them, against about a tenth of a microsecond of the two C FMUs' own work. When every FMU of a run has a
native binary (any FMI 2 Co-Simulation FMU but a pythonfmu one, whose binary runs Python), the master hands
the stepping to ``c/native_loop.c``: a *program* of operations (:class:`Program`) executed at every
communication point, on the same buffers, through the same ``fmi2...`` functions of the same instances
(the addresses of fmpy's loaded functions and the instances' components), in the same order as its
Python loop. The histories are therefore the same bit for bit; a call that returns more than
fmi2Warning stops the run with the same exception, carrying the log lines the FMU wrote during that call.

The driver is compiled at first use with the system C compiler (:func:`uiofmu.fmu.c_backend.c_compiler`)
into a cache folder (:func:`cache_folder`), under a name made of a digest of its source and flags, and
loaded once per process. Without a compiler, or where it fails, :func:`driver` is None and the master
keeps its Python loop (``cosimulate(..., native=False)``, ``uiofmu cosim --python-loop`` ask for that loop
anyway).
"""

from __future__ import annotations

import atexit
import ctypes
import hashlib
import os
import platform
import shutil
import subprocess
import tempfile
from functools import lru_cache
from pathlib import Path

import numpy as np

from .fmi import FmuCallError, refused_step

#: The driver's source.
SOURCE = Path(__file__).parent / "c" / "native_loop.c"
#: Its compiler flags: no contraction into fused multiply-adds (the measurement's arithmetic is numpy's).
FLAGS = ("-std=c99", "-O2", "-shared", "-fPIC", "-fvisibility=hidden", "-ffp-contract=off", "-Wall", "-Wextra")
#: Communication points per driver call (between two progress updates).
CHUNK = 8192

# the operations of c/native_loop.c
CALL, STEP, TO_INTEGER, TO_REAL, MEASURE = range(5)


class _Operation(ctypes.Structure):
    """One operation of a program (``operation`` in ``c/native_loop.c``)."""

    _fields_ = [("kind", ctypes.c_int64), ("function", ctypes.c_void_p), ("component", ctypes.c_void_p),
                ("refs", ctypes.c_void_p), ("count", ctypes.c_int64), ("base", ctypes.c_void_p),
                ("stride", ctypes.c_int64), ("source", ctypes.c_void_p), ("source_stride", ctypes.c_int64),
                ("noise", ctypes.c_void_p), ("noise_stride", ctypes.c_int64), ("quantum", ctypes.c_double),
                ("logged", ctypes.c_void_p)]


def cache_folder() -> Path:
    """Where the compiled driver is kept: ``$UIOFMU_CACHE``, else ``$XDG_CACHE_HOME/uiofmu`` (``~/.cache/uiofmu``)."""
    if os.environ.get("UIOFMU_CACHE"):
        return Path(os.environ["UIOFMU_CACHE"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "uiofmu"


def _build(cc: str, folder: Path) -> Path:
    """The driver's shared library in ``folder``, compiled unless a build of the same source and flags is there
    (written under a temporary name and renamed: processes building it at once each get a whole file)."""
    source = SOURCE.read_bytes()
    digest = hashlib.sha256(b"\0".join([source, cc.encode(), *(f.encode() for f in FLAGS),
                                        platform.machine().encode()])).hexdigest()[:16]
    lib = folder / f"native_loop-{digest}.so"
    if lib.is_file():
        return lib
    folder.mkdir(parents=True, exist_ok=True)
    fd, part = tempfile.mkstemp(prefix=".native_loop-", suffix=".so", dir=folder)
    os.close(fd)
    try:
        proc = subprocess.run([cc, *FLAGS, "-o", part, str(SOURCE), "-lm"], capture_output=True, text=True)
        if proc.returncode != 0:
            raise OSError(proc.stderr.strip()[:500])
        os.replace(part, lib)
    finally:
        if os.path.exists(part):
            os.unlink(part)
    return lib


def _private_folder() -> Path:
    """A temporary folder of this process only, removed at its exit."""
    folder = tempfile.mkdtemp(prefix="uiofmu_native_")
    atexit.register(shutil.rmtree, folder, True)
    return Path(folder)


@lru_cache(maxsize=None)
def driver():
    """The driver's ``uiofmu_run``, built and loaded at first use; None without a C compiler or where the
    build or the loading fails (the master then keeps its Python loop). Where the cache folder cannot be
    written, the driver is built into a private temporary folder of the process."""
    from ..fmu.c_backend import c_compiler

    cc = c_compiler()
    if cc is None:
        return None
    for folder in (cache_folder, _private_folder):
        try:
            lib = ctypes.CDLL(str(_build(cc, folder())))
            break
        except (OSError, subprocess.SubprocessError):
            continue
    else:
        return None
    run = lib.uiofmu_run
    run.argtypes = [ctypes.c_void_p, ctypes.c_int64, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int64,
                    ctypes.c_int64, ctypes.c_int64, ctypes.c_void_p]
    run.restype = ctypes.c_int
    return run


def native_binary(fmu) -> bool:
    """Whether an FMU's binary runs without Python (not a pythonfmu FMU), so that the driver may call it."""
    if (fmu.description.generationTool or "").startswith("PythonFMU"):
        return False
    return not hasattr(fmu.slave.dll, "finalizePythonInterpreter")


def available(*fmus) -> bool:
    """Whether the driver is at hand and every FMU has a native binary (:func:`native_binary`)."""
    return all(native_binary(fmu) for fmu in fmus) and driver() is not None


def _address(function) -> int:
    """The address of a ctypes function (fmpy's, or one made from an address)."""
    return ctypes.cast(function, ctypes.c_void_p).value


def _at(buffer: np.ndarray, first: int = 0) -> int:
    """The address of element ``first`` of row 0 of a C-contiguous or row-strided 2-D buffer."""
    return buffer.ctypes.data + first * buffer.itemsize


def _check_rows(buffer: np.ndarray, dtype, width: int, rows: int) -> None:
    """Refuse a buffer the driver would read or write out of its bounds or as another type: it must be a matrix
    of ``dtype`` with at least ``rows`` rows of ``width`` values, each row contiguous."""
    if (buffer.ndim != 2 or buffer.dtype != dtype or buffer.shape[0] < rows or buffer.shape[1] < width
            or buffer.strides[1] != buffer.itemsize):
        raise ValueError(f"a buffer of the native loop must be a ({rows}, >= {width}) matrix of {np.dtype(dtype)} with "
                         f"contiguous rows, not {buffer.shape} of {buffer.dtype}")


class Program:
    """The operations of one run, executed by the driver at every communication point.

    Parameters
    ----------
    times, steps : numpy.ndarray
        The communication points t_0..t_K and the steps h_0..h_{K-1}.

    Notes
    -----
    Each operation comes with ``fail(k, status, mark)``, which raises the exception of the Python loop
    for the operation stopped at point k (``mark``: the FMU's count of log lines before the call, or for
    a conversion the index of the refused element). The program keeps every buffer and array it points
    into alive as long as it lives.
    """

    def __init__(self, times: np.ndarray, steps: np.ndarray):
        self.times = np.ascontiguousarray(times, dtype=float)
        self.steps = np.ascontiguousarray(steps, dtype=float)
        self.K = len(self.steps)
        self._operations: list = []
        self._fails: list = []
        self._keep: list = [self.times, self.steps]

    def keep(self, *objects) -> None:
        """Keep ``objects`` (what the operations point into) alive as long as the program."""
        self._keep += objects

    def _add(self, fail, **fields) -> None:
        self._operations.append(_Operation(**fields))
        self._fails.append(fail)

    def call(self, fmu, function, refs: int, count: int, base: int, stride: int, fail) -> None:
        """fmi2{Set,Get}{Real,Integer} (``function``: fmpy's, or one made from its address) of ``fmu`` on the
        ``count`` value references at address ``refs`` with the values of point k at ``base + k * stride`` (the
        caller keeps the references and the buffer alive as long as the program)."""
        self._add(fail, kind=CALL, function=_address(function), component=fmu.component, refs=refs, count=count,
                  base=base, stride=stride, logged=ctypes.addressof(fmu.logged))

    def values(self, fmu, function: str, names: list, buffer: np.ndarray, first: int = 0) -> None:
        """:meth:`call` of ``fmu``'s function named ``function`` on the vectors ``names`` with the values of point k
        at column ``first`` of row k of ``buffer`` (nothing when the vectors have no variable); a refusal raises
        :func:`call_failed`'s exception."""
        refs = fmu.value_references(names)
        if len(refs):
            _check_rows(buffer, np.intc if function.endswith("Integer") else np.float64, first + len(refs),
                        self.K + 1)
            self._keep += [refs, buffer]
            self.call(fmu, fmu.function(function), ctypes.addressof(refs), len(refs), _at(buffer, first),
                      buffer.strides[0], call_failed(fmu, function))

    def step(self, fmu, who: str) -> None:
        """fmi2DoStep(t_k, h_k, fmi2True) of ``fmu`` (none at t_K; the steps come after every other operation); a
        refusal raises :func:`~uiofmu.cosim.fmi.refused_step`'s exception naming ``who``."""

        def fail(k, status, mark):
            raise refused_step(who, k, float(self.times[k]), float(self.steps[k]),
                               FmuCallError("fmi2DoStep", int(status), fmu.messages[mark:]))

        self._add(fail, kind=STEP, function=_address(fmu.function("fmi2DoStep")), component=fmu.component,
                  logged=ctypes.addressof(fmu.logged))

    def convert(self, source: np.ndarray, a: int, target: np.ndarray, b: int, width: int, fail) -> None:
        """Copy ``width`` values of row k of ``source`` from column ``a`` into row k of ``target`` from column ``b``,
        Real to Integer (each an fmi2Integer, else ``fail``) or Integer to Real."""
        _check_rows(source, np.float64 if target.dtype == np.intc else np.intc, a + width, self.K + 1)
        _check_rows(target, np.intc if source.dtype == np.float64 else np.float64, b + width, self.K + 1)
        self._keep += [source, target]
        kind = TO_INTEGER if target.dtype == np.intc else TO_REAL
        self._add(fail, kind=kind, count=width, base=_at(target, b), stride=target.strides[0],
                  source=_at(source, a), source_stride=source.strides[0])

    def measure(self, y: np.ndarray, v: np.ndarray, quantum: float | None, target: np.ndarray) -> None:
        """``target[k] = y[k] + v[k]``, then ``quantum * round(target[k] / quantum)`` with a quantum."""
        for array in (y, v, target):
            _check_rows(array, np.float64, y.shape[1], self.K + 1)
        self._keep += [y, v, target]
        self._add(None, kind=MEASURE, count=y.shape[1], base=_at(target), stride=target.strides[0], source=_at(y),
                  source_stride=y.strides[0], noise=_at(v), noise_stride=v.strides[0], quantum=quantum or 0.0)

    def run(self, bar) -> None:
        """Every communication point, :data:`CHUNK` a driver call, the progress ``bar`` updated in between;
        an operation that stops the run raises its ``fail``'s exception."""
        run, K = driver(), self.K
        operations = (_Operation * len(self._operations))(*self._operations)
        fail = (ctypes.c_int64 * 4)()
        times, steps = self.times.ctypes.data, self.steps.ctypes.data
        for k0 in range(0, K + 1, CHUNK):
            count = min(CHUNK, K + 1 - k0)
            if run(operations, len(self._operations), times, steps, k0, count, K, fail):
                k, i, status, mark = fail
                self._fails[i](k, status, mark)
                raise RuntimeError(f"the native loop stopped at point {k}, operation {i} (status {status})")
            bar.update(min(count, K - k0))


def call_failed(fmu, function: str):
    """The ``fail`` of a call of ``fmu``'s ``function``: raise :class:`~uiofmu.cosim.fmi.FmuCallError` with the
    log lines the FMU wrote during the call."""

    def fail(k, status, mark):
        raise FmuCallError(function, int(status), fmu.messages[mark:]) from None

    return fail


__all__ = ["CHUNK", "Program", "available", "cache_folder", "call_failed", "driver", "native_binary"]
