"""Socket I/O for stream connections (`connection.py`).

`Channel` reads and writes one connection's socket under deadlines: before a message's first
byte the idle rules apply (nothing started: a drain or an idle timeout may end the connection
there); once a message has started it must be complete by its message deadline, shortened by
a drain to the service's ``drain_read_deadline``, so a client that sent half a message cannot
hold the process's exit. Payloads are read into one preallocated buffer (``recv_into``), or
discarded in small chunks when the frame was refused from its header alone.
"""

from __future__ import annotations

import contextlib
import socket
import time
from collections.abc import Callable

#: Socket poll interval: how quickly a blocked thread notices a drain or a dead peer.
TICK_S = 0.2
_DISCARD_CHUNK = 1 << 16


class Closed(Exception):
    """The connection is over; `reason` says how (metrics label and log field)."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


class Channel:
    """Deadline-bounded reads and writes on one stream socket (module docstring)."""

    def __init__(
        self,
        sock: socket.socket,
        *,
        idle_timeout_s: float,
        write_timeout_s: float,
        dead: Callable[[], bool],
        draining: Callable[[], bool],
        evicted: Callable[[], bool],
        drain_deadline: Callable[[], float | None],
        in_flight: Callable[[], int],
    ) -> None:
        self.sock = sock
        self._idle_timeout_s = idle_timeout_s
        self._write_timeout_s = write_timeout_s
        self._dead = dead
        self._draining = draining
        self._evicted = evicted
        self._drain_deadline = drain_deadline
        self._in_flight = in_flight
        sock.settimeout(TICK_S)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def _wait_limit(self, deadline: float, started: bool, idle_deadline: float | None) -> float:
        """Raise `Closed` when the current wait is over; returns the deadline in force."""
        if self._dead():
            raise Closed("gone")
        now = time.monotonic()
        if idle_deadline is not None and not started:
            if self._draining():
                raise Closed("shutdown")
            if self._evicted() and self._in_flight() == 0:
                raise Closed("evicted")
            if self._in_flight() > 0:
                idle_deadline = now + self._idle_timeout_s  # waiting for answers, not idle
            if now > idle_deadline:
                raise Closed("idle_timeout")
            return idle_deadline
        drain = self._drain_deadline()
        if drain is not None and now > drain:
            raise Closed("shutdown_mid_message")
        if now > deadline:
            raise Closed("slow")
        return deadline

    def recv_into(
        self, buffer: bytearray | memoryview, deadline: float, *, idle_deadline: float | None = None
    ) -> None:
        """Fill `buffer`, or raise `Closed`. `idle_deadline`: this is a message's first read."""
        view = memoryview(buffer).cast("B")
        got = 0
        first = idle_deadline is not None
        while got < len(view):
            if first and not got:
                assert idle_deadline is not None
                idle_deadline = self._wait_limit(deadline, False, idle_deadline)
            else:
                self._wait_limit(deadline, True, None)
            try:
                n = self.sock.recv_into(view[got:], min(len(view) - got, 1 << 20))
            except TimeoutError:
                continue
            except OSError:
                raise Closed("gone") from None
            if not n:
                raise Closed("eof" if first and not got else "vanished")
            got += n

    def recv(self, n: int, deadline: float, *, idle_deadline: float | None = None) -> bytearray:
        buffer = bytearray(n)
        self.recv_into(buffer, deadline, idle_deadline=idle_deadline)
        return buffer

    def discard(self, n: int, deadline: float) -> None:
        """Read and drop `n` bytes (a refused frame's payload) without allocating them."""
        scratch = bytearray(min(n, _DISCARD_CHUNK))
        while n:
            chunk = memoryview(scratch)[: min(n, len(scratch))]
            self.recv_into(chunk, deadline)
            n -= len(chunk)

    # -- how the connection ends (a WebSocket channel also sends its Close frame) ----------------

    def close_for_error(self, code: str, message: str) -> None:
        """After a fatal ERROR: nothing more to say on a raw socket (the ERROR said it)."""

    def end_orderly(self, reason: str, seconds: float) -> None:
        """After GOODBYE: let the client read everything, then close (`linger`)."""
        linger(self.sock, seconds)

    def shutdown(self) -> None:
        """Close both directions; the peer sees end of file."""
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)

    def send_all(self, data: bytes) -> None:
        view = memoryview(data)
        sent = 0
        deadline = time.monotonic() + self._write_timeout_s
        while sent < len(view):
            if time.monotonic() > deadline:
                raise Closed("write_timeout")
            try:
                sent += self.sock.send(view[sent:])
            except TimeoutError:
                continue
            except OSError:
                raise Closed("gone") from None


def linger(sock: socket.socket, seconds: float) -> None:
    """After GOODBYE: half-close, then discard what the client still sends until it closes (at
    most `seconds`). Closing with unread bytes makes the kernel send RST, which can destroy the
    answers and GOODBYE still on their way (or in a load balancer's buffers)."""
    try:
        sock.shutdown(socket.SHUT_WR)
    except OSError:
        return
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            if not sock.recv(1 << 16):
                return
        except TimeoutError:
            continue
        except OSError:
            return
