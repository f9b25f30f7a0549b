"""The stream listener: a threaded TCP server with one `StreamConnection` per client, counted
in the `StreamConnections` it shares with the WebSocket route (``stream.max_connections``).
"""

from __future__ import annotations

import socket
import socketserver
from typing import ClassVar

from sphrender.core.errors import InputError
from sphrender.server.service.facade import ServiceFacade
from sphrender.server.service.stream.connection import StreamConnection
from sphrender.server.service.stream.registry import StreamConnections


class StreamHandler(socketserver.BaseRequestHandler):
    service: ClassVar[ServiceFacade]
    table: ClassVar[StreamConnections]

    def handle(self) -> None:
        StreamConnection(self.request, self.client_address, self.service, self.table).run()


class StreamServer(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True
    request_queue_size = 128

    def __init__(
        self, address: tuple[str, int], service: ServiceFacade, connections: StreamConnections
    ) -> None:
        if ":" in address[0]:
            self.address_family = socket.AF_INET6
        handler = type(
            "BoundStreamHandler", (StreamHandler,), {"service": service, "table": connections}
        )
        super().__init__(address, handler)
        self.connections = connections

    def open_connections(self) -> int:
        return self.connections.open_connections()

    def drain_connections(self) -> None:
        self.connections.drain_connections()


def make_stream_server(service: ServiceFacade, connections: StreamConnections) -> StreamServer:
    host, port = service.config.http.host, service.config.stream.port
    try:
        return StreamServer((host, port), service, connections)
    except OSError as exc:
        raise InputError(
            "stream.port", f"cannot listen on {host}:{port}: {exc.strerror or exc}"
        ) from None
