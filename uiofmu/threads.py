"""One BLAS thread for uiofmu's small dense linear algebra, inside uiofmu's own calls only; one BLAS
kernel for the command line.

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

The command line's BLAS libraries load on one kernel too (:func:`reproducible_kernel`): OpenBLAS picks the
kernels of the CPU it runs on, and kernels round sums in different orders (with and without fused
multiply-adds, in other blocks), so the same design solved on two machines followed two interior-point paths
apart in their last digits, and next to the edge of feasibility CLARABEL converged on one and not on the
other (``docs/tolerances.md``). The command line loads them with ``OPENBLAS_CORETYPE`` set to the oldest kernel
of the machine's architecture, around the same imports, and starts a campaign's Dask workers with it (their
runs step observers with numpy): its answers do not depend on which CPU of that architecture runs it, as
Intel's MKL does with ``MKL_CBWR``. The kernels are those of OpenBLAS's own build (the wheels of numpy and
scipy), as fast at uiofmu's sizes (``benchmarks/blas_kernel.py``). A user who set ``OPENBLAS_CORETYPE`` keeps the
kernel chosen (``make test-blas`` sets each in turn), and the library (``import uiofmu``), or a program
that imported numpy before it calls :func:`uiofmu.cli.main`, runs on the kernel its numpy loaded with.
"""

from __future__ import annotations

import contextlib
import functools
import importlib
import os
import platform
import sys

#: The environment variables OpenBLAS reads, when it loads, for the number of threads it starts.
THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS")

#: The OpenBLAS kernel the command line loads its BLAS libraries with, by machine architecture
#: (``platform.machine()``): the oldest one OpenBLAS's builds for it have, which every CPU of it runs.
#: OpenBLAS reports Prescott's as ``Katmai`` (its builds hold one kernel for both).
REPRODUCIBLE_KERNELS = {"x86_64": "Prescott", "AMD64": "Prescott", "aarch64": "ARMV8", "arm64": "ARMV8"}

_controller = None
_modules = 0
_at_load: dict = {}             # set by the command line: the variables its BLAS libraries load with


def reproducible_kernel() -> str | None:
    """The kernel :func:`start_with_one_thread` loads the command line's BLAS libraries with: that of
    :data:`REPRODUCIBLE_KERNELS` for this machine, or None where the user set ``OPENBLAS_CORETYPE`` (theirs
    is kept), the machine has none there, or numpy is loaded already (a program that calls
    :func:`uiofmu.cli.main` after its own imports: the kernel numpy loaded with is kept, for the command's
    other libraries and its workers alike, so that a replay in the process reproduces their runs bit for bit)."""
    if os.environ.get("OPENBLAS_CORETYPE") or "numpy" in sys.modules:
        return None
    return REPRODUCIBLE_KERNELS.get(platform.machine())


@contextlib.contextmanager
def start_with_one_thread():
    """Run the block (a command of the command line) with the BLAS libraries it loads started with one
    thread and on :func:`reproducible_kernel`: numpy's now, scipy's and cvxpy's where uiofmu first imports them
    (:func:`blas_module`), a campaign's Dask workers where they start. The number of threads is the user's
    where the user set one of :data:`THREAD_VARIABLES`, the kernel where the user set ``OPENBLAS_CORETYPE`` or
    numpy was loaded before the block (the process keeps one kernel).
    After the block, uiofmu imports them as a library does again (a program that calls
    :func:`uiofmu.cli.main` goes on as it was)."""
    global _at_load
    kernel = reproducible_kernel()
    _at_load = {**({} if any(os.environ.get(name) for name in THREAD_VARIABLES) else {"OPENBLAS_NUM_THREADS": "1"}),
                **({} if kernel is None else {"OPENBLAS_CORETYPE": kernel})}
    try:
        with loading_blas():
            import numpy  # noqa: F401 - numpy's OpenBLAS, started with one thread on one kernel
        yield
    finally:
        _at_load = {}


@contextlib.contextmanager
def loading_blas():
    """Import BLAS libraries (or start processes that do) in the block with the variables
    :func:`start_with_one_thread` chose (``OPENBLAS_NUM_THREADS=1``, ``OPENBLAS_CORETYPE``), then restore the
    environment.

    Only inside :func:`start_with_one_thread`; otherwise the block runs as it is. OpenBLAS reads the
    variables once, when it loads: a library already loaded keeps its threads and its kernel, and the
    processes started after the block do not see the variables.
    """
    chosen = {name: value for name, value in _at_load.items() if not os.environ.get(name)}
    before = {name: os.environ.get(name) for name in chosen}    # None, or "" (which OpenBLAS ignores)
    os.environ.update(chosen)
    try:
        yield
    finally:
        for name, value in before.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def blas_module(name: str):
    """The module ``name``, one whose import loads a BLAS library (``"scipy.linalg"``, ``"scipy.signal"``,
    ``"cvxpy"``), imported in :func:`loading_blas`: uiofmu imports scipy and cvxpy through it, where it
    first needs them, so that the command line starts their OpenBLAS with one thread there."""
    module = sys.modules.get(name)
    if module is None:
        with loading_blas():
            module = importlib.import_module(name)
    return module


def blas_libraries() -> list[dict]:
    """numpy's and scipy's BLAS libraries as this process loaded them (importing them first where needed, as
    :func:`blas_module` does): for each, ``library`` (the file's name), ``version`` and ``kernel`` (OpenBLAS's
    name of the kernel it runs, ``Katmai`` for Prescott's), ``threads``, as threadpoolctl reads them."""
    blas_module("numpy")
    blas_module("scipy.linalg")
    from threadpoolctl import threadpool_info

    return [{"library": os.path.basename(info["filepath"]), "version": info.get("version"),
             "kernel": info.get("architecture"), "threads": info.get("num_threads")}
            for info in threadpool_info() if info.get("user_api") == "blas"]


def _blas(with_scipy: bool):
    """The threadpoolctl controller of the BLAS libraries loaded now (made again when modules were added)."""
    global _controller, _modules
    if with_scipy and "OPENBLAS_NUM_THREADS" not in _at_load:
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
