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

Shaders: `shaders/gaps/gap_tiles.frag.glsl` (the nearest depth and the nearest jump front, a
pixel a walk can stop on, per 4 x 4 pixels), `shaders/gaps/gap_dilate.frag.glsl` (the same over
+-16 pixels, in two 1-D passes), which bound the walks and skip the pixels with no jump front
nearer than themselves around (the inside of a surface, the slope inside a silhouette, open
background: most pixels stop there), `shaders/gaps/close_gaps.frag.glsl`.
The y dilation also keeps, per tile, the nearest jump front on each side of it along its row and
column and in its four quadrants: a direction can enclose a pixel only with a nearer front on
both sides along it, so only those directions are walked (on the 100k ball at 1280x720, 22k of
the 81k pixels near a front walk at all, and 51k direction walks remain of ~176k).
Owns: five tile targets (RG32F and RGBA32F, a quarter of the image per side) and the
closed-depth target (R32F), per image size.
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
from sphrender.server.engine.gpu.uniforms import set_group, set_if_used
from sphrender.server.engine.passes.context import FULLSCREEN_VERT, PassContext

TILES_SHADER = "gaps/gap_tiles.frag.glsl"
DILATE_SHADER = "gaps/gap_dilate.frag.glsl"
CLOSE_SHADER = "gaps/close_gaps.frag.glsl"
#: The widest gap closed, in pixels (close_gaps.frag.glsl's define); the 4-pixel tiles are
#: dilated by GAP_MAX_PX / 4 tiles, so they cover every pixel a walk can reach.
GAP_MAX_PX = 16
GAP_DILATE = GAP_MAX_PX // 4
_DILATE_DEFINES = ({"AXIS": 0, "GAP_DILATE": GAP_DILATE}, {"AXIS": 1, "GAP_DILATE": GAP_DILATE})
#: A surface nearer than a pixel's by more than this many particle radii is in front of it (the
#: normals pass's edge jump: a step beyond it is a discontinuity, not a slope).
EDGE_JUMP_RADII = 4.0


