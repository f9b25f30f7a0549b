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
After the smoothing, `close_again` applies the rule once more to the background pixels alone
(walks of at most PINHOLE_MAX_PX), over the same tiles with the same bounds: pinholes. Where a
view runs along a lattice's channels (a plate of solid particles, a centred camera), a ray
between the spheres passes through every layer: the splat shows background between walls of the
lower layers. The first pass closes the walls (a farther surface between nearer ones) but not
the hole, whose sides lie on different layers, so no direction encloses it; after the smoothing
they are one surface. A 3-layer plate seen at 480x270 showed 16-32 such holes per view (the demo
at 960x540: 7), none after; ~2 ms of the 100k ball's 1280x720 frame on llvmpipe.
The close pass runs only on the tiles where some pixel may be closed at all (the same tests at
the tile's most permissive depths, gap_dilate.frag.glsl): the input is copied (a blit), then
one 4 x 4-pixel point per such tile is drawn (`shaders/gaps/close_tiles.vert.glsl`), so the
rest of the image costs no shader work.
Owns: five tile targets (RGBA32F, a quarter of the image per side), the closed-depth target
(R32F) and, on frames with temperatures, the filled kelvin (R32F), per image size; the
attribute-less vertex arrays of the tile points.
"""

from __future__ import annotations

from collections.abc import Callable

import moderngl

from sphrender.server.engine.geometry.screen_box import ScreenBox
from sphrender.server.engine.gpu.draw import (
    FramebufferOn,
    PerSize,
    Target,
    clear_and_scissor,
    set_scissor,
)
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.gpu.uniforms import set_group
from sphrender.server.engine.passes.context import FULLSCREEN_VERT, PassContext

TILES_SHADER = "gaps/gap_tiles.frag.glsl"
DILATE_SHADER = "gaps/gap_dilate.frag.glsl"
CLOSE_SHADER = "gaps/close_gaps.frag.glsl"
CLOSE_TILES_VERT = "gaps/close_tiles.vert.glsl"
#: The close shader's texture units (`_close` binds the textures to them).
_CLOSE_UNITS = {"u_depth": 0, "u_tiles": 1, "u_temperature": 2, "u_axes": 3, "u_diagonals": 4}
#: The widest gap closed, in pixels (close_gaps.frag.glsl's define); the 4-pixel tiles are
#: dilated by GAP_MAX_PX / 4 tiles, so they cover every pixel a walk can reach.
GAP_MAX_PX = 16
#: close_again's walks (pinholes left after the smoothing are a few pixels wide).
PINHOLE_MAX_PX = 8
GAP_DILATE = GAP_MAX_PX // 4
_DILATE_DEFINES = ({"AXIS": 0, "GAP_DILATE": GAP_DILATE}, {"AXIS": 1, "GAP_DILATE": GAP_DILATE})
#: A surface nearer than a pixel's by more than this many particle radii is in front of it (the
#: normals pass's edge jump: a step beyond it is a discontinuity, not a slope).
EDGE_JUMP_RADII = 4.0


class _GapTargets:
    def __init__(self, ctx: moderngl.Context, size: tuple[int, int]) -> None:
        tiles = ((size[0] + 3) // 4, (size[1] + 3) // 4)
        # Per tile: nearest depth, nearest jump front, farthest depth, has background (`raw`);
        # dilated along x (with the fronts on either side, `along_x`); then along y (one draw
        # into three targets: `dilated`, `axes`, `diagonals`; gap_dilate.frag.glsl).
        self.raw = Target.float(ctx, tiles, 4)
        self.along_x = Target.float(ctx, tiles, 4)
        self.dilated = Target.float(ctx, tiles, 4)
        self.axes = Target.float(ctx, tiles, 4)
        self.diagonals = Target.float(ctx, tiles, 4)
        self.along_y = ctx.framebuffer(
            [self.dilated.texture, self.axes.texture, self.diagonals.texture]
        )
        self.closed = Target.float(ctx, size, 1)
        self.reclosed: Target | None = None  # close_again's, on its first frame
        self._ctx = ctx
        self.kelvin: Target | None = None  # the filled kelvin, on the first frame with them
        # closed (or reclosed) depth + filled kelvin, per depth target (its `again` flag)
        self.both: dict[bool, moderngl.Framebuffer] = {}
        self._back = FramebufferOn(ctx)  # onto the splat's kelvin texture
        self._input = FramebufferOn(ctx)  # onto the depth to close, to copy it

    def again(self) -> Target:
        if self.reclosed is None:
            self.reclosed = Target.float(self._ctx, self.closed.texture.size, 1)
        return self.reclosed

    def with_kelvin(self, out: Target, channels: int) -> tuple[moderngl.Framebuffer, Target]:
        """A framebuffer on `out` (`closed` or `reclosed`) and the filled kelvin (`channels`:
        2 with peaks), and that."""
        if self.kelvin is not None and self.kelvin.texture.components != channels:
            for fbo in self.both.values():
                fbo.release()
            self.both.clear()
            self.kelvin.release()
            self.kelvin = None
        if self.kelvin is None:
            self.kelvin = Target.float(self._ctx, self.closed.texture.size, channels)
        again = out is not self.closed
        both = self.both.get(again)
        if both is None:
            both = self.both[again] = self._ctx.framebuffer([out.texture, self.kelvin.texture])
        return both, self.kelvin

    def back_into(self, temperature: moderngl.Texture) -> moderngl.Framebuffer:
        """A framebuffer on `temperature`, to blit the kelvin in and the filled kelvin back
        (float, exact), kept while the texture is the same."""
        return self._back.get(temperature)

    def input(self, depth: moderngl.Texture) -> moderngl.Framebuffer:
        """A framebuffer on the input `depth`, to blit it into `closed`."""
        return self._input.get(depth)

    def release(self) -> None:
        self._back.release()
        self._input.release()
        self.along_y.release()
        tiles = (self.raw, self.along_x, self.dilated, self.axes, self.diagonals)
        for target in (*tiles, self.closed, self.reclosed, self.kelvin):
            if target is not None:
                target.release()
        for both in self.both.values():
            both.release()
        self.both.clear()


#: What `run` drew with: its tile box, and the close shader's uniform key and values.
_LastRun = tuple[ScreenBox, tuple[object, ...], Callable[[], dict[str, object]]]


class GapPass:
    def __init__(self, context: PassContext) -> None:
        self._context = context
        self._targets = PerSize(lambda size: _GapTargets(context.gl.ctx, size))
        self._points: dict[moderngl.Program, moderngl.VertexArray] = {}  # per close variant
        self._last: _LastRun | None = None  # for close_again on the same frame

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
        particle radii closed (`depth` itself when `gap_radii` is 0). With a `box`, the tiles
        are built only over it (a closed gap lies between two surface pixels, so inside the box
        of the surface). With the splat's `temperature` (kelvin), the closed pixels get the
        kelvin interpolated alike, written back into `temperature`."""
        if gap_radii <= 0.0:
            return depth
        targets = self._targets.get(depth.size)
        edge_jump = EDGE_JUMP_RADII * particle_radius
        tiles = targets.raw.texture.size
        tile_box = (0, 0, *tiles) if box is None else _tile_box(box, tiles)
        self._build_tiles(targets, depth, edge_jump, tile_box)
        program = self._close_program(temperature is not None)
        key = (px_per_unit, particle_radius, gap_radii, tile_box, depth.size)
        size = (float(depth.size[0]), float(depth.size[1]))

        def values() -> dict[str, object]:
            return {
                "u_focal_px": px_per_unit,
                "u_particle_radius": particle_radius,
                "u_gap_radii": gap_radii,
                "u_edge_jump": edge_jump,
                "u_tile_box": tile_box,
                "u_image_size": size,
            }

        set_group(program, "frame", key, values)
        self._close(program, targets, depth, tile_box, temperature, targets.closed)
        self._last = (tile_box, key, values)
        return targets.closed.texture

    def close_again(
        self, depth: moderngl.Texture, temperature: moderngl.Texture | None = None
    ) -> moderngl.Texture:
        """The same rule once more on `depth` (the smoothed surface of the depth `run` closed
        on this frame), over the tiles `run` found may close a pixel, with its tile bounds:
        pinholes. A channel through a lattice's layers splats as a background pixel between
        walls of the lower layers; `run` closes the walls (a farther surface between nearer
        ones) but not the hole, which no direction encloses yet (its sides lie on different
        layers); after the smoothing its sides are one surface."""
        assert self._last is not None, "close_again follows run on the same frame"
        tile_box, key, values = self._last
        program = self._close_program(temperature is not None, pinholes=True)
        set_group(program, "frame", key, values)
        targets = self._targets.get(depth.size)
        self._close(program, targets, depth, tile_box, temperature, targets.again())
        return targets.again().texture

    def _build_tiles(
        self, targets: _GapTargets, depth: moderngl.Texture, edge_jump: float, box: ScreenBox
    ) -> None:
        """The raw tiles over `box` (cleared outside it), then their dilations over it (what
        lies outside is never read: the close pass draws only tiles of `box`)."""
        programs, draw = self._context.programs, self._context.fullscreen.draw
        tiles = programs.get(FULLSCREEN_VERT, TILES_SHADER, samplers={"u_source": 0})
        set_group(tiles, "frame", edge_jump, lambda: {"u_edge_jump": edge_jump})
        depth.use(0)
        clear_and_scissor(targets.raw.fbo, box)
        targets.raw.fbo.use()
        draw(tiles)
        set_scissor(targets.raw.fbo, None)
        along_x = programs.get(FULLSCREEN_VERT, DILATE_SHADER, _DILATE_DEFINES[0], {"u_tiles": 0})
        targets.raw.texture.use(0)
        set_scissor(targets.along_x.fbo, box)
        targets.along_x.fbo.use()
        draw(along_x)
        set_scissor(targets.along_x.fbo, None)
        along_y = programs.get(
            FULLSCREEN_VERT, DILATE_SHADER, _DILATE_DEFINES[1], {"u_tiles": 0, "u_raw": 1}
        )
        set_group(along_y, "frame", edge_jump, lambda: {"u_edge_jump": edge_jump})
        targets.along_x.texture.use(0)
        targets.raw.texture.use(1)
        set_scissor(targets.along_y, box)
        targets.along_y.use()
        draw(along_y)
        set_scissor(targets.along_y, None)  # before the blits, which the scissor would cut

    def _close_program(self, temperature: bool, pinholes: bool = False) -> moderngl.Program:
        defines = {
            "GAP_MAX_PX": PINHOLE_MAX_PX if pinholes else GAP_MAX_PX,
            "HAS_TEMPERATURE": int(temperature),
            "BACKGROUND_ONLY": int(pinholes),
        }
        return self._context.programs.get(CLOSE_TILES_VERT, CLOSE_SHADER, defines, _CLOSE_UNITS)

    def _close(
        self,
        program: moderngl.Program,
        targets: _GapTargets,
        depth: moderngl.Texture,
        tile_box: ScreenBox,
        temperature: moderngl.Texture | None,
        out: Target,
    ) -> None:
        """Copy `depth` (and the kelvin) into `out` (and the kelvin target), then draw the
        close shader on the tiles that may close a pixel; with kelvin, blit the filled kelvin
        back."""
        gl = self._context.gl
        ctx = gl.ctx
        fbo, kelvin = out.fbo, None
        with gl.clock:
            ctx.copy_framebuffer(out.fbo, targets.input(depth))
            if temperature is not None:
                fbo, kelvin = targets.with_kelvin(out, temperature.components)
                ctx.copy_framebuffer(kelvin.fbo, targets.back_into(temperature))
        depth.use(0)
        targets.dilated.texture.use(1)
        if temperature is not None:
            temperature.use(2)
        targets.axes.texture.use(3)
        targets.diagonals.texture.use(4)
        fbo.use()
        _draw_tile_points(gl, self._points, program, tile_box[2] * tile_box[3])
        if temperature is not None and kelvin is not None:
            with gl.clock:
                ctx.copy_framebuffer(targets.back_into(temperature), kelvin.fbo)

    def release(self) -> None:
        for vao in self._points.values():
            vao.release()
        self._points.clear()
        self._targets.release()


def _draw_tile_points(
    gl: GLContext,
    vaos: dict[moderngl.Program, moderngl.VertexArray],
    program: moderngl.Program,
    count: int,
) -> None:
    """`count` attribute-less points (close_tiles.vert.glsl sizes them: program point size,
    enabled for this draw only)."""
    ctx = gl.ctx
    vao = vaos.get(program)
    if vao is None:
        vao = vaos[program] = ctx.vertex_array(program, [])
    ctx.enable(moderngl.PROGRAM_POINT_SIZE)
    gl.clock.call(vao.render, moderngl.POINTS, vertices=count)
    ctx.disable(moderngl.PROGRAM_POINT_SIZE)


def _tile_box(box: ScreenBox, tiles: tuple[int, int]) -> ScreenBox:
    """The tiles covering `box` and one more on each side (the edge between the box's outer
    pixels and the background next to them is flagged in the outer tiles), clipped."""
    x, y, width, height = box
    x0, y0 = max(x // 4 - 1, 0), max(y // 4 - 1, 0)
    x1 = min((x + width + 3) // 4 + 1, tiles[0])
    y1 = min((y + height + 3) // 4 + 1, tiles[1])
    return (x0, y0, x1 - x0, y1 - y0)
