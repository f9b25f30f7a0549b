"""Gap pass: closes the gaps a sparse sheet of particles leaves in the splatted depth, before
the smoothing (`[quality] close_gaps`).

A sheet or a spray of particles a little more than a diameter apart splats as beads, with the
background or the surface behind showing between them, where the fluid's surface (and an offline
reconstruction such as splashsurf's) spans the gap. The smoothing cannot join the beads: it
never averages across a depth discontinuity. This pass gives such a gap pixel the depth
interpolated between the nearer surface on both sides of it, when the two sides are at most
`close_gaps` particle radii apart on screen (projected at their depth) and in depth; a
background pixel must be enclosed along two of the four directions (a hole or a slit, not the
notch between two beads along a silhouette). Depths only get nearer, so no pixel the spheres
cover loses its surface. The rule in full: `shaders/gaps/close_gaps.frag.glsl`.

Shaders: `shaders/gaps/gap_tiles.frag.glsl` (the nearest depth and whether there is a depth
edge, per 4 x 4 and per 16 x 16 pixels, which bound the search and skip pixels with no edge or
no nearer surface around: the interior of a surface stops there),
`shaders/gaps/close_gaps.frag.glsl`.
Owns: the two tile targets and the closed-depth target (R32F), per image size.
"""

from __future__ import annotations

import moderngl

from sphrender.server.engine.geometry.screen_box import ScreenBox
from sphrender.server.engine.gpu.draw import (
    PerSize,
    Target,
    clear_and_scissor,
    set_if_used,
    set_scissor,
)
from sphrender.server.engine.passes.context import FULLSCREEN_VERT, PassContext

TILES_SHADER = "gaps/gap_tiles.frag.glsl"
CLOSE_SHADER = "gaps/close_gaps.frag.glsl"
#: The widest gap closed, in pixels (close_gaps.frag.glsl's define; its tiles are 4 and 16 px,
#: so a 16-pixel reach stays within the 3 x 3 coarse tiles around a pixel).
GAP_MAX_PX = 16
#: A surface nearer than a pixel's by more than this many particle radii is in front of it (the
#: normals pass's edge jump: a step beyond it is a discontinuity, not a slope).
EDGE_JUMP_RADII = 4.0


class _GapTargets:
    def __init__(self, ctx: moderngl.Context, size: tuple[int, int]) -> None:
        fine = ((size[0] + 3) // 4, (size[1] + 3) // 4)
        coarse = ((fine[0] + 3) // 4, (fine[1] + 3) // 4)
        self.tiles4 = Target.float(ctx, fine, 2)  # nearest depth, edge flag
        self.tiles16 = Target.float(ctx, coarse, 2)
        self.closed = Target.float(ctx, size, 1)

    def release(self) -> None:
        for target in (self.tiles4, self.tiles16, self.closed):
            target.release()


class GapPass:
    def __init__(self, context: PassContext) -> None:
        self._context = context
        self._targets = PerSize(lambda size: _GapTargets(context.gl.ctx, size))

    def run(
        self,
        depth: moderngl.Texture,
        *,
        px_per_unit: float,
        particle_radius: float,
        gap_radii: float,
        box: ScreenBox | None = None,
    ) -> moderngl.Texture:
        """The eye-depth image `depth` (0 = background) with its gaps of at most `gap_radii`
        particle radii closed (`depth` itself when `gap_radii` is 0). With a `box`, only inside
        it, on a target cleared outside it (a closed gap lies between two surface pixels, so
        inside the box of the surface)."""
        if gap_radii <= 0.0:
            return depth
        targets = self._targets.get(depth.size)
        programs, draw = self._context.programs, self._context.fullscreen.draw
        edge_jump = EDGE_JUMP_RADII * particle_radius
        sources = ((depth, targets.tiles4, 1), (targets.tiles4.texture, targets.tiles16, 0))
        for source, target, from_depth in sources:
            tiles = programs.get(FULLSCREEN_VERT, TILES_SHADER, {"FROM_DEPTH": from_depth})
            set_if_used(tiles, "u_source", 0)
            set_if_used(tiles, "u_edge_jump", edge_jump)
            source.use(0)
            target.fbo.use()
            draw(tiles)
        close = programs.get(FULLSCREEN_VERT, CLOSE_SHADER, {"GAP_MAX_PX": GAP_MAX_PX})
        set_if_used(close, "u_depth", 0)
        set_if_used(close, "u_tiles4", 1)
        set_if_used(close, "u_tiles16", 2)
        set_if_used(close, "u_focal_px", px_per_unit)
        set_if_used(close, "u_particle_radius", particle_radius)
        set_if_used(close, "u_gap_radii", gap_radii)
        set_if_used(close, "u_edge_jump", edge_jump)
        depth.use(0)
        targets.tiles4.texture.use(1)
        targets.tiles16.texture.use(2)
        clear_and_scissor(targets.closed.fbo, box)
        targets.closed.fbo.use()
        draw(close)
        set_scissor(targets.closed.fbo, None)
        return targets.closed.texture

    def release(self) -> None:
        self._targets.release()
