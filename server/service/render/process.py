"""The render process: owns the GL context, renders and encodes; the service supervises it.

`RenderWorker` (worker.py) starts this module's `process_main` with multiprocessing's ``spawn``
context (a fresh interpreter: nothing is forked, least of all an EGL context). The process
creates the `GLContext` and `SurfaceRenderer` on its main thread, which is the only thread that
touches GL, renders each job it is sent, and encodes PNG/EXR on its own encoder threads,
overlapping the next render. A native fault here (a segfault in a driver, an encoder or the
allocator) ends this process only: the service answers the frames it had sent ``render_failed``
and starts another. The messages on the pipe are typed (messages.py).

Test seam: when ``SPHRENDER_FAULT_INJECTION`` names a Python file, its
``wrap_render_step(step)`` wraps the frame's render step (tests/render_faults.py injects GL
errors and native crashes that way). Nothing in the frame path knows about faults.
"""

from __future__ import annotations

import contextlib
import faulthandler
import importlib.util
import logging
import os
import signal
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from multiprocessing.connection import Connection
from typing import TYPE_CHECKING, TypeAlias

import numpy as np

from sphrender.server.scene import Scene
from sphrender.server.service.heap import HeapTrimmer, configure_malloc
from sphrender.server.service.logs import configure_inherited_logging
from sphrender.server.service.render.messages import (
    Answer,
    ArrayLayout,
    ErrorAnswer,
    FrameRequest,
    Health,
    ImageAnswer,
    Note,
    Ready,
    Started,
    StartupFailed,
    StopRequest,
    WarmAnswer,
    WarmError,
    WarmRequest,
    encode_answer,
)
from sphrender.server.service.render.warmup import warm_scene

if TYPE_CHECKING:
    from sphrender.core.frame import ParticleFrame
    from sphrender.server.engine.frame_output import RenderedFrame, RenderStats
    from sphrender.server.engine.gpu.gl_context import GLContext
    from sphrender.server.engine.renderer import SurfaceRenderer

log = logging.getLogger("sphrender.service.renderer")

#: Names the test-only fault module (see the module docstring); unset in production.
FAULT_INJECTION_ENV = "SPHRENDER_FAULT_INJECTION"

RenderStep: TypeAlias = Callable[
    ["FrameRequest", "SurfaceRenderer", "ParticleFrame"], "tuple[RenderedFrame, RenderStats]"
]

#: Page size for reading /proc/self/statm.
_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def rss_bytes() -> int:
    """Resident set size of this process (Linux /proc; 0 elsewhere)."""
    try:
        with open("/proc/self/statm") as handle:
            return int(handle.read().split()[1]) * _PAGE
    except (OSError, ValueError, IndexError):
        return 0


def render_step(
    request: FrameRequest, renderer: SurfaceRenderer, particles: ParticleFrame
) -> tuple[RenderedFrame, RenderStats]:
    """The frame's render, reading back what its output format carries."""
    from sphrender.server.output.local import render_for_output

    return render_for_output(renderer, particles, request.scene, request.format)


def load_render_step() -> RenderStep:
    """`render_step`, or the test fault module's wrapping of it (``FAULT_INJECTION_ENV``)."""
    path = os.environ.get(FAULT_INJECTION_ENV)
    if not path:
        return render_step
    spec = importlib.util.spec_from_file_location("sphrender_render_faults", path)
    if spec is None or spec.loader is None:
        raise RuntimeError(f"{FAULT_INJECTION_ENV}: cannot load {path}")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    wrapped: RenderStep = module.wrap_render_step(render_step)
    return wrapped


