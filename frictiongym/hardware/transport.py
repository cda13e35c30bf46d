"""The emulator's side of a link: a pseudo-terminal or a TCP server, and the faults it injects.

Both links are driven from one thread with ``select``: :meth:`Link.fds` names the descriptors
to wait on, :meth:`Link.read` returns what arrived (never blocks), :meth:`Link.write` sends what
it can and keeps the rest in a bounded buffer (a device's UART drops what nobody reads).

* :class:`PtyLink`: ``os.openpty()`` with the master in raw mode and non-blocking; the host
  opens the slave path (``os.ttyname``) with pyserial. While no host has the slave open the
  master reads fail with ``EIO``: the link waits and retries.
* :class:`TcpLink`: one client at a time (``TCP_NODELAY``), back to ``accept`` when it leaves;
  the host connects with pyserial's ``socket://HOST:PORT``. A second host that connects while
  one is served is closed at once, so it fails fast and says why instead of waiting for a
  handshake that never comes.
"""

from __future__ import annotations

import errno
import os
import socket
import time
import tty
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from frictiongym._validation import real_number

#: Bytes read per call (a few hundred frames).
READ_SIZE = 4096
#: Unsent bytes kept when the host does not read (the pty or socket buffer is full); beyond
#: this the oldest are dropped, as a UART's output would be lost (about 50 states).
OUT_LIMIT = 1024
#: How long a pty waits before retrying a master that reported EIO (no host), s.
HANGUP_RETRY = 0.02


