"""The HTTP listener: the standard library's ``ThreadingHTTPServer`` with a connection cap.

Handlers call `enter_connection` / `leave_connection` around a connection; past the cap a
connection gets an immediate 503 (see `ApiHandler.handle`)."""

from __future__ import annotations

import socket
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer


class SphrenderHttpServer(ThreadingHTTPServer):
    """Threading server with a connection cap; handler threads are daemons (see `serve`)."""

    daemon_threads = True
    allow_reuse_address = True
    request_queue_size = 128

    def __init__(
        self,
        address: tuple[str, int],
        handler: type[BaseHTTPRequestHandler],
        max_connections: int,
    ) -> None:
        if ":" in address[0]:
            self.address_family = socket.AF_INET6
        super().__init__(address, handler)
        self._max_connections = max_connections
        self._connections = 0
        self._lock = threading.Lock()

    def enter_connection(self) -> bool:
        with self._lock:
            if self._connections >= self._max_connections:
                return False
            self._connections += 1
            return True

    def leave_connection(self) -> None:
        with self._lock:
            self._connections -= 1