class RenderProcess:
    """The render process's state: the pipe, the GL context and renderer, the encoder pool."""

    def __init__(self, conn: Connection, environment_dirs: tuple[str, ...], encoders: int) -> None:
        self.conn = conn
        self.environment_dirs = environment_dirs
        self._send_lock = threading.Lock()
        self._encoders = ThreadPoolExecutor(encoders, thread_name_prefix="sphrender-encode")
        self._encode_slots = threading.BoundedSemaphore(2 * encoders)
        self._gl: GLContext | None = None
        self._renderer: SurfaceRenderer | None = None
        self._rebuilt = False
        self._render_step = load_render_step()

    def send(self, answer: Answer, data: bytes | None = None) -> None:
        """One answer (and the image bytes of an `ImageAnswer`), with this process's health."""
        rebuilt, self._rebuilt = self._rebuilt, False
        message = encode_answer(answer, Health(rss=rss_bytes(), rebuilt=rebuilt))
        with self._send_lock:
            self.conn.send_bytes(message)
            if data is not None:
                self.conn.send_bytes(data)

    # -- GL -------------------------------------------------------------------------------------

    def open(self) -> GLContext:
        from sphrender.server.engine.gpu.gl_context import GLContext
        from sphrender.server.engine.renderer import SurfaceRenderer

        self._gl = GLContext()
        self._renderer = SurfaceRenderer(self._gl, environment_dirs=self.environment_dirs)
        return self._gl

    def close(self) -> None:
        renderer, gl = self._renderer, self._gl
        self._renderer = self._gl = None
        for thing in (renderer, gl):
            if thing is not None:
                # a broken context may fail to release; it is discarded anyway
                with contextlib.suppress(Exception):
                    thing.release()

    def rebuild(self) -> SurfaceRenderer | None:
        """A fresh context and renderer after a GL error (None if that failed: the next job
        retries)."""
        self.close()
        self._rebuilt = True
        try:
            self.open()
        except Exception:
            self._renderer = None
        return self._renderer

    # -- jobs -----------------------------------------------------------------------------------

    def run(self) -> None:
        try:
            gl = self.open()
            start = time.perf_counter()
            assert self._renderer is not None
            warm_scene(self._renderer, Scene())
        except BaseException as exc:
            self.send(StartupFailed(f"{type(exc).__name__}: {exc}"))
            return
        warm_ms = round((time.perf_counter() - start) * 1e3, 1)
        limits = gl.limits.max_image_side
        # The SPH stages' OpenCL context, made now (~0.2 s with PoCL's kernel cache) so the
        # service can name the device it will use; the first frame that needs it reuses it.
        cl: tuple[str | None, ...] = (None, None, None)
        with contextlib.suppress(Exception):  # no usable device: the stages report it per frame
            device = self._renderer.opencl_device()
            cl = (device.platform_name, device.device_name, device.device_type)
        self.send(Ready(os.getpid(), gl.renderer, gl.version, limits, warm_ms, *cl))
        heap = HeapTrimmer()
        try:
            while True:
                heap.maybe_trim()
                try:
                    request = self.conn.recv()
                except (EOFError, OSError):
                    break  # the service is gone: so are we
                if isinstance(request, StopRequest):
                    break
                if isinstance(request, WarmRequest):
                    self._warm_job(request)
                elif isinstance(request, FrameRequest):
                    self._frame_job(request)
        finally:
            self._encoders.shutdown(wait=True)
            self.close()

    def _warm_job(self, request: WarmRequest) -> None:
        from sphrender.core.errors import InputError

        error: WarmError | None = None
        self.send(Started(request.id))
        renderer = self._renderer or self.rebuild()
        try:
            if renderer is None:
                raise RuntimeError("the GL context is unavailable")
            warm_scene(renderer, request.scene)
        except InputError as exc:
            error = WarmError(input=True, field=exc.field, message=exc.message)
        except Exception as exc:
            log.warning("warm failed", extra={"event": "warm_failed", "detail": repr(exc)})
            error = WarmError(input=False, field=None, message="the GL context failed")
            self.rebuild()
        self.send(WarmAnswer(request.id, error))

    def _read_particles(self, request: FrameRequest) -> ParticleFrame:
        """The buffers that follow the request, as raw bytes in its ``arrays`` order."""
        from sphrender.core.frame import ParticleFrame

        arrays = {
            spec.name: np.frombuffer(self.conn.recv_bytes(), dtype=spec.dtype).reshape(spec.shape)
            for spec in request.arrays
        }
        return ParticleFrame(
            positions=arrays["positions"],
            densities=arrays.get("densities"),
            radii=arrays.get("radii"),
            temperatures=arrays.get("temperatures"),
            peak_temperatures=arrays.get("peak_temperatures"),
            solid=arrays.get("solid"),
            velocities=arrays.get("velocities"),
        )

    def _frame_job(self, request: FrameRequest) -> None:
        from sphrender.core.errors import InputError

        start = time.perf_counter()
        particles = self._read_particles(request)
        recv_ms = (time.perf_counter() - start) * 1e3
        renderer = self._renderer or self.rebuild()
        if renderer is None:
            self._error(request.id, "render_failed", "the GL context is unavailable")
            return
        self._encode_slots.acquire()  # bounded backlog of rendered frames waiting to encode
        self.send(Started(request.id))
        handed_off = False
        try:
            frame, stats = self._render_step(request, renderer, particles)
        except InputError as exc:
            self._error(request.id, "bad_input", exc.message, exc.field)
        except Exception as exc:
            log.warning("render failed", extra={"event": "render_failed", "detail": repr(exc)})
            message = "rendering failed; the GL context was rebuilt, later frames are unaffected"
            self.rebuild()
            self._error(request.id, "render_failed", message)
        else:
            self._encoders.submit(self._encode, request, frame, stats, recv_ms)
            handed_off = True
        finally:
            if not handed_off:
                self._encode_slots.release()

    def _error(self, job_id: int, code: str, message: str, field: str | None = None) -> None:
        self.send(ErrorAnswer(job_id, code, message, field))

    def _encode(
        self, request: FrameRequest, frame: RenderedFrame, stats: RenderStats, recv_ms: float
    ) -> None:
        from sphrender.server.output.local import encode_for_scene, raw_layout

        try:
            start = time.perf_counter()
            data = encode_for_scene(frame, request.scene, request.format)
            timings = {**stats.stage_ms, "encode": (time.perf_counter() - start) * 1e3}
            layout = raw_layout(request.scene, request.format)
            answer = ImageAnswer(
                id=request.id,
                width=frame.width,
                height=frame.height,
                particles=stats.particles_in,
                drawn=stats.particles_drawn,
                timings_ms=timings,
                host_ms=stats.host_ms,
                recv_ms=recv_ms,
                arrays=None
                if layout is None
                else tuple(
                    ArrayLayout(str(a["name"]), str(a["dtype"]), tuple(a["shape"])) for a in layout
                ),
                notes=tuple(Note(n.field, n.message) for n in stats.notes),
            )
            del frame
            self.send(answer, data)
        except Exception as exc:
            log.warning("encode failed", extra={"event": "encode_failed", "detail": repr(exc)})
            self._error(request.id, "render_failed", "encoding the image failed")
        finally:
            self._encode_slots.release()


def process_main(conn: Connection, environment_dirs: tuple[str, ...], encoders: int) -> None:
    """Entry point of the render process (multiprocessing ``spawn``)."""
    faulthandler.enable()  # a native fault prints the Python stacks of every thread to stderr
    configure_malloc()
    configure_inherited_logging()  # the service's format (JSON lines or not), warnings included
    # The service drains and then sends a StopRequest; a Ctrl-C to the terminal's process group
    # must not kill the renderer while the service is still answering frames. SIGTERM keeps its
    # default (the service's own exit path terminates leftover processes with it); under
    # systemd use KillMode=mixed so only the service gets the first SIGTERM.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    process = RenderProcess(conn, environment_dirs, encoders)
    try:
        process.run()
    finally:
        conn.close()
