"""The render thread (sole owner of the GL context) and the encoder pool behind it.

The render thread creates the `GLContext` and the `SurfaceRenderer`, so it is their owner and the
only thread that ever touches GL (`GLContext.check_owner` enforces it). It loops: take the next
job from the `FairScheduler`, render it, hand the `RenderedFrame` to an encoder thread, take the
next job. PNG/EXR encoding therefore overlaps with rendering the next frame; a semaphore bounds
how many rendered frames may wait for an encoder, so a slow encoder applies backpressure instead
of piling up frame buffers.

Failures:

* `InputError` from the renderer (an image larger than the GL limit): the frame is answered
  ``bad_input`` and rendering continues.
* Any other exception while rendering is treated as a GL (or, later, CL) failure: the frame is
  answered ``render_failed``, every GPU object and the context are released and rebuilt before
  the next job, and ``sphrender_gl_context_rebuilds_total`` counts it. Per-scene caches live in
  the renderer, so they are rebuilt lazily by the next frame that needs them.

``SPHRENDER_FAULT_INJECTION=gl_error_at_frames=2,5`` raises a GL error inside the render step of
those frames (1-based count of frames rendered by this process). It exists so the tests can drive
the rebuild path through a real server process; nothing sets it in production.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor

import moderngl
import numpy as np

from sphrender.client.errors import InputError
from sphrender.client.frame import make_frame
from sphrender.client.protocol import ErrorCode
from sphrender.server.engine.frame_output import RenderedFrame, RenderStats
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.output.local import encode_for_scene, render_for_output
from sphrender.server.scene import Scene
from sphrender.server.service.jobs import (
    ErrorOutcome,
    FrameJob,
    ImageOutcome,
    WarmJob,
)
from sphrender.server.service.metrics import ServiceMetrics
from sphrender.server.service.scheduler import FairScheduler

log = logging.getLogger("sphrender.service.worker")

FAULT_INJECTION_ENV = "SPHRENDER_FAULT_INJECTION"


def _fault_frames() -> frozenset[int]:
    spec = os.environ.get(FAULT_INJECTION_ENV, "")
    if not spec.startswith("gl_error_at_frames="):
        return frozenset()
    values = spec.split("=", 1)[1].split(",")
    return frozenset(int(v) for v in values if v.strip().isdigit())


def warm_frame(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """One particle at the camera target: renders every pass the scene uses."""
    return np.array([scene.camera.target], dtype=np.float64), np.array(
        [scene.particles.radius], dtype=np.float32
    )


class RenderWorker(threading.Thread):
    """See the module docstring. Start it, wait for `ready`, check `startup_error`."""

    def __init__(
        self,
        scheduler: FairScheduler,
        metrics: ServiceMetrics,
        encoder_threads: int,
        environment_dirs: Sequence[str] = (),
    ) -> None:
        super().__init__(name="sphrender-render", daemon=True)
        self._scheduler = scheduler
        self._metrics = metrics
        self._encoders = ThreadPoolExecutor(encoder_threads, thread_name_prefix="sphrender-encode")
        self._encode_slots = threading.BoundedSemaphore(2 * encoder_threads)
        self._gl: GLContext | None = None
        self._renderer: SurfaceRenderer | None = None
        self._environment_dirs = tuple(environment_dirs)
        self._faults = _fault_frames()
        self._frames_rendered = 0
        self.ready = threading.Event()
        self.healthy = False
        self.startup_error: BaseException | None = None
        self.gl_renderer = "unknown"
        self.gl_version = "unknown"
        self.max_image_side = 0
        self.busy_ms_ewma = 50.0  # recent render+encode time per frame, for Retry-After

    def check_image_size(self, scene: Scene) -> None:
        """Reject an image side over the GL limit before a frame is queued (any thread)."""
        for key in ("width", "height"):
            value = getattr(scene.image, key)
            if self.max_image_side and value > self.max_image_side:
                raise InputError(
                    f"image.{key}", f"must be at most {self.max_image_side} (GL limit), got {value}"
                )

    # -- context lifecycle (render thread only) -------------------------------------------------

    def _open(self) -> SurfaceRenderer:
        self._gl = GLContext()
        self._renderer = SurfaceRenderer(self._gl, environment_dirs=self._environment_dirs)
        self.gl_renderer, self.gl_version = self._gl.renderer, self._gl.version
        self.max_image_side = self._gl.limits.max_image_side
        return self._renderer

    def _close(self) -> None:
        renderer, gl = self._renderer, self._gl
        self._renderer = self._gl = None
        if renderer is not None:
            try:
                renderer.release()
            except Exception:  # a broken context may fail to release; it is discarded anyway
                log.warning("releasing the renderer failed", exc_info=True)
        if gl is not None:
            try:
                gl.release()
            except Exception:
                log.warning("releasing the GL context failed", exc_info=True)

    def _rebuild(self) -> None:
        self._close()
        try:
            self._open()
            self.healthy = True
            log.warning("GL context rebuilt", extra={"event": "gl_rebuilt"})
        except Exception:
            self.healthy = False
            log.exception("rebuilding the GL context failed; will retry on the next frame")
        self._metrics.context_rebuilds.inc()

    def _warm(self, scene: Scene) -> None:
        assert self._renderer is not None
        positions, radii = warm_frame(scene)
        self._renderer.render(make_frame(positions, radii=radii), scene)

    # -- thread body ----------------------------------------------------------------------------

    def run(self) -> None:
        try:
            self._open()
            start = time.perf_counter()
            self._warm(Scene())
            log.info(
                "render thread ready",
                extra={
                    "event": "gl_ready",
                    "gl_renderer": self.gl_renderer,
                    "gl_version": self.gl_version,
                    "opencl": "not used by this build",
                    "warm_ms": round((time.perf_counter() - start) * 1e3, 1),
                },
            )
            self.healthy = True
        except BaseException as exc:
            self.startup_error = exc
            self._close()
            self.ready.set()
            return
        self.ready.set()
        try:
            while True:
                job = self._scheduler.take(timeout=0.5)
                if job is None:
                    if self._scheduler.finished:
                        break
                    continue
                if isinstance(job, WarmJob):
                    self._run_warm(job)
                else:
                    self._run_frame(job)
        finally:
            self._encoders.shutdown(wait=True)
            self._close()
            log.info("render thread stopped", extra={"event": "render_stopped"})

    def _run_warm(self, job: WarmJob) -> None:
        if self._renderer is None:
            self._rebuild()
        try:
            self._warm(job.scene)
            job.future.set_result(None)
        except InputError as exc:
            job.future.set_result(exc)
        except Exception as exc:
            log.exception("GL error while warming a scene", extra={"event": "gl_error"})
            job.future.set_result(exc)
            self._rebuild()

    def _run_frame(self, job: FrameJob) -> None:
        if job.done:  # cancelled or superseded while queued
            return
        job.started_at = time.perf_counter()
        self._metrics.stage_seconds.observe(job.started_at - job.queued_at, "queue")
        if self._renderer is None:
            self._rebuild()
            if self._renderer is None:
                job.resolve(ErrorOutcome(ErrorCode.RENDER_FAILED, "the GL context is unavailable"))
                return
        self._encode_slots.acquire()  # bounded backlog of rendered frames waiting to encode
        handed_off = False
        try:
            self._frames_rendered += 1
            if self._frames_rendered in self._faults:
                self._renderer.gl.ctx.finish()
                raise moderngl.Error(f"injected GL fault at frame {self._frames_rendered}")
            frame, stats = render_for_output(self._renderer, job.particles, job.scene, job.format)
        except InputError as exc:
            job.resolve(ErrorOutcome(ErrorCode.BAD_INPUT, exc.message, exc.field))
        except Exception as exc:
            log.error(
                "GL error while rendering; rebuilding the context",
                extra={"event": "gl_error", "error": str(exc), "frame_id": job.frame_id},
            )
            job.resolve(
                ErrorOutcome(
                    ErrorCode.RENDER_FAILED,
                    f"rendering failed ({type(exc).__name__}: {exc}); the GL context was "
                    "rebuilt, later frames are unaffected",
                )
            )
            self._rebuild()
        else:
            self._encoders.submit(self._encode, job, frame, stats)
            handed_off = True
        finally:
            if not handed_off:
                self._encode_slots.release()

    # -- encoder threads ------------------------------------------------------------------------

    def _encode(self, job: FrameJob, frame: RenderedFrame, stats: RenderStats) -> None:
        try:
            start = time.perf_counter()
            # The same AOV and encoder choices as `sphrender render`, so the bytes match the CLI's.
            data = encode_for_scene(frame, job.scene, job.format)
            done = time.perf_counter()
            timings = {"queue": (job.started_at - job.queued_at) * 1e3, **stats.stage_ms}
            timings["encode"] = (done - start) * 1e3
            for stage, ms in stats.stage_ms.items():
                self._metrics.stage_seconds.observe(ms / 1e3, stage)
            self._metrics.stage_seconds.observe(done - start, "encode")
            busy = stats.total_ms + timings["encode"]
            self.busy_ms_ewma = 0.8 * self.busy_ms_ewma + 0.2 * busy
            job.resolve(
                ImageOutcome(
                    data=data,
                    format=job.format,
                    width=frame.width,
                    height=frame.height,
                    particles=stats.particles_in,
                    drawn=stats.particles_drawn,
                    timings_ms={k: round(v, 3) for k, v in timings.items()},
                )
            )
        except Exception as exc:
            log.exception("encoding failed", extra={"event": "encode_error"})
            job.resolve(ErrorOutcome(ErrorCode.RENDER_FAILED, f"encoding failed: {exc}"))
        finally:
            self._encode_slots.release()
