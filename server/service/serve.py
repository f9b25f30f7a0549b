"""`serve`: the service with its listeners, until SIGTERM or SIGINT, then the drain.

The drain: the listeners close, stream connections stop reading and answer what they
accepted, HTTP requests in progress finish, the render thread empties the queue, releases GL,
and the process exits 0 (or 1 after ``drain_timeout_s``).
"""

from __future__ import annotations

import json
import logging
import signal
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

from sphrender.server.service.app import RenderService, package_version
from sphrender.server.service.config import ServerConfig, check_bind_policy
from sphrender.server.service.heap import HeapTrimmer, configure_malloc
from sphrender.server.service.http.api import make_http_server
from sphrender.server.service.http.listener import SphrenderHttpServer
from sphrender.server.service.logs import configure_logging
from sphrender.server.service.stream.listener import StreamServer, make_stream_server
from sphrender.server.service.stream.registry import StreamConnections

log = logging.getLogger("sphrender.service")

__all__ = ["Listeners", "serve"]


class Listeners:
    """The service's listeners and background threads: start them, and drain them."""

    def __init__(self, service: RenderService) -> None:
        self.service = service
        self.http_server: SphrenderHttpServer | None = None
        self.stream_server: StreamServer | None = None
        #: Stream connections over both transports (the stream port and WebSocket upgrades).
        self.streams = StreamConnections(service.config.stream)
        self._threads: list[threading.Thread] = []
        service.metrics.transport.open_connections.set_callback(
            lambda: [((), float(self.streams.open_connections()))]
        )

    # -- start / stop ---------------------------------------------------------------------------

    def start(self) -> None:
        """Start the render thread (waits until GL is up and warm), then the listeners."""
        service = self.service
        service.worker.start()
        service.worker.ready.wait()
        if service.worker.startup_error is not None:
            raise service.worker.startup_error
        service.metrics.build_info.set(1, package_version("sphrender"), service.worker.gl_renderer)
        try:
            self.http_server = http_server = make_http_server(service, self.streams)
            if service.config.stream.enabled:
                self.stream_server = make_stream_server(service, self.streams)
        except BaseException:
            service.worker.kill()
            raise
        self._spawn("sphrender-http", http_server.serve_forever)
        if self.stream_server is not None:
            self._spawn("sphrender-stream", self.stream_server.serve_forever)
            service.stream_port = self.stream_port
        self._spawn("sphrender-reaper", self._reap_sessions)

    def _spawn(self, name: str, target: Callable[[], Any]) -> None:
        thread = threading.Thread(target=target, name=name, daemon=True)
        thread.start()
        self._threads.append(thread)

    @property
    def http_port(self) -> int:
        assert self.http_server is not None, "not started"
        return int(self.http_server.server_address[1])

    @property
    def stream_port(self) -> int | None:
        return None if self.stream_server is None else int(self.stream_server.server_address[1])

    def stop(self) -> bool:
        """Drain and stop; returns True when everything finished within the drain timeout.

        With ``drain_grace_s`` > 0 the service first only turns not ready (/readyz 503
        "draining") and keeps accepting frames for that long, so a load balancer stops sending
        before the listeners close; then the drain proper (``drain_timeout_s``)."""
        service = self.service
        grace = service.config.lifecycle.drain_grace_s
        if grace > 0:
            service.leaving.set()
            log.info("not ready, grace", extra={"event": "drain_grace", "seconds": grace})
            time.sleep(grace)
        deadline = time.monotonic() + service.config.lifecycle.drain_timeout_s
        service.drain_read_deadline = (
            time.monotonic() + service.config.lifecycle.drain_read_timeout_s
        )
        service.draining.set()
        log.info("draining", extra={"event": "drain_start", "queued": service.scheduler.depth})
        for server in (self.http_server, self.stream_server):
            if server is not None:
                server.shutdown()  # stop accepting
                server.server_close()
        self.streams.drain_connections()
        while time.monotonic() < deadline:
            streams = self.streams.open_connections()
            if service.http_requests.count == 0 and streams == 0:
                break
            time.sleep(0.05)
        service.scheduler.close()
        service.worker.join(max(0.1, deadline - time.monotonic()))
        clean = not service.worker.is_alive()
        log.info("stopped", extra={"event": "stopped", "clean": clean})
        return clean

    def _reap_sessions(self) -> None:
        service = self.service
        interval = min(5.0, max(0.05, service.config.limits.session_idle_timeout_s / 4))
        heap = HeapTrimmer()
        while not service.draining.wait(interval):
            heap.maybe_trim()
            for session in service.sessions.reap_idle():
                service.scheduler.cancel_key(session.id)
                log.info("session expired", extra={"event": "session_expired", "id": session.id})


def _ready_line(service: RenderService, listeners: Listeners) -> str:
    host = service.config.http.host
    return json.dumps(
        {
            "event": "listening",
            "host": host,
            "http_port": listeners.http_port,
            "stream_port": listeners.stream_port,
            "gl_renderer": service.worker.gl_renderer,
        }
    )


def serve(config: ServerConfig) -> int:
    """Run until SIGTERM/SIGINT; returns the exit status (0 after a clean drain)."""
    configure_logging(json_lines=config.logging.json, level=config.logging.level)
    check_bind_policy(config)
    configure_malloc()
    service = RenderService(config)
    stop = threading.Event()

    def on_signal(signum: int, _frame: object) -> None:
        log.info(
            "signal received", extra={"event": "signal", "signal": signal.Signals(signum).name}
        )
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    listeners = Listeners(service)
    listeners.start()
    log.info(
        "listening",
        extra={
            "event": "listening",
            "host": config.http.host,
            "http_port": listeners.http_port,
            "stream_port": listeners.stream_port,
            "gl_renderer": service.worker.gl_renderer,
        },
    )
    # One machine-readable line on stdout: supervisors and tests learn the bound ports from it
    # (with --port 0 the OS picks them).
    print(_ready_line(service, listeners), flush=True)
    while not stop.wait(0.5):
        pass
    clean = listeners.stop()
    sys.stdout.flush()
    return 0 if clean else 1
