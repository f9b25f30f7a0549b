"""The render supervisor: feeds the render process and survives its death.

Rendering and encoding happen in a render process (`process.py`, multiprocessing ``spawn``: a
fresh interpreter that owns the GL context; the service process never creates one). This
thread takes jobs from the `FairScheduler` and sends them down the pipe as typed requests
(`messages.py`), at most ``2 x encoder_threads + 1`` at a time (the process renders one while
its encoders finish the previous ones); the handle's receiver thread reads the answers and this
module resolves the jobs' futures.

Failures:

* `InputError` from the renderer (an image over the GL limit): the frame is answered
  ``bad_input``.
* A GL error: the process answers ``render_failed``, rebuilds its context and says so
  (``sphrender_gl_context_rebuilds_total``).
* The process dies (a native fault: SIGSEGV, SIGABRT, the OOM killer), hangs (a job it began
  more than ``limits.render_timeout_s`` ago: it is killed) or grows past
  ``worker.max_rss_bytes`` (replaced between frames): a new process is started and
  ``sphrender_worker_restarts_total{reason}`` counts it. The job past the limit is answered
  ``render_failed``; every other job the process held is sent again to the new one, first and
  one at a time, so a second death is that job's own: a job held at ``MAX_RESTARTS`` deaths is
  answered ``render_failed``. The listeners never stop; frames queued meanwhile wait in the
  scheduler.
"""

from __future__ import annotations

import logging
import multiprocessing
import threading
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TypeAlias

import numpy as np

from sphrender.core.errors import InputError
from sphrender.server.scene import Scene
from sphrender.server.service.metrics import ServiceMetrics
from sphrender.server.service.render.handle import ProcessHandle, exit_text
from sphrender.server.service.render.in_flight import InFlight, Sent
from sphrender.server.service.render.jobs import FrameJob, WarmJob
from sphrender.server.service.render.messages import (
    Answer,
    ArraySpec,
    ErrorAnswer,
    FrameRequest,
    Health,
    ImageAnswer,
    Ready,
    Started,
    WarmAnswer,
    WarmRequest,
)
from sphrender.server.service.render.outcomes import (
    error_outcome,
    fail,
    image_outcome,
    warm_result,
)
from sphrender.server.service.render.scheduler import FairScheduler

log = logging.getLogger("sphrender.service.worker")

_TICK_S = 0.1
#: A job the render process held at this many of its deaths is answered render_failed.
MAX_RESTARTS = 2

Job: TypeAlias = FrameJob | WarmJob


@dataclass(frozen=True)
class WorkerSettings:
    encoder_threads: int
    environment_dirs: tuple[str, ...]
    start_timeout_s: float
    render_timeout_s: float
    max_rss_bytes: int


