"""Bounded, fair queueing of frames in front of the single render thread.

Each session (or HTTP connection, for one-shot renders) has its own FIFO queue of at most
``per_key`` frames; all queues together hold at most ``total``. The render thread takes frames
round-robin over the keys that have work, so a client that keeps its queue full gets one frame in
turn like everyone else and cannot starve the others. Warm-up jobs (session creation) go first.

``latest`` submission (the stream's live mode) first removes the key's frames that have not
started rendering and answers them `DroppedOutcome("superseded")`, so only the newest waits.

When the queues are full, `submit` raises `QueueFull` (HTTP answers 503 + Retry-After) or, with
``block=True``, waits for room (the stream's backpressure: the connection stops reading).
After `close`, new submissions raise `SchedulerClosed`, and `take` hands out what is left and
then returns None for good, which is how the render thread knows the drain is complete.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable

from sphrender.server.service.render.jobs import DroppedOutcome, FrameJob, WarmJob

#: How often a blocked submitter re-checks its abort condition (seconds).
_POLL_S = 0.25


class QueueFull(Exception):
    """No room for the frame: the caller answers busy (503 + Retry-After)."""


class SchedulerClosed(Exception):
    """The service is shutting down and takes no new frames."""


class FairScheduler:
    def __init__(self, per_key: int, total: int) -> None:
        if per_key < 1 or total < per_key:
            raise ValueError(f"need 1 <= per_key <= total, got {per_key}, {total}")
        self.per_key = per_key
        self.total = total
        self._cond = threading.Condition()
        # Keys with queued frames, in service order: the key served last moves to the end.
        self._queues: dict[str, deque[FrameJob]] = {}
        self._warm: deque[WarmJob] = deque()
        self._count = 0
        self._closed = False

    # -- producers ------------------------------------------------------------------------------

    def submit(
        self,
        job: FrameJob,
        *,
        latest: bool = False,
        block: bool = False,
        abort: Callable[[], bool] | None = None,
    ) -> None:
        """Queue `job`; see the module docstring for `latest` and `block`."""
        superseded: list[FrameJob] = []
        with self._cond:
            if self._closed:
                raise SchedulerClosed
            queue = self._queues.get(job.key)
            if latest and queue:
                superseded = list(queue)
                queue.clear()
                self._count -= len(superseded)
            try:
                while self._full(job.key):
                    if not block:
                        raise QueueFull
                    if abort is not None and abort():
                        raise QueueFull
                    self._cond.wait(_POLL_S)
                    if self._closed:
                        raise SchedulerClosed
                job.queued_at = time.perf_counter()
                self._queues.setdefault(job.key, deque()).append(job)
                self._count += 1
                self._cond.notify_all()
            finally:
                if queue is not None and not queue and self._queues.get(job.key) is queue:
                    del self._queues[job.key]
        for old in superseded:
            old.resolve(DroppedOutcome("superseded"))

    def _full(self, key: str) -> bool:
        queue = self._queues.get(key)
        return self._count >= self.total or (queue is not None and len(queue) >= self.per_key)

    def submit_warm(self, job: WarmJob) -> None:
        with self._cond:
            if self._closed:
                raise SchedulerClosed
            self._warm.append(job)
            self._cond.notify_all()

    def cancel_key(self, key: str) -> int:
        """Cancel every queued frame of `key` (its client went away); returns how many."""
        with self._cond:
            queue = self._queues.pop(key, None)
            jobs = list(queue) if queue else []
            self._count -= len(jobs)
            self._cond.notify_all()
        for job in jobs:
            job.cancel()
        return len(jobs)

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    # -- the render thread ----------------------------------------------------------------------

    def take(self, timeout: float) -> FrameJob | WarmJob | None:
        """The next job, round-robin over keys; None after `timeout` or once closed and empty."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                if self._warm:
                    return self._warm.popleft()
                for key, queue in self._queues.items():
                    job = queue.popleft()
                    self._count -= 1
                    del self._queues[key]
                    if queue:
                        self._queues[key] = queue  # re-inserted at the end: next key goes first
                    self._cond.notify_all()  # room for blocked submitters
                    return job
                remaining = deadline - time.monotonic()
                if self._closed or remaining <= 0:
                    return None
                self._cond.wait(remaining)

    # -- introspection --------------------------------------------------------------------------

    @property
    def depth(self) -> int:
        with self._cond:
            return self._count

    @property
    def finished(self) -> bool:
        """Closed and nothing left to hand out."""
        with self._cond:
            return self._closed and self._count == 0 and not self._warm

    @property
    def closed(self) -> bool:
        return self._closed
