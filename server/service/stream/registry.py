"""The stream connections open at once, over every transport (the stream port and WebSocket
upgrades on the HTTP port): at most ``stream.max_connections``, shared. When full, a
connection still without a session after 1 s (a client that connected and is not saying HELLO)
is closed, or else the session idle longest, if idle past ``stream.evict_idle_s``, gets GOODBYE
``evicted``, to make room. The drain reaches every connection through it.
"""

from __future__ import annotations

import threading
import time
from typing import TYPE_CHECKING

from sphrender.server.service.config import StreamConfig
from sphrender.server.service.stream.handshake import EVICT_HANDSHAKE_AFTER_S

if TYPE_CHECKING:
    from sphrender.server.service.stream.connection import StreamConnection


class StreamConnections:
    """See the module docstring; `StreamConnection.run` registers itself here."""

    def __init__(self, config: StreamConfig) -> None:
        self._max = config.max_connections
        self._evict_idle_s = config.evict_idle_s
        self._lock = threading.Lock()
        self._connections: set[StreamConnection] = set()
        self._draining = False

    def register(self, connection: StreamConnection) -> bool:
        """Count a connection in, making room as the module docstring says; False when there
        is none. A connection that arrives during the drain is told so at once."""
        with self._lock:
            if self._draining:
                connection.begin_drain()
            if len(self._connections) >= self._max:
                now = time.monotonic()
                waiting = [
                    c
                    for c in self._connections
                    if c.session is None and now - c.connected_at > EVICT_HANDSHAKE_AFTER_S
                ]
                idle = max(self._connections, key=lambda c: c.idle_for(now))
                if waiting:
                    victim = min(waiting, key=lambda c: c.connected_at)
                    victim.evict()
                elif idle.idle_for(now) > self._evict_idle_s:
                    victim = idle
                    victim.evict_idle()
                else:
                    return False
                self._connections.discard(victim)
            self._connections.add(connection)
            return True

    def unregister(self, connection: StreamConnection) -> None:
        with self._lock:
            self._connections.discard(connection)

    def open_connections(self) -> int:
        with self._lock:
            return len(self._connections)

    def drain_connections(self) -> None:
        with self._lock:
            self._draining = True
            connections = list(self._connections)
        for connection in connections:
            connection.begin_drain()