class RenderWorker(threading.Thread):
    """See the module docstring. Start it, wait for `ready`, check `startup_error`."""

    def __init__(
        self,
        scheduler: FairScheduler,
        metrics: ServiceMetrics,
        encoder_threads: int,
        environment_dirs: Sequence[str] = (),
        *,
        start_timeout_s: float = 60.0,
        render_timeout_s: float = 120.0,
        max_rss_bytes: int = 3 << 30,
    ) -> None:
        super().__init__(name="sphrender-render", daemon=True)
        self._scheduler = scheduler
        self._metrics = metrics
        self._settings = WorkerSettings(
            encoder_threads,
            tuple(environment_dirs),
            start_timeout_s,
            render_timeout_s,
            max_rss_bytes,
        )
        self._context = multiprocessing.get_context("spawn")
        self._in_flight = InFlight()
        self._retry: deque[tuple[Job, int]] = deque()  # (job, restarts) to send again first
        self._frames_sent = 0
        self._process: ProcessHandle | None = None
        self._gl: Ready | None = None  # what the last process that started said about its GL
        self._recycle = False  # past max_rss_bytes: replace the process once it is idle
        self._stopped = threading.Event()
        self.ready = threading.Event()
        self.healthy = False
        self.startup_error: BaseException | None = None
        self.busy_ms_ewma = 50.0  # recent render+encode time per frame, for Retry-After

    @property
    def gl_renderer(self) -> str:
        return self._gl.gl_renderer if self._gl else "unknown"

    @property
    def gl_version(self) -> str:
        return self._gl.gl_version if self._gl else "unknown"

    @property
    def opencl(self) -> dict[str, str] | None:
        """The render process's OpenCL device (None without one, or before it started)."""
        hello = self._gl
        if hello is None or hello.cl_device is None:
            return None
        return {
            "platform": hello.cl_platform or "",
            "device": hello.cl_device,
            "type": hello.cl_type or "",
        }

    @property
    def max_image_side(self) -> int:
        return self._gl.max_image_side if self._gl else 0

    def check_image_size(self, scene: Scene) -> None:
        """Reject an image side over the GL limit before a frame is queued (any thread)."""
        limit = self.max_image_side
        for key in ("width", "height"):
            value = getattr(scene.image, key)
            if limit and value > limit:
                raise InputError(f"image.{key}", f"must be at most {limit} (GL limit), got {value}")

    def kill(self) -> None:
        """Stop the render process now (start-up failed after the worker was started)."""
        self._stopped.set()
        process = self._process
        if process is not None:
            process.kill()

    # -- the process ----------------------------------------------------------------------------

    def _spawn(self) -> ProcessHandle:
        """Start a render process and wait until it is warm (raises on failure)."""
        settings = self._settings
        process = ProcessHandle.spawn(
            self._context,
            settings.environment_dirs,
            settings.encoder_threads,
            settings.start_timeout_s,
        )
        self._gl = hello = process.ready
        process.start_receiver(self._on_answer, self._in_flight.wake)
        log.info(
            "renderer process ready",
            extra={
                "event": "gl_ready",
                "pid": process.pid,
                "gl_renderer": hello.gl_renderer,
                "gl_version": hello.gl_version,
                "warm_ms": hello.warm_ms,
            },
        )
        return process

    def _replace_process(self, reason: str) -> None:
        """The process is gone (or must go): answer what it held, count it, start another."""
        process, self._process = self._process, None
        exit_words = "replaced"
        if process is not None:
            process.stop(kill=reason != "rss")
            exit_words = exit_text(process.process.exitcode)
        held = self._in_flight.take_all()
        late_s = self._settings.render_timeout_s if reason == "hung" else None
        resend, failed = sort_held(held, late_s, exit_words)
        self._retry.extendleft(reversed(resend))  # before anything queued, in the order sent
        self._metrics.render.worker_restarts.inc(reason)
        log.error(
            "renderer process replaced",
            extra={
                "event": "worker_restart",
                "reason": reason,
                "exit": exit_words,
                "frames_lost": failed,
                "frames_resent": len(resend),
            },
        )
        self._recycle = False
        try:
            self._process = self._spawn()
            self.healthy = True
        except Exception:
            self.healthy = False
            log.exception("starting a renderer process failed; retrying on the next job")

    def _on_answer(
        self, answer: Answer, health: Health, data: bytes | None, recv_ms: float
    ) -> None:
        """Receiver thread: one answer -> its job's future."""
        entry = None
        if isinstance(answer, Started):
            self._in_flight.started(answer.id)
        elif isinstance(answer, ImageAnswer | ErrorAnswer | WarmAnswer):
            entry = self._in_flight.pop(answer.id)
        if health.rebuilt:
            self._metrics.render.context_rebuilds.inc()
            log.warning("GL context rebuilt", extra={"event": "gl_rebuilt"})
        self._metrics.render.worker_rss.set(health.rss)
        if health.rss > self._settings.max_rss_bytes:
            self._recycle = True
        if entry is None:
            return
        job = entry.job
        match answer:
            case WarmAnswer() if isinstance(job, WarmJob):
                job.future.set_result(warm_result(answer))
            case ImageAnswer() if isinstance(job, FrameJob) and data is not None:
                ipc_ms = entry.send_ms + answer.recv_ms + recv_ms
                self.busy_ms_ewma = 0.8 * self.busy_ms_ewma + 0.2 * sum(answer.timings_ms.values())
                job.resolve(image_outcome(job, answer, data, ipc_ms, self._metrics))
            case ErrorAnswer() if isinstance(job, FrameJob):
                job.resolve(error_outcome(answer))
            case _:
                fail(job, f"the renderer answered {type(answer).__name__} to this job")

    # -- thread body ----------------------------------------------------------------------------

    def run(self) -> None:
        try:
            self._process = self._spawn()
            self.healthy = True
        except BaseException as exc:
            self.startup_error = exc
            self.ready.set()
            return
        self.ready.set()
        watchdog = threading.Thread(target=self._watchdog, name="sphrender-watchdog", daemon=True)
        watchdog.start()
        limit = 2 * self._settings.encoder_threads + 1
        try:
            while True:
                self._supervise()
                depth = 1 if self._retry else limit  # a re-sent job goes alone
                if not self._in_flight.wait_for_room(depth, self._recycle, _TICK_S):
                    continue
                job, restarts = self._retry.popleft() if self._retry else (None, 0)
                if job is None:
                    job = self._scheduler.take(timeout=_TICK_S)
                if job is None:
                    if self._scheduler.finished and self._in_flight.idle() and not self._retry:
                        break
                    continue
                try:
                    self._dispatch(job, restarts)
                except Exception:  # the supervisor must never die: that job fails, no other
                    log.exception("dispatching a job failed", extra={"event": "worker_bug"})
                    fail(job, "internal error")
        finally:
            self._stopped.set()
            if self._process is not None:
                self._process.stop()
            log.info("render thread stopped", extra={"event": "render_stopped"})

    def _supervise(self) -> None:
        process = self._process
        if process is None:
            return
        if not process.alive():
            self._replace_process("hung" if process.hung else "crash")
        elif self._recycle and self._in_flight.idle():
            self._replace_process("rss")

    def _watchdog(self) -> None:
        """Kill a process that began a job more than ``limits.render_timeout_s`` ago (a hung
        driver, a degenerate frame); its own thread, because the supervisor may be blocked
        writing to the process's pipe."""
        while not self._stopped.wait(0.25):
            process = self._process
            late = self._in_flight.overdue(self._settings.render_timeout_s)
            if process is not None and late and not process.hung:
                process.hung = True
                log.error("renderer process hung; killing it", extra={"event": "worker_hung"})
                process.process.kill()

    def _dispatch(self, job: Job, restarts: int = 0) -> None:
        if isinstance(job, FrameJob) and job.done:  # cancelled or superseded while queued
            return
        if self._process is None:
            self._replace_process("unavailable")
        process = self._process
        if process is None:
            fail(job, "the renderer process is unavailable")
            return
        start = time.perf_counter()
        job_id = self._in_flight.add(job, restarts)
        try:
            if isinstance(job, WarmJob):
                process.send(WarmRequest(job_id, job.scene))
            else:
                if not restarts:
                    job.started_at = time.perf_counter()
                    queued = job.started_at - job.queued_at
                    self._metrics.render.stage_seconds.observe(queued, "queue")
                self._frames_sent += 1
                request, buffers = self._frame_request(job, job_id)
                process.send(request, buffers)
        except OSError:
            pass  # the process died; _supervise answers the job with the others it held
        except Exception:
            # A bug on our side; the pipe may hold half a message, so this process cannot go on.
            log.exception("sending a job to the renderer failed", extra={"event": "worker_bug"})
            process.process.kill()
        self._in_flight.sent_in(job_id, (time.perf_counter() - start) * 1e3)

    def _frame_request(self, job: FrameJob, job_id: int) -> tuple[FrameRequest, list[np.ndarray]]:
        """The request for `job` and the particle buffers that follow it."""
        p = job.particles
        named = (
            ("positions", p.positions),
            ("densities", p.densities),
            ("radii", p.radii),
            ("temperatures", p.temperatures),
            ("peak_temperatures", p.peak_temperatures),
            ("solid", p.solid),
            ("velocities", p.velocities if job.scene.camera.shutter > 0 else None),  # motion blur
        )
        present = [(name, value) for name, value in named if value is not None]
        specs = tuple(ArraySpec(name, value.dtype.str, value.shape) for name, value in present)
        request = FrameRequest(job_id, job.scene, job.format, self._frames_sent, specs)
        return request, [value for _name, value in present]


def sort_held(
    held: list[Sent], late_s: float | None, exit_words: str
) -> tuple[list[tuple[Job, int]], int]:
    """The jobs a dead process held: those to send again (with their restart count), in the
    order sent; the others are answered render_failed here (returns how many). With `late_s`
    (the process was killed as hung), a job begun more than `late_s` ago is the late one."""
    now = time.monotonic()
    resend: list[tuple[Job, int]] = []
    failed = 0
    for entry in held:
        if late_s is not None and entry.started_at is not None and now - entry.started_at > late_s:
            message = (
                f"rendering took longer than limits.render_timeout_s ({late_s:g} s); the "
                "renderer process was restarted and later frames are unaffected"
            )
        elif entry.restarts + 1 >= MAX_RESTARTS:
            message = (
                f"the renderer process died ({exit_words}) each time it held this frame; it has "
                "been restarted and later frames are unaffected"
            )
        else:
            resend.append((entry.job, entry.restarts + 1))
            continue
        fail(entry.job, message)
        failed += 1
    return resend, failed
