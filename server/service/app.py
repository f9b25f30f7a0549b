"""The render service: one process, one render thread, an HTTP API and a streaming socket.

`RenderService` wires the parts together and is what the transports talk to::

    HTTP handler threads ─┐  decode + validate (numpy, no GL)          ┌─ encoder threads
                          ├─▶ FrameJob ─▶ FairScheduler ─▶ render thread ─▶ (PNG/EXR) ─▶ future
    stream conn threads ──┘                                (owns GL)    └─ resolved once

`serve` runs it until SIGTERM or SIGINT, then drains: listeners close, stream connections stop
reading and answer what they accepted, HTTP requests in progress finish, the render thread
empties the queue, releases GL, and the process exits 0 (or after ``drain_timeout_s``).
"""

from __future__ import annotations

import json
import logging
import math
import platform
import signal
import sys
import threading
import time
from collections.abc import Callable
from importlib import metadata
from typing import Any, Literal

from sphrender.core.frame import ParticleFrame, make_frame
from sphrender.core.protocol import VERSION as PROTOCOL_VERSION
from sphrender.core.protocol import ErrorCode, LimitError
from sphrender.server.content.demo import demo_frame
from sphrender.server.service.admission import MemoryBudget, decoding
from sphrender.server.service.config import (
    ServerConfig,
    check_bind_policy,
    public_limits,
)
from sphrender.server.service.http.api import make_http_server
from sphrender.server.service.logs import configure_logging
from sphrender.server.service.metrics import ServiceMetrics
from sphrender.server.service.render.jobs import (
    DroppedOutcome,
    ErrorOutcome,
    FrameJob,
    ImageOutcome,
    Outcome,
    WarmJob,
)
from sphrender.server.service.render.scheduler import FairScheduler, QueueFull, SchedulerClosed
from sphrender.server.service.render.worker import RenderWorker
from sphrender.server.service.sessions import (
    SceneValidator,
    Session,
    SessionRegistry,
)
from sphrender.server.service.stream.listener import make_stream_server

log = logging.getLogger("sphrender.service")

__all__ = ["RenderService", "serve"]


def _version(package: str) -> str:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return "unknown"


