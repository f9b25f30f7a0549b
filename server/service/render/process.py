"""The renderer process: owns the GL context, renders and encodes; the service supervises it.

`RenderWorker` (worker.py) starts this module's `child_main` with multiprocessing's ``spawn``
context (a fresh interpreter: nothing is forked, least of all an EGL context). The child creates
the `GLContext` and `SurfaceRenderer` on its main thread, which is the only thread that touches
GL, renders each job it is sent, and encodes PNG/EXR on its own encoder threads, overlapping the
next render. A native fault here (a segfault in a driver, an encoder or the allocator) ends this
process only: the service answers the frames it had sent ``render_failed`` and starts another.

The pipe between them (`multiprocessing.connection.Connection`):

* service -> child, trusted (the child is our own code): a pickled tuple, then the arrays' raw
  bytes with ``send_bytes`` (no pickling copy): ``("frame", id, scene, format, fault, arrays)``
  where ``arrays`` lists ``(name, dtype, shape)`` of the buffers that follow; ``("warm", id,
  scene)``; ``("stop",)``.
* child -> service: *never pickled* (a child whose memory may be corrupt must not be able to
  make the service run code): a JSON header with ``send_bytes``, followed by the image bytes
  when ``"data": true``. Types: ``ready``, ``startup_failed``, ``image``, ``error``, ``warm``.
  Every answer carries ``rss`` (the child's resident bytes) and ``rebuilt`` (the GL context was
  rebuilt after a GL error).

``fault`` is the service's fault injection for tests (`worker.FAULT_INJECTION_ENV`):
``"gl_error"`` raises a GL error inside the render step, ``"crash"`` raises SIGSEGV in this
process (a real native fault, as `faulthandler` produces it).
"""

from __future__ import annotations

import contextlib
import faulthandler
import json
import os
import signal
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from multiprocessing.connection import Connection
from typing import Any

import numpy as np

#: Page size for reading /proc/self/statm.
_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def rss_bytes() -> int:
    """Resident set size of this process (Linux /proc; 0 elsewhere)."""
    try:
        with open("/proc/self/statm") as handle:
            return int(handle.read().split()[1]) * _PAGE
    except (OSError, ValueError, IndexError):
        return 0