class _GapTargets:
    def __init__(self, ctx: moderngl.Context, size: tuple[int, int]) -> None:
        tiles = ((size[0] + 3) // 4, (size[1] + 3) // 4)
        # Nearest depth and nearest jump front per tile (`raw`); dilated along x (with the
        # fronts on either side, `along_x`); then along y (one draw into three targets:
        # `dilated`, `axes`, `diagonals`; gap_dilate.frag.glsl).
        self.raw = Target.float(ctx, tiles, 2)
        self.along_x = Target.float(ctx, tiles, 4)
        self.dilated = Target.float(ctx, tiles, 2)
        self.axes = Target.float(ctx, tiles, 4)
        self.diagonals = Target.float(ctx, tiles, 4)
        self.along_y = ctx.framebuffer(
            [self.dilated.texture, self.axes.texture, self.diagonals.texture]
        )
        self.closed = Target.float(ctx, size, 1)
        self._ctx = ctx
        self.kelvin: Target | None = None  # the filled kelvin, on the first frame with them
        self.both: moderngl.Framebuffer | None = None  # closed depth + filled kelvin
        self._back = FramebufferOn(ctx)  # onto the splat's kelvin texture

    def with_kelvin(self) -> tuple[moderngl.Framebuffer, Target]:
        if self.kelvin is None or self.both is None:
            self.kelvin = Target.float(self._ctx, self.closed.texture.size, 1)
            self.both = self._ctx.framebuffer([self.closed.texture, self.kelvin.texture])
        return self.both, self.kelvin

    def back_into(self, temperature: moderngl.Texture) -> moderngl.Framebuffer:
        """A framebuffer on `temperature`, to blit the filled kelvin back (float, exact: a copy
        into the texture itself would convert it), kept while the texture is the same."""
        return self._back.get(temperature)

    def release(self) -> None:
        self._back.release()
        self.along_y.release()
        tiles = (self.raw, self.along_x, self.dilated, self.axes, self.diagonals)
        for target in (*tiles, self.closed, self.kelvin):
            if target is not None:
                target.release()
        if self.both is not None:
            self.both.release()


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
        temperature: moderngl.Texture | None = None,
    ) -> moderngl.Texture:
        """The eye-depth image `depth` (0 = background) with its gaps of at most `gap_radii`
        particle radii closed (`depth` itself when `gap_radii` is 0). With a `box`, only inside
        it, on a target cleared outside it (a closed gap lies between two surface pixels, so
        inside the box of the surface). With the splat's `temperature` (kelvin), the closed
        pixels get the kelvin interpolated alike, written back into `temperature`."""
        if gap_radii <= 0.0:
            return depth
        targets = self._targets.get(depth.size)
        programs, draw = self._context.programs, self._context.fullscreen.draw
        edge_jump = EDGE_JUMP_RADII * particle_radius
        tiles = programs.get(FULLSCREEN_VERT, TILES_SHADER)
        set_group(tiles, "frame", edge_jump, lambda: {"u_source": 0, "u_edge_jump": edge_jump})
        depth.use(0)
        tile_box = None if box is None else _tile_box(box, targets.raw.texture.size)
        clear_and_scissor(targets.raw.fbo, tile_box)
        targets.raw.fbo.use()
        draw(tiles)
        set_scissor(targets.raw.fbo, None)
        along_x = programs.get(FULLSCREEN_VERT, DILATE_SHADER, _DILATE_DEFINES[0])
        set_if_used(along_x, "u_tiles", 0)
        targets.raw.texture.use(0)
        targets.along_x.fbo.use()
        draw(along_x)
        along_y = programs.get(FULLSCREEN_VERT, DILATE_SHADER, _DILATE_DEFINES[1])
        set_group(along_y, "units", None, lambda: {"u_tiles": 0, "u_raw": 1})
        targets.along_x.texture.use(0)
        targets.raw.texture.use(1)
        targets.along_y.use()
        draw(along_y)
        defines = {"GAP_MAX_PX": GAP_MAX_PX, "HAS_TEMPERATURE": int(temperature is not None)}
        close = programs.get(FULLSCREEN_VERT, CLOSE_SHADER, defines)
        set_group(
            close,
            "frame",
            (px_per_unit, particle_radius, gap_radii),
            lambda: {
                "u_depth": 0,
                "u_tiles": 1,
                "u_temperature": 2,
                "u_axes": 3,
                "u_diagonals": 4,
                "u_focal_px": px_per_unit,
                "u_particle_radius": particle_radius,
                "u_gap_radii": gap_radii,
                "u_edge_jump": edge_jump,
            },
        )
        depth.use(0)
        targets.dilated.texture.use(1)
        targets.axes.texture.use(3)
        targets.diagonals.texture.use(4)
        fbo, kelvin = targets.closed.fbo, None
        if temperature is not None:
            fbo, kelvin = targets.with_kelvin()
            temperature.use(2)
        clear_and_scissor(fbo, box)
        fbo.use()
        draw(close)
        set_scissor(fbo, None)
        if temperature is not None and kelvin is not None:
            with self._context.gl.clock:
                self._context.gl.ctx.copy_framebuffer(targets.back_into(temperature), kelvin.fbo)
        return targets.closed.texture

    def release(self) -> None:
        self._targets.release()


def _tile_box(box: ScreenBox, tiles: tuple[int, int]) -> ScreenBox:
    """The tiles covering `box` and one more on each side (the edge between the box's outer
    pixels and the background next to them is flagged in the outer tiles), clipped."""
    x, y, width, height = box
    x0, y0 = max(x // 4 - 1, 0), max(y // 4 - 1, 0)
    x1 = min((x + width + 3) // 4 + 1, tiles[0])
    y1 = min((y + height + 3) // 4 + 1, tiles[1])
    return (x0, y0, x1 - x0, y1 - y0)