class RenderService:
    """Everything one server process holds; transports get it injected (no globals)."""

    def __init__(self, config: ServerConfig) -> None:
        self.config = config
        self.metrics = ServiceMetrics()
        self.scheduler = FairScheduler(
            config.scheduler.queue_per_session, config.scheduler.queue_total
        )
        self.worker = RenderWorker(
            self.scheduler,
            self.metrics,
            config.scheduler.encoder_threads,
            config.security.environment_dirs,
            start_timeout_s=config.worker.start_timeout_s,
            render_timeout_s=config.limits.render_timeout_s,
            max_rss_bytes=config.worker.max_rss_bytes,
        )
        self.sessions = SessionRegistry(
            config.limits.max_sessions, config.limits.session_idle_timeout_s
        )
        self.scenes = SceneValidator(
            config.limits.max_pixels,
            config.security.environment_dirs,
            config.limits.max_scene_bytes,
        )
        self.memory = MemoryBudget(
            config.limits.memory_budget_bytes, config.limits.max_request_bytes
        )
        self.draining = threading.Event()
        #: set first on SIGTERM when drain_grace_s > 0: not ready, but still serving
        self.leaving = threading.Event()
        #: Set by the drain: reads of a half-received message or body end by this time.
        self.drain_read_deadline: float | None = None
        self.started_at = time.time()
        self._active_lock = threading.Lock()
        self._active_http_requests = 0
        self.http_server: Any = None
        self.stream_server: Any = None
        self._threads: list[threading.Thread] = []
        self._demo_lock = threading.Lock()
        self._demo: ParticleFrame | None = None
        self.metrics.queue_depth.set_callback(lambda: [((), float(self.scheduler.depth))])
        self.metrics.sessions.set_callback(
            lambda: [((k,), float(v)) for k, v in self.sessions.counts().items()]
        )
        self.metrics.memory_reserved.set_callback(lambda: [((), float(self.memory.used))])
        self.metrics.open_connections.set_callback(
            lambda: [
                ((), 0.0 if self.stream_server is None else self.stream_server.open_connections())
            ]
        )

    # -- start / stop ---------------------------------------------------------------------------

    def start(self) -> None:
        """Start the render thread (waits until GL is up and warm), then the listeners."""
        self.worker.start()
        self.worker.ready.wait()
        if self.worker.startup_error is not None:
            raise self.worker.startup_error
        self.metrics.build_info.set(1, _version("sphrender"), self.worker.gl_renderer)
        try:
            self.http_server = make_http_server(self)
            if self.config.stream.enabled:
                self.stream_server = make_stream_server(self)
        except BaseException:
            self.worker.kill()
            raise
        self._spawn("sphrender-http", self.http_server.serve_forever)
        if self.stream_server is not None:
            self._spawn("sphrender-stream", self.stream_server.serve_forever)
        self._spawn("sphrender-reaper", self._reap_sessions)

    def _spawn(self, name: str, target: Callable[[], Any]) -> None:
        thread = threading.Thread(target=target, name=name, daemon=True)
        thread.start()
        self._threads.append(thread)

    @property
    def http_port(self) -> int:
        return int(self.http_server.server_address[1])

    @property
    def stream_port(self) -> int | None:
        return None if self.stream_server is None else int(self.stream_server.server_address[1])

    def stop(self) -> bool:
        """Drain and stop; returns True when everything finished within the drain timeout.

        With ``drain_grace_s`` > 0 the service first only turns not ready (/readyz 503
        "draining") and keeps accepting frames for that long, so a load balancer stops sending
        before the listeners close; then the drain proper (``drain_timeout_s``)."""
        grace = self.config.lifecycle.drain_grace_s
        if grace > 0:
            self.leaving.set()
            log.info("not ready, grace", extra={"event": "drain_grace", "seconds": grace})
            time.sleep(grace)
        deadline = time.monotonic() + self.config.lifecycle.drain_timeout_s
        self.drain_read_deadline = time.monotonic() + self.config.lifecycle.drain_read_timeout_s
        self.draining.set()
        log.info("draining", extra={"event": "drain_start", "queued": self.scheduler.depth})
        for server in (self.http_server, self.stream_server):
            if server is not None:
                server.shutdown()  # stop accepting
                server.server_close()
        if self.stream_server is not None:
            self.stream_server.drain_connections()
        while time.monotonic() < deadline:
            streams = 0 if self.stream_server is None else self.stream_server.open_connections()
            if self.active_http_requests == 0 and streams == 0:
                break
            time.sleep(0.05)
        self.scheduler.close()
        self.worker.join(max(0.1, deadline - time.monotonic()))
        clean = not self.worker.is_alive()
        log.info("stopped", extra={"event": "stopped", "clean": clean})
        return clean

    def _reap_sessions(self) -> None:
        interval = min(5.0, max(0.05, self.config.limits.session_idle_timeout_s / 4))
        while not self.draining.wait(interval):
            for session in self.sessions.reap_idle():
                self.scheduler.cancel_key(session.id)
                log.info("session expired", extra={"event": "session_expired", "id": session.id})

    # -- HTTP bookkeeping (for the drain) -------------------------------------------------------

    def enter_http_request(self) -> None:
        with self._active_lock:
            self._active_http_requests += 1

    def leave_http_request(self) -> None:
        with self._active_lock:
            self._active_http_requests -= 1

    @property
    def active_http_requests(self) -> int:
        with self._active_lock:
            return self._active_http_requests

    # -- frames and sessions --------------------------------------------------------------------

    def make_particles(self, arrays: dict[str, Any]) -> ParticleFrame:
        """Validate decoded arrays (shapes, NaN, ranges) under the server's particle limit."""
        positions = arrays.get("positions")
        if positions is not None and getattr(positions, "ndim", 0) >= 1:
            count = int(positions.shape[0])
            if count > self.config.limits.max_particles:
                raise LimitError(
                    "positions",
                    f"{count} particles exceed this server's limit of "
                    f"{self.config.limits.max_particles}",
                )
        return make_frame(
            positions,
            densities=arrays.get("densities"),
            radii=arrays.get("radii"),
            temperatures=arrays.get("temperatures"),
            max_particles=self.config.limits.max_particles,
        )

    def submit(
        self,
        job: FrameJob,
        *,
        latest: bool = False,
        block: bool = False,
        abort: Callable[[], bool] | None = None,
    ) -> None:
        """Queue a frame; raises `QueueFull`, or `SchedulerClosed` once the drain has closed the
        scheduler (which happens only after every request in flight has been queued)."""
        self.metrics.in_flight.add(1)
        job.add_done_callback(self._record)
        try:
            self.scheduler.submit(job, latest=latest, block=block, abort=abort)
        except (QueueFull, SchedulerClosed) as exc:
            if isinstance(exc, QueueFull):
                code, message = ErrorCode.BUSY, "the render queue is full; retry later"
            else:
                code, message = ErrorCode.SHUTTING_DOWN, "the server is shutting down"
            job.resolve(ErrorOutcome(code, message, retry_after_s=self.retry_after_s()))
            raise

    def _record(self, job: FrameJob, outcome: Outcome) -> None:
        self.metrics.in_flight.add(-1)
        if isinstance(outcome, ImageOutcome):
            kind = "image"
        elif isinstance(outcome, DroppedOutcome):
            kind = "dropped"
        elif outcome.code in (ErrorCode.BUSY, ErrorCode.SHUTTING_DOWN):
            kind = "rejected"
        else:
            kind = "error"
            self.metrics.errors.inc(job.transport, outcome.code)
        self.metrics.frames.inc(job.transport, kind)
        latency = time.perf_counter() - job.received_at
        self.metrics.frame_seconds.observe(latency, job.transport)
        if isinstance(outcome, ImageOutcome):
            self.metrics.recent.add(latency)
            session = self.sessions.get(job.key, touch=False)
            if session is not None:
                session.keep_latest(outcome.format, outcome.data, outcome.width, outcome.height)

    def record_invalid_frame(self, transport: str, code: str) -> None:
        """A frame rejected before it became a job (bad arrays, NaN, too large)."""
        self.metrics.frames.inc(transport, "error")
        self.metrics.errors.inc(transport, code)

    def retry_after_s(self) -> int:
        """Seconds until the queue has probably drained enough: depth x recent time per frame."""
        estimate = self.scheduler.depth * self.worker.busy_ms_ewma / 1e3
        return max(1, min(60, math.ceil(estimate)))

    def create_session(
        self, raw_scene: dict[str, Any], transport: Literal["http", "stream"]
    ) -> Session:
        """Validate the scene, register the session and warm the scene on the render thread.

        Raises `InputError`/`LimitError` for the scene, `SessionLimitReached`, `SchedulerClosed`
        or `TimeoutError`."""
        if self.draining.is_set():
            raise SchedulerClosed
        with decoding("scene", transport):
            scene = self.scenes.from_dict(raw_scene)
        self.worker.check_image_size(scene)
        session = self.sessions.add(scene, raw_scene, transport)
        try:
            warm = WarmJob(scene)
            self.scheduler.submit_warm(warm)
            error = warm.future.result(timeout=self.config.limits.render_timeout_s)
            if error is not None:
                raise error
        except BaseException:
            self.sessions.remove(session.id)
            raise
        log.info(
            "session opened",
            extra={"event": "session_open", "id": session.id, "transport": transport},
        )
        return session

    def close_session(self, session_id: str) -> bool:
        session = self.sessions.remove(session_id)
        if session is None:
            return False
        self.scheduler.cancel_key(session_id)
        log.info("session closed", extra={"event": "session_close", "id": session_id})
        return True

    # -- status ---------------------------------------------------------------------------------

    def readiness(self) -> tuple[bool, str]:
        if self.draining.is_set() or self.leaving.is_set():
            return False, "draining"
        if not self.worker.ready.is_set():
            return False, "starting"
        if not self.worker.healthy:
            return False, "gl_unavailable"
        return True, "ready"

    def status(self) -> dict[str, Any]:
        """The live numbers of ``GET /v1/status`` (the viewer page shows them)."""
        frames = self.metrics.frames
        outcomes = ("image", "error", "dropped", "rejected")
        ready, state = self.readiness()
        return {
            "state": state,
            "ready": ready,
            "renderer": self.worker.gl_renderer,
            "sessions": self.sessions.counts(),
            "session_list": self.sessions.listing(),
            "queue_depth": self.scheduler.depth,
            "in_flight": int(self.metrics.in_flight.value()),
            "frames_total": {
                kind: int(sum(frames.value(t, kind) for t in ("http", "stream")))
                for kind in outcomes
            },
            "recent": self.metrics.recent.summary(),
            "uptime_s": round(time.time() - self.started_at, 1),
        }

    def demo_particles(self) -> ParticleFrame:
        """The built-in weld bead's particles (made once, on first use)."""
        with self._demo_lock:
            if self._demo is None:
                self._demo = demo_frame()
            return self._demo

    def info(self) -> dict[str, Any]:
        return {
            "service": "sphrender",
            "version": _version("sphrender"),
            "protocol_version": PROTOCOL_VERSION,
            "python": platform.python_version(),
            "libraries": {
                name: _version(name) for name in ("numpy", "moderngl", "OpenImageIO", "OpenEXR")
            },
            "gl": {
                "renderer": self.worker.gl_renderer,
                "version": self.worker.gl_version,
                "max_image_side": self.worker.max_image_side,
            },
            "opencl": None,
            "formats": ["png", "exr"],
            "stream_port": self.stream_port,
            "auth": "bearer" if self.config.security.token else "none",
            "limits": public_limits(self.config),
            "uptime_s": round(time.time() - self.started_at, 3),
        }


