"""The jobs the render process holds, by the id they were sent under.

One condition guards the table: the supervisor waits on it for room (at most
``2 x encoder_threads + 1`` jobs in flight), the receiver thread takes answered jobs out, the
watchdog reads the oldest send time.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

from sphrender.server.service.render.jobs import FrameJob, WarmJob


@dataclass
class Sent:
    job: FrameJob | WarmJob
    sent_at: float  # time.monotonic() when it was handed to the pipe
    send_ms: float = 0.0  # time spent writing it to the pipe


class InFlight:
    """See the module docstring."""

    def __init__(self) -> None:
        self._changed = threading.Condition()
        self._jobs: dict[int, Sent] = {}
        self._next_id = 0

    def add(self, job: FrameJob | WarmJob) -> int:
        """Record `job` as sent now; returns its id on the pipe."""
        with self._changed:
            self._next_id += 1
            self._jobs[self._next_id] = Sent(job, time.monotonic())
            return self._next_id

    def sent_in(self, job_id: int, send_ms: float) -> None:
        with self._changed:
            if job_id in self._jobs:
                self._jobs[job_id].send_ms = send_ms

    def pop(self, job_id: int) -> Sent | None:
        with self._changed:
            entry = self._jobs.pop(job_id, None)
            self._changed.notify_all()
            return entry

    def take_all(self) -> list[Sent]:
        """Every job in flight (the process holding them is gone)."""
        with self._changed:
            lost = list(self._jobs.values())
            self._jobs.clear()
            self._changed.notify_all()
            return lost

    def idle(self) -> bool:
        with self._changed:
            return not self._jobs

    def oldest_sent_at(self) -> float | None:
        with self._changed:
            return min((entry.sent_at for entry in self._jobs.values()), default=None)

    def wait_for_room(self, limit: int, blocked: bool, timeout: float) -> bool:
        """Whether another job may be sent; if not (full, or `blocked`), waits up to `timeout`
        for a change first."""
        with self._changed:
            if len(self._jobs) < limit and not blocked:
                return True
            self._changed.wait(timeout)
            return False

    def wake(self) -> None:
        with self._changed:
            self._changed.notify_all()