class _Child:
    def __init__(self, conn: Connection, environment_dirs: tuple[str, ...], encoders: int) -> None:
        self.conn = conn
        self.environment_dirs = environment_dirs
        self._send_lock = threading.Lock()
        self._encoders = ThreadPoolExecutor(encoders, thread_name_prefix="sphrender-encode")
        self._encode_slots = threading.BoundedSemaphore(2 * encoders)
        self._gl: Any = None
        self._renderer: Any = None
        self._rebuilt = False
        self._recv_ms = 0.0

    # -- pipe -----------------------------------------------------------------------------------

    def send(self, header: dict[str, Any], data: bytes | None = None) -> None:
        header["rss"] = rss_bytes()
        header["data"] = data is not None
        message = json.dumps(header, allow_nan=False).encode("utf-8")
        with self._send_lock:
            self.conn.send_bytes(message)
            if data is not None:
                self.conn.send_bytes(data)

    # -- GL -------------------------------------------------------------------------------------

    def open(self) -> None:
        from sphrender.server.engine.gpu.gl_context import GLContext
        from sphrender.server.engine.renderer import SurfaceRenderer

        self._gl = GLContext()
        self._renderer = SurfaceRenderer(self._gl, environment_dirs=self.environment_dirs)

    def close(self) -> None:
        renderer, gl = self._renderer, self._gl
        self._renderer = self._gl = None
        for thing in (renderer, gl):
            if thing is not None:
                # a broken context may fail to release; it is discarded anyway
                with contextlib.suppress(Exception):
                    thing.release()

    def rebuild(self) -> None:
        self.close()
        self._rebuilt = True
        try:
            self.open()
        except Exception:
            self._renderer = None  # retried by the next job

    def warm(self, scene: Any) -> None:
        from sphrender.core.frame import make_frame

        positions = np.array([scene.camera.target], dtype=np.float64)
        radii = np.array([scene.particles.radius], dtype=np.float32)
        self._renderer.render(make_frame(positions, radii=radii), scene)

    # -- jobs -----------------------------------------------------------------------------------

    def run(self) -> None:
        from sphrender.server.scene import Scene

        try:
            self.open()
            start = time.perf_counter()
            self.warm(Scene())
        except BaseException as exc:
            self.send({"type": "startup_failed", "error": f"{type(exc).__name__}: {exc}"})
            return
        self.send(
            {
                "type": "ready",
                "pid": os.getpid(),
                "gl_renderer": self._gl.renderer,
                "gl_version": self._gl.version,
                "max_image_side": self._gl.limits.max_image_side,
                "warm_ms": round((time.perf_counter() - start) * 1e3, 1),
            }
        )
        try:
            while True:
                try:
                    message = self.conn.recv()
                except (EOFError, OSError):
                    break  # the service is gone: so are we
                if message[0] == "stop":
                    break
                if message[0] == "warm":
                    self._warm_job(message[1], message[2])
                elif message[0] == "frame":
                    _kind, job_id, scene, fmt, fault, specs = message
                    start = time.perf_counter()
                    arrays = {
                        name: np.frombuffer(self.conn.recv_bytes(), dtype=dtype).reshape(shape)
                        for name, dtype, shape in specs
                    }
                    self._recv_ms = (time.perf_counter() - start) * 1e3
                    self._frame_job(job_id, scene, fmt, fault, arrays)
        finally:
            self._encoders.shutdown(wait=True)
            self.close()

    def _flags(self) -> dict[str, Any]:
        rebuilt, self._rebuilt = self._rebuilt, False
        return {"rebuilt": rebuilt}

    def _warm_job(self, job_id: int, scene: Any) -> None:
        from sphrender.core.errors import InputError

        error: dict[str, Any] | None = None
        if self._renderer is None:
            self.rebuild()
        try:
            self.warm(scene)
        except InputError as exc:
            error = {"input": True, "field": exc.field, "message": exc.message}
        except Exception as exc:
            error = {"input": False, "field": None, "message": f"{type(exc).__name__}: {exc}"}
            self.rebuild()
        self.send({"type": "warm", "id": job_id, "error": error, **self._flags()})

    def _frame_job(
        self, job_id: int, scene: Any, fmt: str, fault: str | None, arrays: dict[str, Any]
    ) -> None:
        from sphrender.core.errors import InputError
        from sphrender.core.frame import ParticleFrame
        from sphrender.server.output.local import render_for_output

        if self._renderer is None:
            self.rebuild()
            if self._renderer is None:
                self._error(job_id, "render_failed", "the GL context is unavailable")
                return
        particles = ParticleFrame(
            positions=arrays["positions"],
            densities=arrays.get("densities"),
            radii=arrays.get("radii"),
            temperatures=arrays.get("temperatures"),
        )
        recv_ms = self._recv_ms
        self._encode_slots.acquire()  # bounded backlog of rendered frames waiting to encode
        handed_off = False
        try:
            if fault == "crash":
                faulthandler._sigsegv()  # type: ignore[attr-defined]  # a real SIGSEGV (test hook)
            if fault == "gl_error":
                import moderngl

                self._renderer.gl.ctx.finish()
                raise moderngl.Error("injected GL fault")
            frame, stats = render_for_output(self._renderer, particles, scene, fmt)  # type: ignore[arg-type]
        except InputError as exc:
            self._error(job_id, "bad_input", exc.message, exc.field)
        except Exception as exc:
            message = (
                f"rendering failed ({type(exc).__name__}: {exc}); the GL context was rebuilt, "
                "later frames are unaffected"
            )
            self.rebuild()
            self._error(job_id, "render_failed", message)
        else:
            self._encoders.submit(self._encode, job_id, scene, fmt, frame, stats, recv_ms)
            handed_off = True
        finally:
            if not handed_off:
                self._encode_slots.release()

    def _error(self, job_id: int, code: str, message: str, field: str | None = None) -> None:
        header = {"type": "error", "id": job_id, "code": code, "message": message}
        self.send({**header, "field": field, **self._flags()})

    def _encode(
        self, job_id: int, scene: Any, fmt: str, frame: Any, stats: Any, recv_ms: float
    ) -> None:
        from sphrender.server.output.local import encode_for_scene, raw_layout

        try:
            start = time.perf_counter()
            data = encode_for_scene(frame, scene, fmt)  # type: ignore[arg-type]
            timings = {**stats.stage_ms, "encode": (time.perf_counter() - start) * 1e3}
            header = {
                "type": "image",
                "id": job_id,
                "width": frame.width,
                "height": frame.height,
                "particles": stats.particles_in,
                "drawn": stats.particles_drawn,
                "timings_ms": timings,
                "host_ms": stats.host_ms,
                "recv_ms": recv_ms,
                "arrays": raw_layout(scene, fmt),  # type: ignore[arg-type]
                "notes": [{"field": n.field, "message": n.message} for n in stats.notes],
            }
            del frame
            self.send(header, data)
        except Exception as exc:
            self._error(job_id, "render_failed", f"encoding failed: {exc}")
        finally:
            self._encode_slots.release()


def child_main(conn: Connection, environment_dirs: tuple[str, ...], encoders: int) -> None:
    """Entry point of the renderer process (multiprocessing ``spawn``)."""
    faulthandler.enable()  # a native fault prints the Python stacks of every thread to stderr
    # The service drains and then sends "stop"; a Ctrl-C to the terminal's process group must
    # not kill the renderer while the service is still answering frames. SIGTERM keeps its
    # default (the service's own exit path terminates leftover children with it); under
    # systemd use KillMode=mixed so only the service gets the first SIGTERM.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    child = _Child(conn, environment_dirs, encoders)
    try:
        child.run()
    finally:
        conn.close()
