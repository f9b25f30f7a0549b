"""The render supervisor: feeds the renderer process and survives its death.

Rendering and encoding happen in a child process (`process.py`, multiprocessing ``spawn``:
a fresh interpreter that owns the GL context; the service process never creates one). This
thread takes jobs from the `FairScheduler` and sends them down the pipe, at most
``2 x encoder_threads + 1`` at a time (the child renders one while its encoders finish the
previous ones); a receiver thread reads the answers and resolves the jobs' futures.

Failures:

* `InputError` from the renderer (an image over the GL limit): the frame is answered
  ``bad_input``.
* A GL error: the child answers ``render_failed``, rebuilds its context and says so
  (``sphrender_gl_context_rebuilds_total``).
* The child dies (a native fault: SIGSEGV, SIGABRT, the OOM killer), hangs (a frame in it for
  longer than ``limits.render_timeout_s``: it is killed) or grows past ``worker.max_rss_bytes``
  (replaced between frames): every frame it held is answered ``render_failed``, warm-ups fail,
  a new child is started, and ``sphrender_worker_restarts_total{reason}`` counts it. The
  listeners never stop; frames queued meanwhile wait in the scheduler.

``SPHRENDER_FAULT_INJECTION`` (tests only; nothing sets it in production) makes frames fail on
purpose, by their 1-based count over the life of this service: ``gl_error_at_frames=2,5`` raises
a GL error in the render step, ``crash_at_frames=3`` raises SIGSEGV in the renderer process;
several specs are separated by ``;``.
"""

from __future__ import annotations

import contextlib
import json
import logging
import multiprocessing
import os
import signal
import threading
import time
from collections.abc import Sequence
from multiprocessing.connection import Connection
from typing import Any

import numpy as np

from sphrender.core.errors import InputError
from sphrender.core.protocol import ErrorCode
from sphrender.server.scene import Scene
from sphrender.server.service.metrics import ServiceMetrics
from sphrender.server.service.render.jobs import ErrorOutcome, FrameJob, ImageOutcome, WarmJob
from sphrender.server.service.render.process import child_main
from sphrender.server.service.render.scheduler import FairScheduler

log = logging.getLogger("sphrender.service.worker")

FAULT_INJECTION_ENV = "SPHRENDER_FAULT_INJECTION"
_TICK_S = 0.1


def _fault_frames() -> dict[int, str]:
    """{frame number: "gl_error" | "crash"} from `FAULT_INJECTION_ENV`."""
    faults: dict[int, str] = {}
    for part in os.environ.get(FAULT_INJECTION_ENV, "").split(";"):
        key, _, values = part.strip().partition("=")
        kind = {"gl_error_at_frames": "gl_error", "crash_at_frames": "crash"}.get(key)
        if kind is not None:
            faults.update((int(v), kind) for v in values.split(",") if v.strip().isdigit())
    return faults


def _exit_text(code: int | None) -> str:
    if code is None:
        return "did not exit"
    if code < 0:
        try:
            return f"signal {-code} ({signal.Signals(-code).name})"
        except ValueError:
            return f"signal {-code}"
    return f"exit status {code}"


class _Child:
    """One renderer process, its pipe and its receiver thread."""

    def __init__(self, process: Any, conn: Connection) -> None:
        self.process = process
        self.conn = conn
        self.dead = threading.Event()
        self.hung = False  # killed by the watchdog
        self.receiver: threading.Thread | None = None
        self.pid = process.pid


