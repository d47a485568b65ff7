"""The Dask cluster of a campaign: a LocalCluster of worker processes, or an existing scheduler
whose ``--scheduler`` address is checked and probed with a deadline first."""

from __future__ import annotations

import contextlib
import os
import re
import threading

from ...runtime.errors import UserError

#: Seconds to reach a Dask scheduler, hear its handshake and see a worker.
SCHEDULER_TIMEOUT_S = 10.0


def start_client(workers: int | None, address: str | None):
    """A Dask client: on the scheduler at ``address`` (that :func:`probe_scheduler` has heard), or on
    a new LocalCluster of worker processes."""
    import logging

    from distributed import Client, LocalCluster

    if address is not None:
        try:
            client = Client(address, timeout=f"{SCHEDULER_TIMEOUT_S}s")
        except Exception as exc:  # noqa: BLE001 - whatever the service did, it is not a usable scheduler
            raise SchedulerError(f"--scheduler {address}: {_failure_text(exc)}") from None
        try:
            client.wait_for_workers(1, timeout=SCHEDULER_TIMEOUT_S)
        except Exception:  # noqa: BLE001 - a TimeoutError, or the connection lost meanwhile
            client.close()
            raise SchedulerError(f"--scheduler {address}: no worker joined the scheduler within "
                                 f"{SCHEDULER_TIMEOUT_S:g} s") from None
        return client, None
    n = workers or os.cpu_count() or 1
    from ...threads import loading_blas

    with _workers_ignore_interrupts(), loading_blas():     # the command's BLAS kernel in the workers too
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                               silence_logs=logging.ERROR)
    return Client(cluster), cluster


@contextlib.contextmanager
def _workers_ignore_interrupts():
    """Start worker processes with SIGINT ignored (a disposition a child keeps, and Python keeps at its start):
    Ctrl-C in a terminal reaches the whole process group, and only this process should answer it (it
    cancels the runs and writes the outputs); workers stopped by it printed tracebacks instead. Nothing
    changes off the main thread, where no handler can be set."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, before)


class SchedulerError(UserError):
    """A ``--scheduler`` address that is malformed, or where no Dask scheduler answers in time."""


_HOST_LABEL = re.compile(r"[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?\Z")


def _host_problem(host: str) -> str | None:
    """What is wrong with a host name or IP address (None when nothing is)."""
    import ipaddress

    if host.startswith("[") and host.endswith("]"):
        try:
            ipaddress.IPv6Address(host[1:-1])
        except ValueError:
            return "not an IPv6 address in brackets"
        return None
    if not host:
        return "no host"
    if len(host) > 253:
        return f"a host of {len(host)} characters, more than 253"
    if not all(_HOST_LABEL.match(label) for label in host.removesuffix(".").split(".")):
        return "not a host name (letters, digits and hyphens, in dot-separated labels of 1 to 63) or IP address"
    return None


def _split_address(value: str) -> tuple:
    """``(scheme, host, port)`` of an address (scheme tcp when none is given, port None without one)."""
    scheme, sep, rest = value.partition("://")
    if not sep:
        scheme, rest = "tcp", value
    host, colon, port = rest.rpartition(":")
    return (scheme, host, port) if colon else (scheme, rest, None)


def _address_problem(value) -> str | None:
    """What is wrong with a ``--scheduler`` value (None when nothing is)."""
    if not isinstance(value, str) or not value.strip():
        return "an empty address" if isinstance(value, str) else "not a string"
    scheme, host, port = _split_address(value)
    if scheme != "tcp":
        return f"the protocol {scheme[:20]!r} is not supported"
    if port is None:
        return "no port"
    if not (port.isascii() and port.isdigit() and len(port) <= 5 and 1 <= int(port) <= 65535):
        return f"the port {port[:20]!r} is not a number from 1 to 65535"
    return _host_problem(host)


def scheduler_address(value: str) -> str:
    """The address of ``--scheduler``: ``tcp://HOST:PORT``, or ``HOST:PORT`` (meaning tcp).

    Parameters
    ----------
    value : str
        As given.

    Returns
    -------
    str
        ``tcp://HOST:PORT``.

    Raises
    ------
    SchedulerError
        Naming the value, what is wrong with it and what is accepted.
    """
    problem = _address_problem(value)
    if problem:
        shown = repr(value[:80]) + ("..." if len(value) > 80 else "") if isinstance(value, str) else repr(value)[:80]
        raise SchedulerError(f"--scheduler {shown}: {problem}; expected tcp://HOST:PORT or HOST:PORT (a host "
                             "name or IP address, a port from 1 to 65535)")
    _, host, port = _split_address(value)
    return f"tcp://{host}:{int(port)}"


def _failure_text(exc: BaseException) -> str:
    """An exception in a few words, on one line."""
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}"[:300] if text else type(exc).__name__


async def _identity(address: str, timeout: float):
    """The scheduler's answer to ``identity`` (after the comm handshake), within ``timeout`` seconds."""
    import asyncio

    from distributed.comm import connect

    async def ask():
        comm = await connect(address, timeout=timeout / 2)
        try:
            await comm.write({"op": "identity", "reply": True})
            return await comm.read()
        finally:
            comm.abort()

    return await asyncio.wait_for(ask(), timeout)


