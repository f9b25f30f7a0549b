"""Field normals (`[quality] field_normals`): the normals near a rim from the SPH field's
gradient: a compute pass lists the pixels near rims, another blends their normals in place in
the normals pass's target.

A screen-space surface is the union of the particle spheres, smoothed. Near a rim (background,
or a depth step: a sheet over the bulk, a hole in a sheet) its depth-differenced normal follows
the spheres' beads and stays flat up to a hole's edge, where the surface a reconstruction
draws (splashsurf's iso-surface of the SPH field) turns smoothly towards the rim. The normal of
that iso-surface is -grad phi / |grad phi| of phi(x) = sum_j W(|x - x_j|, h), evaluated at each
pixel's own surface point within `field_normals` projected particle radii (at most 5 pixels) of
a rim and blended in by the distance to it (full next to the rim, none beyond the reach)
times the rim's strength (a depth step just past the edge jump is barely one).
Droplets (lone particles) get their exact sphere normal from it. Depth, coverage and the rim's
place are unchanged. The rule in full: `shaders/field/field_normals.glsl`.

Two parts, the first before the normals pass draws (`prepare`), the second after (`blend`):
1. `shaders/field/field_list.comp.glsl`: the rim tiles (`rim_tiles.py`) that may hold a pixel
   within reach of a rim list themselves (a test per tile over its neighbours' extremes), then
   one invocation per pixel of a listed tile appends each surface pixel within reach of a rim
   and its weight to a list (`shaders/field/field_rims.glsl`; an indirect dispatch sized on
   the device). On the 100k ball at 1280x720, 2.7k of 57.6k tiles list themselves and 9k
   pixels are listed: 4.6 ms on llvmpipe, against 6.3 ms inside the normals pass's fragment
   shader (whose variant cost ~2.6 ms over the whole image even where no pixel searched) and
   17 ms as a compute pass over every pixel; then the field grid (`field_grid.py`) sorts the
   particles whose support reaches a 16-px block with a listed pixel;
2. `shaders/field/field_blend.comp.glsl`: one invocation turns the list's length into the
   arguments of an indirect dispatch (the CPU never reads the count), then one invocation per
   listed pixel evaluates the gradient over the field grid and writes the blended normal back
   into the target (image load/store). Packed 64 listed pixels to a work group the gradient
   runs in no idle lane: 4.4 ms on the 100k ball at 1280x720 on llvmpipe (against ~11 ms
   inside the fragment shader at the 7-px reach, whose 4 x 4 blocks along the rims were a
   third idle).

Owns: the field grid, the list (binding 17) and its count + the blend's dispatch arguments
(18), the rim blocks (19), the listed tiles (21) and their count + the listing's dispatch
arguments (22), grown with the image; released by `release`.
"""

from __future__ import annotations

from collections.abc import Callable

import moderngl

from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.geometry.screen_box import ScreenBox
from sphrender.server.engine.gpu.draw import Target
from sphrender.server.engine.gpu.uniforms import set_group, set_if_used, write_matrix
from sphrender.server.engine.passes.context import PassContext
from sphrender.server.engine.passes.field_grid import (
    RIM_BLOCKS,
    BuiltGrid,
    FieldGrid,
    FieldParticles,
    RimCulling,
    rim_blocks,
)

BLEND_SHADER = "field/field_blend.comp.glsl"
LIST_SHADER = "field/field_list.comp.glsl"
#: Its texture units: the eye depth, the rim tiles' windows and their own extremes, and the
#: bulk's depth under the exact droplets (the eye depth itself when none were drawn).
_LIST_SAMPLERS = {"u_depth": 0, "u_tiles": 1, "u_tile_extremes": 2, "u_bulk_depth": 3}
#: Storage bindings of the list and of its count + the blend's dispatch arguments, and of the
#: listed rim tiles and their count + the listing's dispatch arguments.
RIMS, COUNT, TILES, TILE_COUNT = 17, 18, 21, 22
#: Work groups per row of the indirect dispatches (GL 4.3 promises 65535 per axis).
GROUPS_X = 4096
#: Work-group size of the listing (field_list.comp.glsl's FIELD_LIST_GROUP).
LIST_GROUP = 64
#: The lists pack pixel and tile coordinates in 16 bits each (scene images are far smaller).
MAX_PACKED_SIDE = 65535


