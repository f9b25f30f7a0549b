"""The stream listener: a threaded TCP server with one `StreamConnection` per client, at most
``stream.max_connections`` at once (a full server closes a connection stuck before its HELLO,
or else the session idle longest past ``stream.evict_idle_s``, to make room).
"""

from __future__ import annotations

import socket
import socketserver
import threading
import time
from typing import ClassVar, cast

from sphrender.core.errors import InputError
from sphrender.server.service.facade import ServiceFacade
from sphrender.server.service.stream.connection import StreamConnection
from sphrender.server.service.stream.handshake import EVICT_HANDSHAKE_AFTER_S


class StreamHandler(socketserver.BaseRequestHandler):
    service: ClassVar[ServiceFacade]

    def handle(self) -> None:
        server = cast(StreamServer, self.server)
        StreamConnection(self.request, self.client_address, self.service, server).run()


class StreamServer(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True
    request_queue_size = 128

    def __init__(self, address: tuple[str, int], service: ServiceFacade) -> None:
        if ":" in address[0]:
            self.address_family = socket.AF_INET6
        handler = type("BoundStreamHandler", (StreamHandler,), {"service": service})
        super().__init__(address, handler)
        self._max = service.config.stream.max_connections
        self._evict_idle_s = service.config.stream.evict_idle_s
        self._lock = threading.Lock()
        self._connections: set[StreamConnection] = set()

    def register(self, connection: StreamConnection) -> bool:
        """Count a connection in; when full, make room: the oldest one still without a session
        after 1 s (a client that connected and is not saying HELLO) is closed, or else the
        session idle longest, if idle for more than ``stream.evict_idle_s``, gets GOODBYE
        ``evicted``. Returns False when there is no room."""
        with self._lock:
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
            connections = list(self._connections)
        for connection in connections:
            connection.begin_drain()


def make_stream_server(service: ServiceFacade) -> StreamServer:
    host, port = service.config.http.host, service.config.stream.port
    try:
        return StreamServer((host, port), service)
    except OSError as exc:
        raise InputError(
            "stream.port", f"cannot listen on {host}:{port}: {exc.strerror or exc}"
        ) from None
