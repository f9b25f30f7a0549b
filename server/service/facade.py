"""What the transports may use of the service: the `ServiceFacade` protocol.

The HTTP handler (`http/`) and the stream connections (`stream/`) are given the running
`RenderService` (`app.py`) through this protocol, bound by a factory (`make_handler`,
`make_stream_server`), so they depend on what they use and not on `app.py`: `serve.py`
imports the transports, never the other way round. mypy checks that `RenderService` satisfies
it where `serve.py` hands it to the factories.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any, Literal, Protocol

from sphrender.core.frame import ParticleFrame
from sphrender.server.service.admission import MemoryBudget
from sphrender.server.service.config import ServerConfig
from sphrender.server.service.metrics import ServiceMetrics
from sphrender.server.service.render.jobs import FrameJob
from sphrender.server.service.render.scheduler import FairScheduler
from sphrender.server.service.render.worker import RenderWorker
from sphrender.server.service.sessions import SceneValidator, Session, SessionRegistry


class ServiceFacade(Protocol):
    config: ServerConfig
    metrics: ServiceMetrics
    scheduler: FairScheduler
    sessions: SessionRegistry
    scenes: SceneValidator
    worker: RenderWorker
    memory: MemoryBudget
    #: Set when SIGTERM / SIGINT starts the drain: transports stop taking new work.
    draining: threading.Event
    #: Set by the drain: half-received messages and bodies must be complete by this time.
    drain_read_deadline: float | None

    def enter_http_request(self) -> None:
        """An HTTP request started (the drain waits for it)."""

    def leave_http_request(self) -> None:
        """That HTTP request finished."""

    def make_particles(self, arrays: dict[str, Any]) -> ParticleFrame:
        """Validate decoded arrays under the server's particle limit."""
        ...

    def submit(
        self,
        job: FrameJob,
        *,
        latest: bool = False,
        block: bool = False,
        abort: Callable[[], bool] | None = None,
    ) -> None:
        """Queue a frame (raises `QueueFull` or `SchedulerClosed`; the job is answered)."""

    def record_invalid_frame(self, transport: str, code: str) -> None:
        """Count a frame rejected before it became a job."""

    def retry_after_s(self) -> int:
        """Seconds a client told to retry should wait."""
        ...

    def create_session(
        self, raw_scene: dict[str, Any], transport: Literal["http", "stream"]
    ) -> Session:
        """Validate the scene, register the session and warm it on the render thread."""
        ...

    def close_session(self, session_id: str) -> bool:
        """Remove a session and cancel its queued frames; False when it did not exist."""
        ...

    def readiness(self) -> tuple[bool, str]:
        """(ready, reason) for /readyz."""
        ...

    def info(self) -> dict[str, Any]:
        """The /v1/info document."""
        ...

    def status(self) -> dict[str, Any]:
        """The /v1/status document (live numbers for the viewer page)."""
        ...

    def demo_particles(self) -> ParticleFrame:
        """The built-in demo's particles, for demo sessions."""
        ...
