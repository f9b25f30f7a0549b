"""The jobs the render process holds, by the id they were sent under.

One condition guards the table: the supervisor waits on it for room (at most
``2 x encoder_threads + 1`` jobs in flight, one while a job re-sent after a restart is in it),
the receiver thread marks jobs started and takes answered jobs out, the watchdog asks whether
a job has been in the process's hands past the render limit.
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
    started_at: float | None = None  # time.monotonic() when the process said it began it
    restarts: int = 0  # render processes that died while holding this job


class InFlight:
    """See the module docstring."""

    def __init__(self) -> None:
        self._changed = threading.Condition()
        self._jobs: dict[int, Sent] = {}
        self._next_id = 0
        self._last_event = 0.0  # time.monotonic() of the last Started or answer

    def add(self, job: FrameJob | WarmJob, restarts: int = 0) -> int:
        """Record `job` as sent now; returns its id on the pipe."""
        with self._changed:
            self._next_id += 1
            self._jobs[self._next_id] = Sent(job, time.monotonic(), restarts=restarts)
            return self._next_id

    def started(self, job_id: int) -> None:
        with self._changed:
            self._last_event = time.monotonic()
            if job_id in self._jobs:
                self._jobs[job_id].started_at = self._last_event

    def sent_in(self, job_id: int, send_ms: float) -> None:
        with self._changed:
            if job_id in self._jobs:
                self._jobs[job_id].send_ms = send_ms

    def pop(self, job_id: int) -> Sent | None:
        with self._changed:
            entry = self._jobs.pop(job_id, None)
            self._last_event = time.monotonic()
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

    def overdue(self, limit_s: float) -> bool:
        """Whether a job has been started more than `limit_s` ago, or (the process stuck
        before starting anything) nothing is started and the process has said nothing for that
        long since the oldest job was sent."""
        now = time.monotonic()
        with self._changed:
            if not self._jobs:
                return False
            starts = [e.started_at for e in self._jobs.values() if e.started_at is not None]
            if starts:
                return now - min(starts) > limit_s
            oldest = min(entry.sent_at for entry in self._jobs.values())
            return now - max(oldest, self._last_event) > limit_s

    def wait_for_room(self, limit: int, blocked: bool, timeout: float) -> bool:
        """Whether another job may be sent; if not (full, or `blocked`), waits up to `timeout`
        for a change first. A re-sent job travels alone (a second death is then its own)."""
        with self._changed:
            retrying = any(entry.restarts for entry in self._jobs.values())
            if len(self._jobs) < (1 if retrying else limit) and not blocked:
                return True
            self._changed.wait(timeout)
            return False

    def wake(self) -> None:
        with self._changed:
            self._changed.notify_all()
