"""Small GL building blocks every pass uses: float render targets, the attribute-less
full-screen triangle, scissor rectangles, image bytes (uniform uploads: uniforms.py).

Everything here runs on the GL owner thread; each object is released by whoever created it
(see ARCHITECTURE.md, "Threads and GPU objects").
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, Protocol, TypeVar

import moderngl
import numpy as np
import numpy.typing as npt

from sphrender.server.engine.geometry.screen_box import ScreenBox
from sphrender.server.engine.gpu.gl_clock import thread_clock
from sphrender.server.engine.gpu.gl_context import GLContext


def float_texture(
    ctx: moderngl.Context, size: tuple[int, int], components: int, *, clamp: bool = True
) -> moderngl.Texture:
    """An RGBA32F-family texture (`components` channels) with nearest filtering; `clamp` turns
    off wrapping (reads outside stay at the edge)."""
    texture = ctx.texture(size, components, dtype="f4")
    texture.filter = (moderngl.NEAREST, moderngl.NEAREST)
    if clamp:
        texture.repeat_x = texture.repeat_y = False
    return texture


@dataclass(frozen=True)
class Target:
    """A texture and the framebuffer that renders into it."""

    texture: moderngl.Texture
    fbo: moderngl.Framebuffer

    @classmethod
    def float(
        cls, ctx: moderngl.Context, size: tuple[int, int], components: int, *, clamp: bool = True
    ) -> Target:
        texture = float_texture(ctx, size, components, clamp=clamp)
        return cls(texture, ctx.framebuffer([texture]))

    def release(self) -> None:
        self.fbo.release()
        self.texture.release()


class Releasable(Protocol):
    def release(self) -> None: ...


R = TypeVar("R", bound=Releasable)


class PerSize(Generic[R]):
    """One GPU resource (a target, a set of targets) for the current image size: built on first
    use, released and rebuilt only when the size changes, released with its owner."""

    def __init__(self, build: Callable[[tuple[int, int]], R]) -> None:
        self._build = build
        self._size: tuple[int, int] | None = None
        self._resource: R | None = None

    def get(self, size: tuple[int, int]) -> R:
        if self._resource is None or self._size != size:
            self.release()
            self._resource = self._build(size)
            self._size = size
        return self._resource

    def release(self) -> None:
        if self._resource is not None:
            self._resource.release()
            self._resource = None
            self._size = None


class FramebufferOn:
    """A framebuffer on textures someone else owns (another pass's target), kept while they are
    the same objects and rebuilt when one changes (keyed by identity: GL names are reused);
    `depth`: a depth attachment the caller owns, the same for every framebuffer built."""

    def __init__(self, ctx: moderngl.Context, depth: moderngl.Renderbuffer | None = None) -> None:
        self._ctx = ctx
        self._depth = depth
        self._textures: tuple[moderngl.Texture, ...] = ()
        self._fbo: moderngl.Framebuffer | None = None

    def get(self, *textures: moderngl.Texture) -> moderngl.Framebuffer:
        if (
            self._fbo is None
            or len(textures) != len(self._textures)
            or any(a is not b for a, b in zip(textures, self._textures, strict=True))
        ):
            self.release()
            self._fbo = self._ctx.framebuffer(list(textures), self._depth)
            self._textures = textures
        return self._fbo

    def release(self) -> None:
        if self._fbo is not None:
            self._fbo.release()
            self._fbo = None
            self._textures = ()


class FullscreenTriangle:
    """One vertex array per program for the attribute-less full-screen triangle
    (`shaders/common/fullscreen.vert.glsl`), shared by the passes that draw one."""

    def __init__(self, gl: GLContext) -> None:
        self._gl = gl
        self._vaos: dict[moderngl.Program, moderngl.VertexArray] = {}  # keyed by identity

    def draw(self, program: moderngl.Program) -> None:
        """Draw the triangle with `program` into the bound framebuffer."""
        vao = self._vaos.get(program)
        if vao is None:
            vao = self._gl.ctx.vertex_array(program, [])
            self._vaos[program] = vao
        self._gl.clock.call(vao.render, moderngl.TRIANGLES, vertices=3)

    def release(self) -> None:
        for vao in self._vaos.values():
            vao.release()
        self._vaos.clear()


def set_scissor(fbo: moderngl.Framebuffer, box: ScreenBox | None) -> None:
    """Restrict passes into `fbo` to `box`; None lifts the restriction (moderngl accepts None
    at run time, its type stub only lists the tuple)."""
    fbo.scissor = box  # type: ignore[assignment]


def clear_and_scissor(fbo: moderngl.Framebuffer, box: ScreenBox | None) -> None:
    """Clear the whole target, then restrict the next passes into it to `box` (None: all)."""
    set_scissor(fbo, None)
    thread_clock().call(fbo.clear, 0.0, 0.0, 0.0, 0.0)
    set_scissor(fbo, box)


def image_bytes(image: npt.NDArray[np.floating]) -> bytes:
    """A numpy image (rows top first) as the bytes of a float32 GL texture (rows bottom first)."""
    return np.ascontiguousarray(image[::-1], dtype=np.float32).tobytes()


def read_image(data: bytes, width: int, height: int) -> npt.NDArray[np.float32]:
    """A single-channel float32 texture's bytes as a numpy image, rows top first."""
    out = np.frombuffer(data, dtype=np.float32).reshape(height, width)
    return np.ascontiguousarray(out[::-1])
