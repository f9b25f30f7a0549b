"""Coverage band: where the anti-aliasing coverage is read, so the coverage pass only works there.

The shade pass reads the splat's sub-pixel coverage at two kinds of pixels only: one without a
surface next to one with a surface (it shows that surface, blended by its coverage) and one
with a surface next to one without (alpha = coverage); inside a surface it takes 1, over open
background nothing. The coverage quads of the particles near a silhouette mostly land inside
the surface, so the coverage pass (passes/splat.py `_draw_coverage`) must not work outside this
mask. The mask is a depth buffer (1 in the band, 0 elsewhere) that the coverage draws test
against with early fragment tests: a fragment outside is rejected before the shader runs. On
the 100k ball at 1280x720 98 % of the coverage quads' 0.9M fragments lie outside; as a texture
fetch and a discard in the shader they took 12 ms of llvmpipe's time.

The same draw starts the coverage target at 1 inside surfaces (0 elsewhere; the coverage pass
then blends MAX over it), so the shade pass sees coverage 1 there and skips its own 9-tap test
for a neighbour without surface: the same image, one test per pixel less.

The mask is that of the bulk splat's depth. The passes after it only add surface (closed gaps,
exact droplets) and never remove any, so a pixel outside the mask stays one whose coverage is
ignored, except next to a droplet: the droplets' own coverage is drawn without the mask.

Shader: `shaders/splat/coverage_band.frag.glsl` (8-neighbours, the shade pass's own tests).
Owns: the mask (a depth renderbuffer) per image size and the framebuffer of it and the splat's
coverage target, which the coverage draws use too; released with the splat pass.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import moderngl

from sphrender.server.engine.geometry.screen_box import ScreenBox
from sphrender.server.engine.gpu.draw import (
    FramebufferOn,
    PerSize,
    set_scissor,
)
from sphrender.server.engine.passes.context import FULLSCREEN_VERT, PassContext

SHADER = "splat/coverage_band.frag.glsl"


class _BandTargets:
    def __init__(self, ctx: moderngl.Context, size: tuple[int, int]) -> None:
        self.band = ctx.depth_renderbuffer(size)
        self.with_coverage = FramebufferOn(ctx, depth=self.band)  # the splat's coverage target

    def release(self) -> None:
        self.with_coverage.release()
        self.band.release()


class CoverageBand:
    def __init__(self, context: PassContext) -> None:
        self._context = context
        self._targets = PerSize(lambda size: _BandTargets(context.gl.ctx, size))

    def run(
        self, depth: moderngl.Texture, coverage: moderngl.Texture, box: ScreenBox | None
    ) -> moderngl.Framebuffer:
        """The mask of the splat's eye depth `depth`, drawn inside `box` (which holds every
        surface pixel and its neighbours), none outside it; the coverage target `coverage`
        gets 1 inside surfaces, 0 elsewhere. Returns the framebuffer of `coverage` and the mask,
        for the coverage draws (`gate`)."""
        targets = self._targets.get(depth.size)
        program = self._context.programs.get(FULLSCREEN_VERT, SHADER, samplers={"u_depth": 0})
        depth.use(0)
        fbo = targets.with_coverage.get(coverage)
        ctx = self._context.gl.ctx
        fbo.depth_mask = True
        set_scissor(fbo, None)
        with self._context.gl.clock:
            fbo.clear(0.0, 0.0, 0.0, 0.0, depth=0.0)  # coverage 0, no band
        set_scissor(fbo, box)
        fbo.use()
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.depth_func = "1"  # always: the shader's depth is the mask
        try:
            self._context.fullscreen.draw(program)
        finally:
            ctx.depth_func = "<"
            ctx.disable(moderngl.DEPTH_TEST)
            set_scissor(fbo, None)
        return fbo

    def release(self) -> None:
        self._targets.release()


@contextmanager
def gate(ctx: moderngl.Context, fbo: moderngl.Framebuffer) -> Iterator[None]:
    """Draws inside reach only the band of `fbo` (`CoverageBand.run`'s): the depth test
    against the mask, no depth writes; the shaders ask for early fragment tests."""
    fbo.depth_mask = False
    ctx.enable(moderngl.DEPTH_TEST)
    try:
        yield
    finally:
        ctx.disable(moderngl.DEPTH_TEST)
        fbo.depth_mask = True