@dataclass(frozen=True)
class Faults:
    """Faults the emulator injects on its link (all draws from the emulator's seed).

    Parameters
    ----------
    drop : float, default 0.0
        Probability of dropping each outgoing byte.
    corrupt : float, default 0.0
        Probability of flipping one random bit of an outgoing frame.
    delay : float, default 0.0
        Constant extra latency before a frame is written, s.
    jitter : float, default 0.0
        Random extra latency, uniform in ``[0, jitter]`` s (frames keep their order).
    unplug_after : float, optional
        Close the link after this many seconds of device time.
    freeze_after : float, optional
        Stop sending (link kept open) after this many seconds of device time.
    """

    drop: float = 0.0
    corrupt: float = 0.0
    delay: float = 0.0
    jitter: float = 0.0
    unplug_after: float | None = None
    freeze_after: float | None = None

    def __post_init__(self) -> None:
        for name in ("drop", "corrupt"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and 0.0 <= value <= 1.0):
                raise ValueError(f"{name} is a probability and must lie in [0, 1], got {value!r}")
        for name in ("delay", "jitter", "unplug_after", "freeze_after"):
            if getattr(self, name) is not None or not name.endswith("_after"):  # None: never
                real_number(name, getattr(self, name), ">= 0", unit=" s")

    def mangle(self, frame: bytes, rng: np.random.Generator) -> bytes:
        """Return ``frame`` with a bit flipped (``corrupt``) and bytes dropped (``drop``)."""
        if self.corrupt and rng.random() < self.corrupt:
            bit = int(rng.integers(len(frame) * 8))
            mangled = bytearray(frame)
            mangled[bit // 8] ^= 1 << (bit % 8)
            frame = bytes(mangled)
        if self.drop:
            keep = rng.random(len(frame)) >= self.drop
            frame = np.frombuffer(frame, np.uint8)[keep].tobytes()
        return frame

    @property
    def delayed(self) -> bool:
        """Whether frames wait before they are written."""
        return self.delay > 0.0 or self.jitter > 0.0


class Link(ABC):
    """One end of a byte link, used from a single thread."""

    url: str
    dropped: int = 0  #: bytes dropped because the host did not read them

    def __init__(self) -> None:
        self._out = bytearray()

    @property
    def pending(self) -> bool:
        """Whether input is already waiting inside the link (read it without waiting)."""
        return False

    @abstractmethod
    def fds(self) -> list[int]:
        """Descriptors to wait on for input now (may be empty)."""

    @abstractmethod
    def read(self, ready: list[int]) -> bytes:
        """Return the bytes available (``ready``: the descriptors ``select`` reported)."""

    @abstractmethod
    def _send(self, data: bytes) -> int:
        """Send what the link takes now; return the count (0 if it would block)."""

    @abstractmethod
    def close(self) -> None:
        """Close the link (the host's reads fail); idempotent."""

    def write(self, data: bytes) -> None:
        """Queue ``data`` and send what the link takes now."""
        self._out += data
        if len(self._out) > OUT_LIMIT:
            extra = len(self._out) - OUT_LIMIT
            del self._out[:extra]
            self.dropped += extra
        self.flush()

    def flush(self) -> None:
        """Send what the link takes of the queued bytes."""
        if self._out:
            sent = self._send(bytes(self._out))
            del self._out[:sent]


class PtyLink(Link):
    """A pseudo-terminal: the emulator holds the master, the host opens :attr:`url`.

    While no host has the slave open, the master's reads fail with ``EIO``: the link then
    drops what it would send (pyserial flushes a port's input when it opens it anyway) and
    probes the master again every ``HANGUP_RETRY`` s.
    """

    def __init__(self) -> None:
        super().__init__()
        master, slave = os.openpty()
        tty.setraw(master)
        os.set_blocking(master, False)
        self.url = os.ttyname(slave)
        os.close(slave)  # the host opens it by name
        self._master: int | None = master
        self._retry_at = 0.0
        self._inbox = b""
        self.present = False  #: whether a host has the port open (as last seen)

    def _read_master(self) -> bytes:
        """Read the master; note whether a host is there (EIO: none)."""
        if self._master is None:
            return b""
        try:
            data = os.read(self._master, READ_SIZE)
        except BlockingIOError:
            self.present = True
            return b""
        except OSError as exc:
            if exc.errno != errno.EIO:
                raise
            self.present = False
            self._retry_at = time.monotonic() + HANGUP_RETRY
            return b""
        self.present = True
        return data

    @property
    def pending(self) -> bool:
        """Whether a probe read input that :meth:`read` has not returned yet."""
        return bool(self._inbox)

    def fds(self) -> list[int]:
        """Return the master, unless it is waiting out a hangup."""
        if self._master is None or (not self.present and time.monotonic() < self._retry_at):
            return []
        return [self._master]

    def read(self, ready: list[int]) -> bytes:
        """Read the master (``b""`` without a host)."""
        data, self._inbox = self._inbox, b""
        if self.present or time.monotonic() >= self._retry_at:
            data += self._read_master()
        return data

    def _send(self, data: bytes) -> int:
        if not self.present and self._master is not None and time.monotonic() >= self._retry_at:
            self._inbox += self._read_master()  # probe: has a host opened the port?
        if self._master is None or not self.present:
            self.dropped += len(data)
            return len(data)
        try:
            return os.write(self._master, data)
        except BlockingIOError:
            return 0
        except OSError as exc:
            if exc.errno != errno.EIO:
                raise
            self.present = False
            self.dropped += len(data)
            return len(data)

    def close(self) -> None:
        """Close the master: the slave path goes away and the host's reads fail."""
        if self._master is not None:
            os.close(self._master)
            self._master = None


class TcpLink(Link):
    """A TCP server for one client at a time; :attr:`url` is pyserial's ``socket://`` URL."""

    def __init__(self, host: str = "127.0.0.1", port: int = 0) -> None:
        super().__init__()
        server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            server.bind((host, port))
            server.listen(1)
        except OSError:
            server.close()
            raise
        server.setblocking(False)
        self._server: socket.socket | None = server
        self._client: socket.socket | None = None
        bound_host, bound_port = server.getsockname()[:2]
        self.url = f"socket://{bound_host}:{bound_port}"

    def fds(self) -> list[int]:
        """Return the client's socket and the server's (a newcomer is refused at once)."""
        fds = [] if self._server is None else [self._server.fileno()]
        if self._client is not None:
            fds.append(self._client.fileno())
        return fds

    def _refuse_newcomer(self) -> None:
        """Close a connection waiting while a host is served (it reads EOF at once)."""
        assert self._server is not None
        try:
            newcomer, _ = self._server.accept()
        except (BlockingIOError, InterruptedError):
            return
        newcomer.close()

    def _drop_client(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None
        self._out.clear()  # queued for the host that left

    def read(self, ready: list[int]) -> bytes:
        """Accept a waiting host, or read the connected one (refusing a second one)."""
        if self._client is not None and self._server is not None:
            if self._server.fileno() in ready:
                self._refuse_newcomer()
            if self._client.fileno() not in ready:
                return b""
        if self._client is None:
            if self._server is None:
                return b""
            try:
                client, _ = self._server.accept()
            except (BlockingIOError, InterruptedError):
                return b""
            client.setblocking(False)
            client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._client = client
            return b""
        try:
            data = self._client.recv(READ_SIZE)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError:
            self._drop_client()
            return b""
        if not data:  # the host closed: back to accept()
            self._drop_client()
        return data

    def _send(self, data: bytes) -> int:
        if self._client is None:
            self.dropped += len(data)
            return len(data)
        try:
            return self._client.send(data)
        except (BlockingIOError, InterruptedError):
            return 0
        except OSError:
            self._drop_client()
            self.dropped += len(data)
            return len(data)

    def close(self) -> None:
        """Close the client and the server: the host's reads fail, nobody can reconnect."""
        self._drop_client()
        if self._server is not None:
            self._server.close()
            self._server = None


__all__ = ["Faults", "Link", "PtyLink", "TcpLink"]