def probe_scheduler(address: str, timeout: float | None = None) -> dict:
    """Check that a Dask scheduler answers at ``address``, all within ``timeout`` seconds.

    Connecting, the protocol's handshake and an ``identity`` request run on their own event loop in
    a daemon thread that is given up after the deadline: a service that accepts connections and then
    says nothing, or answers in another protocol (HTTP, whose first bytes read as a frame length
    of exabytes), is refused in bounded time.

    Parameters
    ----------
    address : str
        ``tcp://HOST:PORT`` (:func:`scheduler_address`).
    timeout : float, optional
        Seconds (default :data:`SCHEDULER_TIMEOUT_S`).

    Returns
    -------
    dict
        The scheduler's identity (``type``, ``address``, ``workers``, ...).

    Raises
    ------
    SchedulerError
        One line naming the address and what happened.
    """
    import asyncio

    timeout = SCHEDULER_TIMEOUT_S if timeout is None else timeout
    box: dict = {}

    def work() -> None:
        try:
            box["reply"] = asyncio.run(_identity(address, timeout))
        except BaseException as exc:  # noqa: BLE001 - handed to the caller's thread
            box["error"] = exc

    thread = threading.Thread(target=work, name="uiofmu-scheduler-probe", daemon=True)
    thread.start()
    thread.join(timeout + 1.0)
    error = box.get("error")
    if thread.is_alive() or isinstance(error, TimeoutError):
        raise SchedulerError(f"--scheduler {address}: no answer of a Dask scheduler within {timeout:g} s (the "
                             "service there accepts connections but does not speak Dask's protocol?)")
    if isinstance(error, OSError):
        raise SchedulerError(f"--scheduler {address}: no Dask scheduler reachable there ({_failure_text(error)})")
    if isinstance(error, MemoryError):    # a length prefix of exabytes: the first bytes of another protocol
        raise SchedulerError(f"--scheduler {address}: the service there answers in another protocol than Dask's "
                             "(its first bytes announce a message too large to hold)")
    if error is not None:
        raise SchedulerError(f"--scheduler {address}: the service there does not answer as a Dask scheduler "
                             f"({_failure_text(error)})")
    reply = box["reply"]
    if not isinstance(reply, dict) or reply.get("type") != "Scheduler":
        kind = reply.get("type") if isinstance(reply, dict) else type(reply).__name__
        raise SchedulerError(f"--scheduler {address}: the service there answers, but as a {str(kind)[:40]}, "
                             "not as a Dask scheduler")
    return reply


__all__ = ["SCHEDULER_TIMEOUT_S", "SchedulerError", "probe_scheduler", "scheduler_address", "start_client"]