class FieldNormals:
    def __init__(self, context: PassContext) -> None:
        self._context = context
        self._grid = FieldGrid(context)
        ctx = context.gl.ctx
        self._rims = ctx.buffer(reserve=16)
        self._count = ctx.buffer(reserve=16)
        self._blocks = ctx.buffer(reserve=16)
        self._tiles = ctx.buffer(reserve=16)
        self._tile_count = ctx.buffer(reserve=16)

    def prepare(
        self,
        depth: moderngl.Texture,
        tiles: tuple[moderngl.Texture, moderngl.Texture],
        box: ScreenBox | None,
        camera: Camera,
        frame_uniforms: tuple[object, Callable[[], dict[str, object]]],
        field: tuple[FieldParticles, float],
        *,
        reach_radii: float,
        bulk: moderngl.Texture | None = None,
    ) -> BuiltGrid:
        """Before the normals pass draws from the eye-depth image `depth`: list its pixels
        inside `box` (None: all) within `reach_radii` projected particle radii of a rim
        (`tiles`: its rim tiles, the +-8 px windows and each tile's own extremes;
        `frame_uniforms`: the normals pass's uniform group, its key and values), then sort the
        particles of `field` (and its SPH support) that can reach a listed pixel into the
        field grid; `blend` takes what this returns. `bulk`: the bulk's depth under the exact
        droplets drawn into `depth` (`SplatOutput.bulk_depth`; None: `depth` is the bulk's),
        so that a droplet is no rim of the bulk behind it. Neither reads the normals, so the normals
        draw queued after them need not finish first (on llvmpipe a compute dispatch waits
        for the drawing before it: 117 against 122 ms a frame on the 100k ball at 1280x720)."""
        under = depth if bulk is None else bulk
        self._list_rims(depth, tiles, box, frame_uniforms, reach_radii, under)
        tan_y = camera.tan_half_fov_y
        cull = RimCulling(self._blocks, depth.size, (tan_y * camera.aspect, tan_y))
        return self._grid.build(*field, cull)

    def _list_rims(
        self,
        depth: moderngl.Texture,
        tiles: tuple[moderngl.Texture, moderngl.Texture],
        box: ScreenBox | None,
        frame_uniforms: tuple[object, Callable[[], dict[str, object]]],
        reach_radii: float,
        bulk: moderngl.Texture,
    ) -> None:
        """The list of rim pixels, its count and the rim blocks, fresh."""
        size = depth.size
        if max(size) > MAX_PACKED_SIDE:
            raise ValueError(f"field normals: image sides at most {MAX_PACKED_SIDE} px, got {size}")
        box = (0, 0, *size) if box is None else box
        tile_box = _tile_box(box, tiles[0].size)
        self._grow(self._rims, 8 * size[0] * size[1])
        self._grow(self._tiles, 4 * tile_box[2] * tile_box[3])
        blocks_x, blocks_y = rim_blocks(size)
        self._grow(self._blocks, 4 * blocks_x * blocks_y)
        shader = self._context.programs.compute(LIST_SHADER, _LIST_SAMPLERS)
        set_group(shader, "frame", *frame_uniforms)
        set_if_used(shader, "u_reach_radii", float(reach_radii))
        set_if_used(shader, "u_rim_blocks", (blocks_x, blocks_y))
        set_if_used(shader, "u_groups_x", GROUPS_X)
        set_if_used(shader, "u_tile_box", tile_box)
        set_if_used(shader, "u_box", box)
        set_if_used(shader, "u_droplets", bulk is not depth)
        with self._context.gl.clock:
            self._count.clear()
            self._blocks.clear()
            self._tile_count.clear()
            for buffer, binding in (
                (self._rims, RIMS),
                (self._count, COUNT),
                (self._blocks, RIM_BLOCKS),
                (self._tiles, TILES),
                (self._tile_count, TILE_COUNT),
            ):
                buffer.bind_to_storage_buffer(binding)
            depth.use(0)
            tiles[0].use(1)
            tiles[1].use(2)
            bulk.use(3)
        set_if_used(shader, "u_phase", 0)
        self._run(shader.run, -(-tile_box[2] * tile_box[3] // LIST_GROUP))
        set_if_used(shader, "u_phase", 1)
        self._run(shader.run, 1)
        set_if_used(shader, "u_phase", 2)
        self._run(lambda: shader.run_indirect(self._tile_count, 4))

    @staticmethod
    def _grow(buffer: moderngl.Buffer, nbytes: int) -> None:
        if nbytes > buffer.size:
            buffer.orphan(nbytes)

    def blend(
        self,
        normals: Target,
        depth: moderngl.Texture,
        camera: Camera,
        frame_uniforms: tuple[object, Callable[[], dict[str, object]]],
        built: BuiltGrid,
    ) -> None:
        """After `prepare` (which returned `built`) and the normals pass drew `normals` from
        the eye-depth image `depth`: take the listed pixels' normals towards the field
        (`frame_uniforms`: the normals pass's uniform group, its key and values)."""
        shader = self._context.programs.compute(BLEND_SHADER, {"u_depth": 0})
        set_group(shader, "frame", *frame_uniforms)
        set_if_used(shader, "u_support", built.support)
        set_if_used(shader, "u_bucket_mask", built.bucket_mask)
        write_matrix(shader, "u_view_to_world", lambda: camera.rotation.T, camera)
        with self._context.gl.clock:
            depth.use(0)
            normals.texture.bind_to_image(0, read=True, write=True)
            self._grid.bind_for_reading()
            self._rims.bind_to_storage_buffer(RIMS)
            self._count.bind_to_storage_buffer(COUNT)
        set_if_used(shader, "u_groups_x", GROUPS_X)
        set_if_used(shader, "u_phase", 0)
        self._run(shader.run, 1)
        set_if_used(shader, "u_phase", 1)
        self._run(lambda: shader.run_indirect(self._count, 4))

    def _run(self, dispatch: Callable[..., None], *groups: int) -> None:
        """`dispatch(*groups)`, then a barrier: what it wrote is seen by the next reader (a
        shader, the indirect dispatch, a texture fetch)."""
        with self._context.gl.clock:
            dispatch(*groups)
            self._context.gl.ctx.memory_barrier(moderngl.ALL_BARRIER_BITS)

    def release(self) -> None:
        self._tiles.release()
        self._tile_count.release()
        self._grid.release()
        self._rims.release()
        self._count.release()
        self._blocks.release()


def _tile_box(box: ScreenBox, tiles: tuple[int, int]) -> ScreenBox:
    """The 4 x 4 tiles holding a pixel of `box`, clipped to the `tiles` of the image."""
    x, y, width, height = box
    x0, y0 = max(x // 4, 0), max(y // 4, 0)
    x1 = min(-(-(x + width) // 4), tiles[0])
    y1 = min(-(-(y + height) // 4), tiles[1])
    return (x0, y0, max(x1 - x0, 0), max(y1 - y0, 0))
