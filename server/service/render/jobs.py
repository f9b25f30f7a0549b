"""Units of work that cross from the network threads to the render thread, and their answers.

A `FrameJob` is created by a transport (HTTP handler or stream connection) after the frame has
been decoded and validated; it carries everything the render thread needs and a future that is
resolved exactly once with an `Outcome`: `ImageOutcome`, `ErrorOutcome` or `DroppedOutcome`.
"Exactly once" is enforced here (`resolve` ignores every call after the first), which is what
lets the stream promise one answer per frame id even when a cancellation races the render.
"""

from __future__ import annotations

import itertools
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any, Literal, TypeAlias

from sphrender.core.frame import ParticleFrame
from sphrender.core.protocol import ImageFormat
from sphrender.server.scene import Scene

#: MIME types of the image answers (raw: PROTOCOL.md §4.3, described by X-Sphrender-Arrays).
CONTENT_TYPES: dict[str, str] = {
    "png": "image/png",
    "exr": "image/x-exr",
    "jpeg": "image/jpeg",
    "raw": "application/octet-stream",
}


@dataclass(frozen=True)
class ImageOutcome:
    data: bytes
    format: ImageFormat
    width: int
    height: int
    particles: int
    drawn: int
    #: Milliseconds per stage: queue, the renderer's passes, encode.
    timings_ms: dict[str, float]
    #: raw only: the payload's array descriptors (name, dtype, shape), in payload order.
    arrays: list[dict[str, Any]] | None = None
    #: What the renderer changed about the frame's input ({"field", "message"}; PROTOCOL 4.3).
    notes: tuple[dict[str, str], ...] = ()


@dataclass(frozen=True)
class ErrorOutcome:
    code: str  # an `ErrorCode` value
    message: str
    field: str | None = None
    retry_after_s: int | None = None


@dataclass(frozen=True)
class DroppedOutcome:
    reason: Literal["superseded", "cancelled"]


Outcome: TypeAlias = ImageOutcome | ErrorOutcome | DroppedOutcome

_sequence = itertools.count(1)


@dataclass(eq=False)
class FrameJob:
    """One frame on its way through the scheduler, the render thread and an encoder."""

    key: str  # fairness key: the session id (or the HTTP connection for one-shot renders)
    particles: ParticleFrame
    scene: Scene
    format: ImageFormat
    transport: Literal["http", "stream"]
    frame_id: int | None = None
    received_at: float = field(default_factory=time.perf_counter)
    queued_at: float = 0.0
    started_at: float = 0.0
    sequence: int = field(default_factory=lambda: next(_sequence))
    future: Future[Outcome] = field(default_factory=Future, repr=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def resolve(self, outcome: Outcome) -> bool:
        """Set the answer; only the first call counts (returns whether this one did)."""
        with self._lock:
            if self.future.done():
                return False
            self.future.set_result(outcome)
            return True

    def cancel(self) -> None:
        """Nobody will read the answer (client gone, request timed out): skip the render."""
        self.resolve(DroppedOutcome("cancelled"))

    @property
    def done(self) -> bool:
        return self.future.done()

    def add_done_callback(self, callback: Callable[[FrameJob, Outcome], None]) -> None:
        self.future.add_done_callback(lambda f: callback(self, f.result()))


@dataclass(eq=False)
class WarmJob:
    """Per-scene precomputation on the render thread (programs, targets, later IBL/LUTs): render
    one particle with the scene and throw the image away. Resolved with None or the error."""

    scene: Scene
    future: Future[BaseException | None] = field(default_factory=Future, repr=False)
