"""The HTTP listener: the standard library's ``ThreadingHTTPServer`` with a connection cap that
slow clients cannot exhaust, and a socket reader with whole-request deadlines.

Deadlines (`DeadlineReader`, the handler's ``rfile``): between requests a keep-alive connection
waits at most ``http.read_timeout_s`` for the next request's first byte; from that byte the
request line and every header must arrive within ``http.header_timeout_s``; a body within
``http.body_timeout_s``. Each is a deadline for the whole phase, not a per-read timeout, so one
byte a second buys nothing. During a drain an idle connection ends at once and a half-read
request gets until the service's ``drain_read_deadline``.

The cap (`SphrenderHttpServer.enter_connection`): at most ``http.max_connections`` connections.
When full, the connection that has waited longest *for its request line or headers* (an idle
keep-alive connection, or a slowloris client) is closed to make room, so clients that are being
served are never pushed out by clients that are not sending. Only when every connection is busy
with a request does a newcomer get one of ``http.health_connections`` extra slots, which answer
``GET /healthz``, ``/readyz`` and ``/metrics`` only; past those it gets 503 at once.
"""

from __future__ import annotations

import contextlib
import io
import socket
import threading
import time
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any, Literal

#: How often a blocked read re-checks its deadline and the drain (seconds).
_TICK_S = 0.5
#: A connection must have been waiting at least this long for its request to be evicted.
_EVICT_AFTER_S = 0.25

Phase = Literal["idle", "head", "handling", "body"]


class DeadlineReader(io.RawIOBase):
    """Raw socket reads under the current phase's deadline (module docstring)."""

    def __init__(
        self,
        sock: socket.socket,
        *,
        idle_timeout_s: float,
        write_timeout_s: float,
        drain_deadline: Callable[[], float | None],
    ) -> None:
        self._sock = sock
        self._idle_timeout_s = idle_timeout_s
        self._write_timeout_s = write_timeout_s
        self._drain_deadline = drain_deadline
        self._head_timeout_s = idle_timeout_s
        self.phase: Phase = "idle"
        self.waiting_since = time.monotonic()
        self._deadline: float | None = None
        self.evicted = False
        self.detached = False

    def readable(self) -> bool:
        return True

    def expect_request(self, head_timeout_s: float) -> None:
        self.phase = "idle"
        self.waiting_since = time.monotonic()
        self._deadline = self.waiting_since + self._idle_timeout_s
        self._head_timeout_s = head_timeout_s

    def end_head(self) -> None:
        self.phase = "handling"
        self._deadline = None

    def begin_body(self, timeout_s: float) -> None:
        self.phase = "body"
        self._deadline = time.monotonic() + timeout_s

    def detach(self) -> None:
        """The socket now belongs to another protocol (a WebSocket upgrade): reads report
        nothing more, so the buffered reader hands over only what it already holds."""
        self.detached = True

    def evict(self) -> None:
        """Close the reading side: the handler's pending read sees end of file."""
        self.evicted = True
        with contextlib.suppress(OSError):
            self._sock.shutdown(socket.SHUT_RD)

    def readinto(self, buffer: Any) -> int | None:
        if self.detached:
            return None
        while True:
            if self.evicted:
                return 0
            now = time.monotonic()
            deadline = self._deadline
            drain = self._drain_deadline()
            if drain is not None:
                if self.phase == "idle":
                    return 0  # draining: an idle keep-alive connection just ends
                deadline = drain if deadline is None else min(deadline, drain)
            if deadline is not None and now >= deadline:
                raise TimeoutError(f"HTTP {self.phase} deadline passed")
            wait = _TICK_S if deadline is None else max(0.001, min(_TICK_S, deadline - now))
            self._sock.settimeout(wait)
            try:
                n = self._sock.recv_into(buffer)
            except TimeoutError:
                continue
            finally:
                self._sock.settimeout(self._write_timeout_s)  # writes use the socket timeout
            if n and self.phase == "idle":
                self.phase = "head"
                self._deadline = time.monotonic() + self._head_timeout_s
            return n


ConnectionMode = Literal["normal", "health"]


class SphrenderHttpServer(ThreadingHTTPServer):
    """Threading server with the cap described above; handler threads are daemons."""

    daemon_threads = True
    allow_reuse_address = True
    request_queue_size = 128

    def __init__(
        self,
        address: tuple[str, int],
        handler: type[BaseHTTPRequestHandler],
        max_connections: int,
        health_connections: int = 0,
    ) -> None:
        if ":" in address[0]:
            self.address_family = socket.AF_INET6
        super().__init__(address, handler)
        self._max_connections = max_connections
        self._health_connections = health_connections
        self._normal: dict[int, DeadlineReader] = {}
        self._health = 0
        self._lock = threading.Lock()
        self.evictions = 0

    def enter_connection(self, key: int, reader: DeadlineReader) -> ConnectionMode | None:
        with self._lock:
            if len(self._normal) >= self._max_connections:
                victim = self._evictable()
                if victim is not None:
                    self._normal.pop(victim).evict()  # its thread sees EOF and ends
                    self.evictions += 1
            if len(self._normal) < self._max_connections:
                self._normal[key] = reader
                return "normal"
            if self._health < self._health_connections:
                self._health += 1
                return "health"
            return None

    def _evictable(self) -> int | None:
        """The normal connection waiting longest for its request (idle or slow head)."""
        now = time.monotonic()
        best: tuple[float, int] | None = None
        for key, reader in self._normal.items():
            waiting = reader.phase in ("idle", "head")
            older = best is None or reader.waiting_since < best[0]
            if waiting and older and now - reader.waiting_since > _EVICT_AFTER_S:
                best = (reader.waiting_since, key)
        return None if best is None else best[1]

    def leave_connection(self, key: int, mode: ConnectionMode) -> None:
        with self._lock:
            if mode == "health":
                self._health -= 1
            else:
                self._normal.pop(key, None)

    def open_connections(self) -> int:
        with self._lock:
            return len(self._normal) + self._health