class RenderWorker(threading.Thread):
    """See the module docstring. Start it, wait for `ready`, check `startup_error`."""

    def __init__(
        self,
        scheduler: FairScheduler,
        metrics: ServiceMetrics,
        encoder_threads: int,
        environment_dirs: Sequence[str] = (),
        *,
        start_timeout_s: float = 120.0,
        render_timeout_s: float = 120.0,
        max_rss_bytes: int = 3 << 30,
    ) -> None:
        super().__init__(name="sphrender-render", daemon=True)
        self._scheduler = scheduler
        self._metrics = metrics
        self._encoder_threads = encoder_threads
        self._environment_dirs = tuple(environment_dirs)
        self._start_timeout_s = start_timeout_s
        self._render_timeout_s = render_timeout_s
        self._max_rss_bytes = max_rss_bytes
        self._max_outstanding = 2 * encoder_threads + 1
        self._context = multiprocessing.get_context("spawn")
        self._faults = _fault_frames()
        self._frames_sent = 0
        self._next_id = 0
        self._lock = threading.Condition()
        #: id -> (job, monotonic time sent, ms spent sending)
        self._pending: dict[int, tuple[FrameJob | WarmJob, float, float]] = {}
        self._child: _Child | None = None
        self._recycle = False
        self._stopped = threading.Event()
        self.ready = threading.Event()
        self.healthy = False
        self.startup_error: BaseException | None = None
        self.gl_renderer = "unknown"
        self.gl_version = "unknown"
        self.max_image_side = 0
        self.child_pid: int | None = None
        self.busy_ms_ewma = 50.0  # recent render+encode time per frame, for Retry-After

    def check_image_size(self, scene: Scene) -> None:
        """Reject an image side over the GL limit before a frame is queued (any thread)."""
        for key in ("width", "height"):
            value = getattr(scene.image, key)
            if self.max_image_side and value > self.max_image_side:
                raise InputError(
                    f"image.{key}", f"must be at most {self.max_image_side} (GL limit), got {value}"
                )

    # -- the child ------------------------------------------------------------------------------

    def _spawn(self) -> _Child:
        """Start a renderer process and wait until it is warm (raises on failure)."""
        ours, theirs = self._context.Pipe(duplex=True)
        process = self._context.Process(
            target=child_main,
            args=(theirs, self._environment_dirs, self._encoder_threads),
            name="sphrender-renderer",
            daemon=True,
        )
        process.start()
        theirs.close()
        child = _Child(process, ours)
        try:
            if not ours.poll(self._start_timeout_s):
                raise RuntimeError(
                    f"the renderer process was not ready within {self._start_timeout_s} s"
                )
            hello = json.loads(ours.recv_bytes())
        except (EOFError, OSError, RuntimeError, ValueError) as exc:
            process.kill()
            process.join(5)
            detail = _exit_text(process.exitcode) if isinstance(exc, EOFError) else str(exc)
            raise RuntimeError(f"the renderer process failed to start: {detail}") from None
        if hello.get("type") != "ready":
            process.join(5)
            raise RuntimeError(f"the renderer process failed to start: {hello.get('error')}")
        self.gl_renderer = str(hello["gl_renderer"])
        self.gl_version = str(hello["gl_version"])
        self.max_image_side = int(hello["max_image_side"])
        self.child_pid = child.pid
        child.receiver = threading.Thread(
            target=self._receive, args=(child,), name="sphrender-render-receiver", daemon=True
        )
        child.receiver.start()
        log.info(
            "renderer process ready",
            extra={
                "event": "gl_ready",
                "pid": child.pid,
                "gl_renderer": self.gl_renderer,
                "gl_version": self.gl_version,
                "warm_ms": hello.get("warm_ms"),
            },
        )
        return child

    def _stop_child(self, child: _Child, *, kill: bool = False) -> None:
        if not kill:
            with contextlib.suppress(OSError):
                child.conn.send(("stop",))
            child.process.join(10)
        if child.process.is_alive():
            child.process.kill()
            child.process.join(5)
        child.dead.wait(5)
        if child.receiver is not None:
            child.receiver.join(5)
        child.conn.close()

    def kill(self) -> None:
        """Stop the renderer process now (start-up failed after the worker was started)."""
        self._stopped.set()
        child = self._child
        if child is not None:
            child.process.kill()
            child.process.join(5)

    def _replace_child(self, reason: str) -> None:
        """The child is gone (or must go): answer what it held, count it, start another."""
        child, self._child = self._child, None
        exit_text = "replaced"
        if child is not None:
            self._stop_child(child, kill=reason != "rss")
            exit_text = _exit_text(child.process.exitcode)
        with self._lock:
            lost = list(self._pending.values())
            self._pending.clear()
            self._lock.notify_all()
        message = (
            f"the renderer process died ({exit_text}) while this frame was in it; it has been "
            "restarted and later frames are unaffected"
        )
        if reason == "hung":
            message = (
                f"rendering took longer than limits.render_timeout_s ({self._render_timeout_s} s); "
                "the renderer process was restarted"
            )
        for job, _sent, _send_ms in lost:
            if isinstance(job, WarmJob):
                job.future.set_result(RuntimeError(message))
            else:
                job.resolve(ErrorOutcome(ErrorCode.RENDER_FAILED, message))
        self._metrics.worker_restarts.inc(reason)
        log.error(
            "renderer process replaced",
            extra={
                "event": "worker_restart",
                "reason": reason,
                "exit": exit_text,
                "frames_lost": len(lost),
            },
        )
        self._recycle = False
        try:
            self._child = self._spawn()
            self.healthy = True
        except Exception:
            self.healthy = False
            log.exception("starting a renderer process failed; retrying on the next job")

    def _receive(self, child: _Child) -> None:
        """Receiver thread: answers from the child -> the jobs' futures (never unpickles)."""
        try:
            while True:
                header = json.loads(child.conn.recv_bytes())
                data = None
                start = time.perf_counter()
                if header.get("data"):
                    data = child.conn.recv_bytes()
                self._on_answer(header, data, (time.perf_counter() - start) * 1e3)
        except (EOFError, OSError, ValueError):
            pass
        finally:
            child.dead.set()
            with self._lock:
                self._lock.notify_all()

    def _on_answer(self, header: dict[str, Any], data: bytes | None, recv_ms: float) -> None:
        with self._lock:
            entry = self._pending.pop(int(header.get("id", -1)), None)
            self._lock.notify_all()
        if header.get("rebuilt"):
            self._metrics.context_rebuilds.inc()
            log.warning("GL context rebuilt", extra={"event": "gl_rebuilt"})
        rss = int(header.get("rss", 0))
        self._metrics.worker_rss.set(rss)
        if rss > self._max_rss_bytes:
            self._recycle = True
        if entry is None:
            return
        job, _sent, send_ms = entry
        kind = header.get("type")
        if isinstance(job, WarmJob):
            error = header.get("error")
            if error is None:
                job.future.set_result(None)
            elif error.get("input"):
                job.future.set_result(InputError(error["field"], error["message"]))
            else:
                job.future.set_result(RuntimeError(error["message"]))
            return
        if kind == "image" and data is not None:
            stage_ms: dict[str, float] = header["timings_ms"]
            ipc_ms = send_ms + float(header.get("recv_ms", 0.0)) + recv_ms
            timings = {"queue": (job.started_at - job.queued_at) * 1e3, **stage_ms, "ipc": ipc_ms}
            for stage, ms in stage_ms.items():
                self._metrics.stage_seconds.observe(ms / 1e3, stage)
            self._metrics.stage_seconds.observe(ipc_ms / 1e3, "ipc")
            self._metrics.host_seconds.observe(float(header.get("host_ms", 0.0)) / 1e3)
            self.busy_ms_ewma = 0.8 * self.busy_ms_ewma + 0.2 * sum(stage_ms.values())
            job.resolve(
                ImageOutcome(
                    data=data,
                    format=job.format,
                    width=int(header["width"]),
                    height=int(header["height"]),
                    particles=int(header["particles"]),
                    drawn=int(header["drawn"]),
                    timings_ms={k: round(v, 3) for k, v in timings.items()},
                    arrays=header.get("arrays"),
                    notes=tuple(header.get("notes", ())),
                )
            )
        else:
            code = str(header.get("code", ErrorCode.RENDER_FAILED))
            if code not in (ErrorCode.BAD_INPUT, ErrorCode.RENDER_FAILED):
                code = ErrorCode.RENDER_FAILED
            job.resolve(ErrorOutcome(code, str(header.get("message")), header.get("field")))

    # -- thread body ----------------------------------------------------------------------------

    def run(self) -> None:
        try:
            self._child = self._spawn()
            self.healthy = True
        except BaseException as exc:
            self.startup_error = exc
            self.ready.set()
            return
        self.ready.set()
        watchdog = threading.Thread(target=self._watchdog, name="sphrender-watchdog", daemon=True)
        watchdog.start()
        try:
            while True:
                self._supervise()
                with self._lock:
                    if len(self._pending) >= self._max_outstanding or self._recycle:
                        self._lock.wait(_TICK_S)
                        continue
                job = self._scheduler.take(timeout=_TICK_S)
                if job is None:
                    with self._lock:
                        idle = not self._pending
                    if self._scheduler.finished and idle:
                        break
                    continue
                try:
                    self._dispatch(job)
                except Exception:  # the supervisor must never die: that job fails, no other
                    log.exception("dispatching a job failed", extra={"event": "worker_bug"})
                    if isinstance(job, WarmJob):
                        if not job.future.done():
                            job.future.set_result(RuntimeError("internal error"))
                    else:
                        job.resolve(ErrorOutcome(ErrorCode.RENDER_FAILED, "internal error"))
        finally:
            self._stopped.set()
            if self._child is not None:
                self._stop_child(self._child)
            log.info("render thread stopped", extra={"event": "render_stopped"})

    def _supervise(self) -> None:
        child = self._child
        if child is None:
            return
        if child.dead.is_set() or not child.process.is_alive():
            self._replace_child("hung" if child.hung else "crash")
            return
        with self._lock:
            idle = not self._pending
        if self._recycle and idle:
            self._replace_child("rss")

    def _watchdog(self) -> None:
        """Kill a child that has held a job past ``limits.render_timeout_s`` (a hung driver);
        its own thread, because the supervisor may be blocked writing to the child's pipe."""
        while not self._stopped.wait(0.5):
            child = self._child
            with self._lock:
                oldest = min((sent for _job, sent, _ms in self._pending.values()), default=None)
            late = oldest is not None and time.monotonic() - oldest > self._render_timeout_s
            if child is not None and late and not child.hung:
                child.hung = True
                log.error("renderer process hung; killing it", extra={"event": "worker_hung"})
                child.process.kill()

    def _dispatch(self, job: FrameJob | WarmJob) -> None:
        if isinstance(job, FrameJob) and job.done:  # cancelled or superseded while queued
            return
        if self._child is None:
            self._replace_child("unavailable")
        child = self._child
        if child is None:
            error = RuntimeError("the renderer process is unavailable")
            if isinstance(job, WarmJob):
                job.future.set_result(error)
            else:
                job.resolve(ErrorOutcome(ErrorCode.RENDER_FAILED, str(error)))
            return
        self._next_id += 1
        job_id = self._next_id
        start = time.perf_counter()
        with self._lock:
            self._pending[job_id] = (job, time.monotonic(), 0.0)
        try:
            if isinstance(job, WarmJob):
                child.conn.send(("warm", job_id, job.scene))
            else:
                job.started_at = time.perf_counter()
                self._metrics.stage_seconds.observe(job.started_at - job.queued_at, "queue")
                self._frames_sent += 1
                fault = self._faults.get(self._frames_sent)
                p = job.particles
                arrays = [
                    (name, value)
                    for name, value in (
                        ("positions", p.positions),
                        ("densities", p.densities),
                        ("radii", p.radii),
                        ("temperatures", p.temperatures),
                    )
                    if value is not None
                ]
                specs = [(name, value.dtype.str, value.shape) for name, value in arrays]
                child.conn.send(("frame", job_id, job.scene, job.format, fault, specs))
                for _name, value in arrays:  # raw bytes, no pickling (empty arrays too)
                    flat = np.ascontiguousarray(value).reshape(-1).view(np.uint8)
                    child.conn.send_bytes(flat)  # type: ignore[arg-type]  # ndarray is a buffer
        except OSError:
            pass  # the child died; _supervise answers the job with the others it held
        except Exception:
            # A bug on our side; the pipe may hold half a message, so this child cannot go on.
            log.exception("sending a job to the renderer failed", extra={"event": "worker_bug"})
            child.process.kill()
        send_ms = (time.perf_counter() - start) * 1e3
        with self._lock:
            if job_id in self._pending:
                self._pending[job_id] = (job, self._pending[job_id][1], send_ms)
