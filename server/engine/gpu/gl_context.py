"""The headless EGL OpenGL context and its single owner thread.

One thread creates the context and is the only one allowed to touch it (or any GPU object made
from it): that is the render thread in the service and the main thread in the CLI. `GLContext`
records its owner and `check_owner()` raises if another thread tries to use it, which turns a
subtle driver crash into a clear programming error. GPU objects are released by their owner
(`SurfaceRenderer.release`) on that same thread, then the context itself.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import moderngl

from sphrender.server.engine.gpu.gl_clock import GLClock, own_on_this_thread
from sphrender.server.engine.gpu.gl_libraries import failure_message, resolve_libraries
from sphrender.server.engine.gpu.rasteriser_threads import batch_rasteriser_threads


class GLUnavailableError(RuntimeError):
    """No headless OpenGL 4.3+ context could be created (missing EGL/Mesa, or too old a GL)."""


@dataclass(frozen=True)
class GLLimits:
    max_texture_size: int
    max_viewport: tuple[int, int]
    max_renderbuffer_size: int

    @property
    def max_image_side(self) -> int:
        return min(self.max_texture_size, *self.max_viewport, self.max_renderbuffer_size)


#: The live context each thread owns (at most one, see GLContext.__init__).
_owned = threading.local()


class GLContext:
    """Owns a standalone moderngl context created through EGL (no display needed)."""

    REQUIRED_VERSION = 430  # storage buffers and compute shaders (the splat pulls its particles)

    def __init__(self, device_index: int = 0) -> None:
        """Raises RuntimeError when this thread already owns a live context: a new standalone
        context is made current on creation, so the first one's calls would reach the second
        (and, once that is released, no context at all: wrong images, then a driver crash)."""
        live: GLContext | None = getattr(_owned, "context", None)
        if live is not None and live._ctx is not None:
            raise RuntimeError(
                "this thread already owns a GL context; release it first (one thread owns at "
                "most one: a second one would take over the first's calls) or create the new "
                "one on another thread"
            )
        libegl, libgl = resolve_libraries()
        try:
            # moderngl's stub types every **setting as a dict; the call takes plain values.
            create: Callable[..., moderngl.Context] = moderngl.create_context
            ctx = create(
                standalone=True,
                backend="egl",
                require=self.REQUIRED_VERSION,
                device_index=device_index,
                libegl=libegl,
                libgl=libgl,
            )
        except Exception as exc:  # moderngl raises plain Exceptions for every EGL failure
            raise GLUnavailableError(failure_message(str(exc), libegl, libgl)) from None
        self._ctx: moderngl.Context | None = ctx
        self._owner = threading.get_ident()
        #: Time inside the GL calls that do the device's work (gl_clock.py).
        self.clock = GLClock()
        # Who bound the storage-buffer binding points last (see claim_storage_bindings).
        self._storage_owner: object | None = None
        own_on_this_thread(self.clock)
        info: dict[str, Any] = ctx.info
        self.renderer: str = str(info.get("GL_RENDERER", "unknown"))
        self.version: str = str(info.get("GL_VERSION", "unknown"))
        self.limits = GLLimits(
            max_texture_size=int(info["GL_MAX_TEXTURE_SIZE"]),
            max_viewport=tuple(int(v) for v in info["GL_MAX_VIEWPORT_DIMS"]),  # type: ignore[arg-type]
            max_renderbuffer_size=int(info["GL_MAX_RENDERBUFFER_SIZE"]),
        )
        #: llvmpipe worker threads under SCHED_BATCH (rasteriser_threads.py); 0 on a GPU.
        self.batch_rasteriser_threads = batch_rasteriser_threads() if self.is_software else 0
        _owned.context = self

    @property
    def ctx(self) -> moderngl.Context:
        """The moderngl context; only the owner thread may call this."""
        self.check_owner()
        if self._ctx is None:
            raise RuntimeError("the GL context has been released")
        return self._ctx

    @property
    def is_software(self) -> bool:
        return "llvmpipe" in self.renderer or "softpipe" in self.renderer

    def check_owner(self) -> None:
        if threading.get_ident() != self._owner:
            raise RuntimeError(
                "the GL context was used from a thread that does not own it; "
                "all GL work must run on the render thread"
            )

    def claim_storage_bindings(self, owner: object) -> bool:
        """Storage-buffer bindings are context state that several owners use (the splat's
        buffers, the display pass's table, another renderer on this context): True when
        `owner` must bind its buffers because someone else bound since its last claim."""
        if self._storage_owner is owner:
            return False
        self._storage_owner = owner
        return True

    def storage_bindings_disturbed(self, owner: object) -> None:
        """`owner` rebound one binding point outside a claim (a grown buffer): when that point
        may have been someone else's, nobody's bindings can be trusted any more."""
        if self._storage_owner is not owner:
            self._storage_owner = None

    def release_storage_claim(self, owner: object) -> None:
        """`owner` releases its buffers: its claim (if it is the latest) ends."""
        if self._storage_owner is owner:
            self._storage_owner = None

    def release(self) -> None:
        """Release the context. It is this thread's no longer even when the driver's release
        fails (a broken context is discarded: the service's render child then makes a new one)."""
        if self._ctx is not None:
            self.check_owner()
            ctx, self._ctx = self._ctx, None
            try:
                ctx.release()
            finally:
                if getattr(_owned, "context", None) is self:
                    _owned.context = None

    def __enter__(self) -> GLContext:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()
