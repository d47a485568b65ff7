"""One BLAS thread for uiofmu's small dense linear algebra, inside uiofmu's own calls only.

Every matrix uiofmu multiplies, factors or exponentiates is small (n of a few to a few dozen): a
second BLAS thread there costs more in start-up and spinning than it saves, and on a busy machine
OpenBLAS's threads make a 4x4 ``scipy.linalg.expm`` cost 6-10 ms of CPU against 0.01 ms. The public
entry points (:func:`uiofmu.check`, :func:`uiofmu.design`, :func:`uiofmu.verify`, the co-simulation
master, a campaign's runs, the command line) run under :func:`one_blas_thread`; the previous limits
come back when they return, so the user's own numpy code keeps whatever threading it had. No
environment variable is set.

numpy and scipy each load their own OpenBLAS: the limit covers every BLAS library loaded when it
is entered (the design and the re-check, which use scipy, import it first; the master imports it
only where it needs it), and :mod:`threadpoolctl` reads the loaded libraries again only
when modules were imported since it last read them.
"""

from __future__ import annotations

import contextlib
import functools
import sys

_controller = None
_modules = 0


def _blas(with_scipy: bool):
    """The threadpoolctl controller of the BLAS libraries loaded now (made again when modules were added)."""
    global _controller, _modules
    if with_scipy and "scipy.linalg" not in sys.modules:
        import scipy.linalg  # noqa: F401 - scipy's own OpenBLAS, loaded before the limit so that it covers it
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
        Import ``scipy.linalg`` first (the block uses it), so that its OpenBLAS is limited too.

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
