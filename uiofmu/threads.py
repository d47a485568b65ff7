"""One BLAS thread for uiofmu's small dense linear algebra, inside uiofmu's own calls only.

Every matrix uiofmu multiplies, factors or exponentiates is small (n of a few to a few dozen): a
second BLAS thread there costs more in start-up and spinning than it saves, and on a busy machine
OpenBLAS's threads make a 4x4 ``scipy.linalg.expm`` cost 6-10 ms of CPU against 0.01 ms. The public
entry points (:func:`uiofmu.check`, :func:`uiofmu.design`, :func:`uiofmu.verify`, the co-simulation
master, a campaign's runs, the command line) run under :func:`one_blas_thread`; the previous limits
come back when they return, so the user's own numpy code keeps whatever threading it had. uiofmu
sets no environment variable (threadpoolctl's import sets ``KMP_DUPLICATE_LIB_OK``, for Intel's
OpenMP, unless it is set).

numpy and scipy each load their own OpenBLAS: the limit covers every BLAS library loaded when it
is entered (the design and the re-check, which use scipy, import it first; the master imports it
only where it needs it), and :mod:`threadpoolctl` reads the loaded libraries again only
when modules were imported since it last read them.

The command line goes one step further, for its commands only (:func:`start_with_one_thread`):
OpenBLAS starts its pool of threads when it loads, from the number it reads then in
``OPENBLAS_NUM_THREADS`` (or ``GOTO_NUM_THREADS``, ``OMP_NUM_THREADS``), and its threads spin
while they wait: a pool limited afterwards has cost its CPU already (``import numpy, scipy.linalg``
takes 0.37 s of CPU on a 2-core machine, 0.20 s with one thread). So numpy's BLAS library is loaded
by :func:`start_with_one_thread`, and scipy's (and cvxpy's) where uiofmu first imports them
(:func:`blas_module`), with ``OPENBLAS_NUM_THREADS=1`` in the environment, set only around their
imports (:func:`loading_blas`) and removed after them; a command that needs no scipy (``uiofmu check``
of a discrete plant) does not import it. The processes started later (the C compiler, the
co-simulation loop, Dask's workers, which Dask starts with one BLAS thread of its own accord)
inherit the user's environment. A user who set one of these variables keeps the number chosen
(``make test-blas`` runs with 2 threads), and ``import uiofmu`` changes nothing of this.
"""

from __future__ import annotations

import contextlib
import functools
import importlib
import os
import sys

#: The environment variables OpenBLAS reads, when it loads, for the number of threads it starts.
THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS")

_controller = None
_modules = 0
_one_at_load = False            # set by the command line: BLAS libraries load with one thread


@contextlib.contextmanager
def start_with_one_thread():
    """Run the block (a command of the command line) with the BLAS libraries it loads started with one
    thread: numpy's now, scipy's and cvxpy's where uiofmu first imports them (:func:`blas_module`);
    nothing when the user set one of :data:`THREAD_VARIABLES`. After the block, uiofmu imports them
    as a library does again (a program that calls :func:`uiofmu.cli.main` goes on as it was)."""
    global _one_at_load
    _one_at_load = not any(os.environ.get(name) for name in THREAD_VARIABLES)
    try:
        with loading_blas():
            import numpy  # noqa: F401 - numpy's OpenBLAS, started with one thread
        yield
    finally:
        _one_at_load = False


@contextlib.contextmanager
def loading_blas():
    """Import BLAS libraries in the block with ``OPENBLAS_NUM_THREADS=1``, then restore the environment.

    Only inside :func:`start_with_one_thread`; otherwise the block runs as it is. OpenBLAS reads the
    variable once, when it loads: a library already loaded keeps its threads, and the processes started
    after the block do not see the variable.
    """
    if not _one_at_load or any(os.environ.get(name) for name in THREAD_VARIABLES):
        yield
        return
    empty = os.environ.get("OPENBLAS_NUM_THREADS")           # None, or "" (which OpenBLAS ignores)
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    try:
        yield
    finally:
        if empty is None:
            del os.environ["OPENBLAS_NUM_THREADS"]
        else:
            os.environ["OPENBLAS_NUM_THREADS"] = empty


def blas_module(name: str):
    """The module ``name``, one whose import loads a BLAS library (``"scipy.linalg"``, ``"scipy.signal"``,
    ``"cvxpy"``), imported in :func:`loading_blas`: uiofmu imports scipy and cvxpy through it, where it
    first needs them, so that the command line starts their OpenBLAS with one thread there."""
    module = sys.modules.get(name)
    if module is None:
        with loading_blas():
            module = importlib.import_module(name)
    return module


def _blas(with_scipy: bool):
    """The threadpoolctl controller of the BLAS libraries loaded now (made again when modules were added)."""
    global _controller, _modules
    if with_scipy and not _one_at_load:
        blas_module("scipy.linalg")      # scipy's own OpenBLAS, loaded before the limit so that it covers it
    if _controller is None or len(sys.modules) != _modules:
        from threadpoolctl import ThreadpoolController

        _controller, _modules = ThreadpoolController().select(user_api="blas"), len(sys.modules)
    return _controller


@contextlib.contextmanager
def one_blas_thread(with_scipy: bool = False):
    """Run the block with one BLAS thread in every loaded BLAS library; restore the limits after it.

    Parameters
    ----------
    with_scipy : bool, optional
        Import ``scipy.linalg`` first (the block may use it), so that its OpenBLAS is limited too; not in
        a command of the command line that starts its libraries with one thread (the user set no
        thread variable): there scipy's starts with one thread wherever uiofmu first imports it
        (:func:`blas_module`), and a block that needs no scipy does not import it.

    Nested uses cost about 10 us each. Without :mod:`threadpoolctl` (it is a dependency of uiofmu,
    but a runtime copy inside an FMU has numpy only) the block runs as it is.
    """
    try:
        blas = _blas(with_scipy)
    except ImportError:
        yield
        return
    with blas.limit(limits=1):
        yield


def single_blas_thread(func=None, *, with_scipy: bool = False):
    """Decorate ``func`` to run under :func:`one_blas_thread` (``@single_blas_thread(with_scipy=True)``
    for functions that use scipy)."""
    if func is None:
        return functools.partial(single_blas_thread, with_scipy=with_scipy)

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        with one_blas_thread(with_scipy):
            return func(*args, **kwargs)

    return wrapper