def _ready_line(service: RenderService) -> str:
    host = service.config.http.host
    return json.dumps(
        {
            "event": "listening",
            "host": host,
            "http_port": service.http_port,
            "stream_port": service.stream_port,
            "gl_renderer": service.worker.gl_renderer,
        }
    )


def serve(config: ServerConfig) -> int:
    """Run until SIGTERM/SIGINT; returns the exit status (0 after a clean drain)."""
    configure_logging(json_lines=config.logging.json, level=config.logging.level)
    check_bind_policy(config)
    service = RenderService(config)
    stop = threading.Event()

    def on_signal(signum: int, _frame: object) -> None:
        log.info(
            "signal received", extra={"event": "signal", "signal": signal.Signals(signum).name}
        )
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    service.start()
    log.info(
        "listening",
        extra={
            "event": "listening",
            "host": config.http.host,
            "http_port": service.http_port,
            "stream_port": service.stream_port,
            "gl_renderer": service.worker.gl_renderer,
        },
    )
    # One machine-readable line on stdout: supervisors and tests learn the bound ports from it
    # (with --port 0 the OS picks them).
    print(_ready_line(service), flush=True)
    while not stop.wait(0.5):
        pass
    clean = service.stop()
    sys.stdout.flush()
    return 0 if clean else 1
