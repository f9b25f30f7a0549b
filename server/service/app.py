"""The render service: one process, one render thread, an HTTP API and a streaming socket.

`RenderService` holds the parts and is what the transports talk to (`facade.ServiceFacade`)::

    HTTP handler threads ─┐  decode + validate (numpy, no GL)          ┌─ encoder threads
                          ├─▶ FrameJob ─▶ FairScheduler ─▶ render thread ─▶ (PNG/EXR) ─▶ future
    stream conn threads ──┘                                (owns GL)    └─ resolved once

`serve.py` starts it with its listeners and drains it on SIGTERM or SIGINT.
"""

from __future__ import annotations

import functools
import logging
import math
import platform
import threading
import time
from collections.abc import Callable
from importlib import metadata
from typing import Any, Literal, get_args, get_type_hints

from sphrender.core.frame import ParticleFrame, make_frame
from sphrender.core.frame_message import ENCODINGS, FRAME_CONTENT_TYPE
from sphrender.core.protocol import ARRAY_NAMES, IMAGE_FORMATS, ErrorCode, LimitError
from sphrender.core.protocol import VERSION as PROTOCOL_VERSION
from sphrender.server.content.demo import demo_frame
from sphrender.server.scene import OutputConfig
from sphrender.server.service.admission import MemoryBudget, decoding
from sphrender.server.service.config import (
    ServerConfig,
    public_limits,
)
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

log = logging.getLogger("sphrender.service")

#: The raw image types the scene's output.raw_type accepts (what /v1/info lists).
RAW_TYPES: tuple[str, ...] = get_args(get_type_hints(OutputConfig)["raw_type"])

__all__ = ["RenderService"]


def package_version(package: str) -> str:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return "unknown"


@functools.cache
def _demo_particles() -> ParticleFrame:
    return demo_frame()  # deterministic and never modified: one copy serves every service


class ActiveRequests:
    """How many HTTP requests are in progress (the drain waits for them)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._count = 0

    def enter(self) -> None:
        with self._lock:
            self._count += 1

    def leave(self) -> None:
        with self._lock:
            self._count -= 1

    @property
    def count(self) -> int:
        with self._lock:
            return self._count


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
        self.http_requests = ActiveRequests()
        #: The stream listener's port once it listens (`serve.Listeners`), for /v1/info.
        self.stream_port: int | None = None
        self.metrics.render.queue_depth.set_callback(lambda: [((), float(self.scheduler.depth))])
        self.metrics.transport.sessions.set_callback(
            lambda: [((k,), float(v)) for k, v in self.sessions.counts().items()]
        )
        self.metrics.transport.memory_reserved.set_callback(lambda: [((), float(self.memory.used))])

    # -- HTTP bookkeeping (for the drain) -------------------------------------------------------

    def enter_http_request(self) -> None:
        self.http_requests.enter()

    def leave_http_request(self) -> None:
        self.http_requests.leave()

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
            velocities=arrays.get("velocities"),
            ids=arrays.get("ids"),
            peak_temperatures=arrays.get("peak_temperatures"),
            solid=arrays.get("solid"),
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
        particles = job.particles
        if particles.ids is not None and particles.temperatures is not None:
            session = self.sessions.get(job.key, touch=False)
            if session is not None:
                job.particles = session.peaks.apply(particles, job.scene)
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
        return _demo_particles()

    def info(self) -> dict[str, Any]:
        return {
            "service": "sphrender",
            "version": package_version("sphrender"),
            "protocol_version": PROTOCOL_VERSION,
            "python": platform.python_version(),
            "libraries": {
                name: package_version(name)
                for name in ("numpy", "moderngl", "OpenImageIO", "OpenEXR")
            },
            "gl": {
                "renderer": self.worker.gl_renderer,
                "version": self.worker.gl_version,
                "max_image_side": self.worker.max_image_side,
            },
            "opencl": self.worker.opencl,
            "formats": list(IMAGE_FORMATS),
            "raw_types": list(RAW_TYPES),
            "frame_arrays": list(ARRAY_NAMES),
            "frame_encodings": list(ENCODINGS),
            "frame_content_types": ["application/x-npz", FRAME_CONTENT_TYPE],
            "stream_port": self.stream_port,
            "auth": "bearer" if self.config.security.token else "none",
            "limits": public_limits(self.config),
            "uptime_s": round(time.time() - self.started_at, 3),
        }
