"""Coverage band: where the anti-aliasing coverage is read, so the coverage pass only works there.

The shade pass reads the splat's sub-pixel coverage at two kinds of pixels only: one without a
surface next to one with a surface (it shows that surface, blended by its coverage) and one
with a surface next to one without (alpha = coverage); inside a surface it takes 1, over open
background nothing. The coverage quads of the particles near a silhouette mostly land inside
the surface, so the coverage pass (passes/splat.py `_draw_coverage`) discards every fragment
outside this mask before its ray-cone work: on llvmpipe that was most of the pass.

The same draw starts the coverage target at 1 inside surfaces (0 elsewhere; the coverage pass
then blends MAX over it), so the shade pass sees coverage 1 there and skips its own 9-tap test
for a neighbour without surface: the same image, one test per pixel less.

The mask is that of the bulk splat's depth. The passes after it only add surface (closed gaps,
exact droplets) and never remove any, so a pixel outside the mask stays one whose coverage is
ignored, except next to a droplet: the droplets' own coverage is drawn without the mask.

Shader: `shaders/splat/coverage_band.frag.glsl` (8-neighbours, the shade pass's own tests).
Owns: the R32F mask per image size and the framebuffer onto it and the coverage target;
released with the splat pass.
"""

from __future__ import annotations

import moderngl

from sphrender.server.engine.geometry.screen_box import ScreenBox
from sphrender.server.engine.gpu.draw import (
    FramebufferOn,
    PerSize,
    Target,
    clear_and_scissor,
    set_scissor,
)
from sphrender.server.engine.passes.context import FULLSCREEN_VERT, PassContext

SHADER = "splat/coverage_band.frag.glsl"


class _BandTargets:
    def __init__(self, ctx: moderngl.Context, size: tuple[int, int]) -> None:
        self.band = Target.float(ctx, size, 1)
        self.with_coverage = FramebufferOn(ctx)  # the mask + the splat's coverage target

    def release(self) -> None:
        self.with_coverage.release()
        self.band.release()


class CoverageBand:
    def __init__(self, context: PassContext) -> None:
        self._context = context
        self._targets = PerSize(lambda size: _BandTargets(context.gl.ctx, size))

    def run(
        self, depth: moderngl.Texture, coverage: moderngl.Texture, box: ScreenBox | None
    ) -> moderngl.Texture:
        """The mask (1 = the coverage is read here) of the splat's eye depth `depth`, drawn
        inside `box` (which holds every surface pixel and its neighbours), 0 outside it; the
        coverage target `coverage` (cleared to 0) gets 1 inside surfaces, 0 in the mask."""
        targets = self._targets.get(depth.size)
        program = self._context.programs.get(FULLSCREEN_VERT, SHADER, samplers={"u_depth": 0})
        depth.use(0)
        clear_and_scissor(targets.band.fbo, box)
        fbo = targets.with_coverage.get(targets.band.texture, coverage)
        set_scissor(fbo, box)
        fbo.use()
        self._context.fullscreen.draw(program)
        set_scissor(fbo, None)
        set_scissor(targets.band.fbo, None)
        return targets.band.texture

    def release(self) -> None:
        self._targets.release()
