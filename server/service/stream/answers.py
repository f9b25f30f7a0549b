"""The answers one stream connection owes, in the order its frames arrived.

The reader appends a `Slot` for every FRAME *before* queueing its job; the writer takes the
slots in order, waits for each one's outcome and sends it. `Answers` is the state the two
threads share: the slots, how many are owed (the reader's backpressure), whether reading is
over, and whether the connection is dead or draining.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from sphrender.core.protocol import ErrorCode, MessageType, encode_message
from sphrender.server.service.render.jobs import (
    DroppedOutcome,
    ErrorOutcome,
    FrameJob,
    ImageOutcome,
    Outcome,
)
from sphrender.server.service.stream.wire import TICK_S


@dataclass
class Slot:
    """One owed answer, in arrival order: a job still running or an outcome already known."""

    frame_id: int | None
    job: FrameJob | None = None
    outcome: Outcome | None = None
    fatal: bool = False
    release: Callable[[], None] | None = None  # the frame's memory reservation


def answer_bytes(slot: Slot, outcome: Outcome) -> bytes:
    """The IMAGE, DROPPED or ERROR message for `slot`. A frame cancelled by the service (its
    session closed under it) is answered ERROR ``shutting_down``/``busy``, never DROPPED
    ``cancelled``: DROPPED means only ``superseded`` (PROTOCOL.md 4.5)."""
    if isinstance(outcome, ImageOutcome):
        header: dict[str, Any] = {
            "id": slot.frame_id,
            "format": outcome.format,
            "width": outcome.width,
            "height": outcome.height,
            "particles": outcome.particles,
            "drawn": outcome.drawn,
            "timings_ms": outcome.timings_ms,
        }
        if outcome.arrays is not None:
            header["arrays"] = outcome.arrays
        if outcome.notes:
            header["notes"] = list(outcome.notes)
        return encode_message(MessageType.IMAGE, header, outcome.data)
    if isinstance(outcome, DroppedOutcome):
        if outcome.reason == "superseded":
            return encode_message(
                MessageType.DROPPED, {"id": slot.frame_id, "reason": outcome.reason}
            )
        outcome = ErrorOutcome(ErrorCode.BUSY, "the frame was cancelled before it was rendered")
    return encode_message(
        MessageType.ERROR,
        {
            "id": slot.frame_id,
            "code": outcome.code,
            "error": outcome.message,
            "field": outcome.field,
            "fatal": slot.fatal,
        },
    )


class Answers:
    """See the module docstring."""

    def __init__(self) -> None:
        self._changed = threading.Condition()
        self._slots: deque[Slot] = deque()
        self._owed = 0
        self._reading_done = False
        #: GOODBYE's reason, when the connection ends in an orderly way.
        self.goodbye: str | None = None
        self.dead = threading.Event()  # the peer is gone or the connection was evicted
        self.draining = threading.Event()  # the service is shutting down
        self.evicted = threading.Event()  # closed while idle to make room for a new connection
        self.last_active = time.monotonic()  # the last frame received or answer sent

    @property
    def owed(self) -> int:
        return self._owed

    def push(self, slot: Slot) -> None:
        with self._changed:
            self._slots.append(slot)
            self._owed += 1
            self.last_active = time.monotonic()
            self._changed.notify_all()

    def idle_for(self, now: float) -> float:
        """Seconds with nothing owed and nothing received (0 while a frame is in flight)."""
        with self._changed:
            return 0.0 if self._owed or self.evicted.is_set() else now - self.last_active

    def wait_for_room(self, limit: int) -> None:
        """Block the reader while `limit` answers are owed (unless dead or draining)."""
        with self._changed:
            while self._owed >= limit and not self.dead.is_set() and not self.draining.is_set():
                self._changed.wait(TICK_S)

    def finish_reading(self) -> None:
        with self._changed:
            self._reading_done = True
            self._changed.notify_all()

    def first(self) -> Slot | None:
        """The next answer owed, waiting for one; None once reading is over and none is."""
        with self._changed:
            while not self._slots and not self._reading_done:
                self._changed.wait(TICK_S)
            return self._slots[0] if self._slots else None

    def sent_first(self) -> None:
        with self._changed:
            self._slots.popleft()
            self._owed -= 1
            self.last_active = time.monotonic()
            self._changed.notify_all()

    def abandon(self) -> list[Slot]:
        """Everything still owed, taken out (the client cannot receive it any more)."""
        with self._changed:
            slots = list(self._slots)
            self._slots.clear()
            self._owed = 0
            self._changed.notify_all()
            return slots
