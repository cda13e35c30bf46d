"""Ray, the optional runtime of ``frictiongym sweep`` and ``frictiongym tune --ray``.

:func:`ray_session` starts a local Ray for one command (and shuts it down after) or connects
to an existing cluster; :func:`ordered_map` runs a function over items as Ray tasks. Ray is
imported inside these functions only: it is an optional extra (``frictiongym[cluster]``), and
``frictiongym --help`` and the other commands never load it.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import socket
import threading
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

#: The one line a command prints where Ray cannot be imported.
INSTALL_HINT = 'pip install "frictiongym[cluster]"'
#: Seconds to wait for a cluster's address to accept a connection before giving up.
CONNECT_TIMEOUT = 5.0


class ClusterError(Exception):
    """Ray is missing or the cluster cannot be reached; the message says what to do."""


def import_ray(command: str) -> Any:
    """Return the ``ray`` module, or raise :class:`ClusterError` naming the extra to install."""
    try:
        import ray
    except ImportError:
        raise ClusterError(f"{command} needs Ray: {INSTALL_HINT}") from None
    return ray


def _host_and_port(address: str) -> tuple[str, int] | None:
    """Return the host and port of ``HOST:PORT`` or ``ray://HOST:PORT`` (None for ``auto``)."""
    bare = address.removeprefix("ray://")
    host, sep, port = bare.rpartition(":")
    if not sep or not port.isdigit():
        return None
    return host.strip("[]"), int(port)


def check_reachable(address: str, option: str = "--address") -> None:
    """Raise :class:`ClusterError` unless ``address`` accepts a TCP connection.

    ``ray.init`` retries an unreachable address for minutes; this answers in seconds.
    """
    target = _host_and_port(address)
    if target is None:
        if address != "auto":
            raise ClusterError(
                f"{option} {address!r} is not HOST:PORT, ray://HOST:PORT or auto; give the "
                "address `ray start --head` printed (e.g. 10.0.0.5:6379)"
            )
        return
    try:
        with socket.create_connection(target, timeout=CONNECT_TIMEOUT):
            pass
    except OSError as error:
        raise ClusterError(
            f"cannot reach a Ray cluster at {option} {address} ({error.strerror or error}); "
            "start one there with `ray start --head`, or drop the address for a local Ray"
        ) from None


def _package_root() -> str:
    """Return the folder that holds the ``frictiongym`` package this process imported."""
    return str(Path(__file__).resolve().parent.parent)


def _termination_handlers() -> dict[int, Any]:
    """Return the Python handlers of SIGTERM and SIGHUP (none outside the main thread)."""
    if threading.current_thread() is not threading.main_thread():
        return {}
    numbers = [getattr(signal, name, None) for name in ("SIGTERM", "SIGHUP")]
    return {n: signal.getsignal(n) for n in numbers if n is not None}


@contextlib.contextmanager
def ray_session(
    command: str,
    address: str | None = None,
    runtime_env: dict[str, Any] | None = None,
    option: str = "--address",
) -> Iterator[Any]:
    """Yield ``ray`` connected to a cluster: a local one started here, or ``address``.

    A local Ray uses every core of this machine, and its workers import the same
    ``frictiongym`` as this process (its folder leads their ``PYTHONPATH``). A cluster's
    workers need the package installed, or shipped with ``runtime_env`` (docs/cluster.md).
    Ray started here is shut down after, and a Ray already initialised in this process
    (a test's, a notebook's) is used as it is and left running. ``option`` names the
    address's option in messages.

    Raises
    ------
    ClusterError
        Without Ray, or when ``address`` cannot be reached.
    """
    ray = import_ray(command)
    if ray.is_initialized():
        yield ray
        return
    if address is not None:
        check_reachable(address, option)
    env = dict(runtime_env or {})
    if address is None:
        paths = [_package_root(), os.environ.get("PYTHONPATH", "")]
        variables = {"PYTHONPATH": os.pathsep.join(p for p in paths if p)}
        env["env_vars"] = {**variables, **env.get("env_vars", {})}
    handlers = _termination_handlers()
    try:
        ray.init(
            address=address,
            runtime_env=env or None,
            include_dashboard=False,
            logging_level=logging.WARNING,
            log_to_driver=False,  # the command reports each trial; worker logs stay in Ray's
            configure_logging=True,
        )
    except (ConnectionError, RuntimeError, ValueError) as error:
        where = f"at {address}" if address else "locally"
        first = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise ClusterError(f"cannot start or join Ray {where}: {first}") from None
    for number, handler in handlers.items():  # ray.init takes SIGTERM: give it back, so a
        signal.signal(number, handler)  # command ends on it as on a Ctrl-C (frictiongym.cli)
    try:
        yield ray
    finally:
        ray.shutdown()


def ordered_map(
    ray: Any, function: Callable[..., Any], items: Sequence[Any], *shared: Any
) -> Iterator[Any]:
    """Yield ``function(item, *shared)`` for each item, in order, computed as Ray tasks.

    All tasks are submitted at once and run as the cluster's CPUs allow (one CPU each);
    ``shared`` is put in Ray's object store once for all of them. Leaving early (an error,
    a Ctrl-C) cancels the tasks not yet collected.
    """
    remote = ray.remote(num_cpus=1)(function)
    refs = [ray.put(value) for value in shared]
    pending = [remote.remote(item, *refs) for item in items]
    collected = 0
    try:
        for ref in pending:
            yield ray.get(ref)
            collected += 1
    finally:
        for ref in pending[collected:]:
            with contextlib.suppress(Exception):  # a task that ended meanwhile
                ray.cancel(ref, force=True)
