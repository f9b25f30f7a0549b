"""Field normals (`[quality] field_normals`): the normals near a rim from the SPH field's
gradient: the normals pass's variant lists the pixels near rims, a compute pass blends their
normals in place in its target.

A screen-space surface is the union of the particle spheres, smoothed. Near a rim (background,
or a depth step: a sheet over the bulk, a hole in a sheet) its depth-differenced normal follows
the spheres' beads and stays flat up to a hole's edge, where the surface a reconstruction
draws (splashsurf's iso-surface of the SPH field) turns smoothly towards the rim. The normal of
that iso-surface is -grad phi / |grad phi| of phi(x) = sum_j W(|x - x_j|, h), evaluated at each
pixel's own surface point within `field_normals` projected particle radii (at most 5 pixels) of
a rim and blended in by the distance to it (full next to the rim, none beyond the reach).
Droplets (lone particles) get their exact sphere normal from it. Depth, coverage and the rim's
place are unchanged. The rule in full: `shaders/field/field_normals.glsl`.

Two parts:
1. in the normals pass (its FIELD_NORMALS variant, `shaders/field/field_rims.glsl`): each
   surface pixel within reach of a rim (the rim tiles, `rim_tiles.py`, let the rest stop at
   once) appends itself and its weight to a list; the fragment shader has the depth at hand
   (the same test as a compute pass over the image cost 17 ms at 1280x720 on llvmpipe);
2. `shaders/field/field_blend.comp.glsl`: one invocation turns the list's length into the
   arguments of an indirect dispatch (the CPU never reads the count), then one invocation per
   listed pixel evaluates the gradient over the field grid (`field_grid.py`, built between the
   two from the particles whose support reaches a 16-px block with a listed pixel) and writes
   the blended normal back into the target (image load/store). Packed 64 listed pixels to a
   work group the gradient runs in no idle lane: 6 ms on the 100k ball at 1280x720 on
   llvmpipe, against ~11 ms inside the fragment shader, whose 4 x 4 blocks along the rims were
   a third idle.

Owns: the field grid, the list (binding 17) and its count + the dispatch arguments (18), the
rim blocks (19), grown with the image; released by `release`.
"""

from __future__ import annotations

from collections.abc import Callable

import moderngl

from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.gpu.draw import Target
from sphrender.server.engine.gpu.uniforms import set_group, set_if_used, write_matrix
from sphrender.server.engine.passes.context import PassContext
from sphrender.server.engine.passes.field_grid import (
    RIM_BLOCKS,
    FieldGrid,
    FieldParticles,
    RimCulling,
    rim_blocks,
)

BLEND_SHADER = "field/field_blend.comp.glsl"
#: The normals pass's variant that lists the rims (field/field_rims.glsl).
DEFINES = {"FIELD_NORMALS": 1}
#: Texture units of the rim tiles in that variant: the +-8 px windows, each tile's own extremes.
TILES_UNIT, EXTREMES_UNIT = 1, 2
#: Storage bindings of the list and of its count + the blend's dispatch arguments.
RIMS, COUNT = 17, 18
#: Work groups per row of the blend's dispatch (GL 4.3 promises 65535 per axis), 64 pixels each.
GROUPS_X = 4096
#: The list packs pixel coordinates in 16 bits each (scene images are far smaller).
MAX_PACKED_SIDE = 65535


class FieldNormals:
    def __init__(self, context: PassContext) -> None:
        self._context = context
        self._grid = FieldGrid(context)
        ctx = context.gl.ctx
        self._rims = ctx.buffer(reserve=16)
        self._count = ctx.buffer(reserve=16)
        self._blocks = ctx.buffer(reserve=16)

    def prepare(
        self,
        program: moderngl.Program,
        tiles: moderngl.Texture,
        extremes: moderngl.Texture,
        size: tuple[int, int],
        *,
        reach_radii: float,
    ) -> None:
        """Before the normals pass's FIELD_NORMALS variant `program` draws an image of `size`:
        empty the list and the rim blocks, set the variant's uniforms and bind what it reads
        and writes (the rim tiles' windows `tiles` to TILES_UNIT, their `extremes` to
        EXTREMES_UNIT)."""
        if max(size) > MAX_PACKED_SIDE:
            raise ValueError(f"field normals: image sides at most {MAX_PACKED_SIDE} px, got {size}")
        if 8 * size[0] * size[1] > self._rims.size:
            self._rims.orphan(8 * size[0] * size[1])
        blocks_x, blocks_y = rim_blocks(size)
        if 4 * blocks_x * blocks_y > self._blocks.size:
            self._blocks.orphan(4 * blocks_x * blocks_y)
        with self._context.gl.clock:
            self._count.clear()
            self._blocks.clear()
            self._rims.bind_to_storage_buffer(RIMS)
            self._count.bind_to_storage_buffer(COUNT)
            self._blocks.bind_to_storage_buffer(RIM_BLOCKS)
            tiles.use(TILES_UNIT)
            extremes.use(EXTREMES_UNIT)
        set_if_used(program, "u_reach_radii", float(reach_radii))
        set_if_used(program, "u_rim_blocks", (blocks_x, blocks_y))

    def finish(
        self,
        normals: Target,
        depth: moderngl.Texture,
        camera: Camera,
        frame_uniforms: tuple[object, Callable[[], dict[str, object]]],
        particles: FieldParticles,
        support: float,
    ) -> None:
        """After the variant drew `normals` from the eye-depth image `depth`: sort the
        `particles` that can reach a listed pixel into the field grid (SPH support `support`),
        then take the listed pixels' normals towards the field (`frame_uniforms`: the normals
        pass's uniform group: its key and values)."""
        tan_y = camera.tan_half_fov_y
        cull = RimCulling(self._blocks, depth.size, (tan_y * camera.aspect, tan_y))
        with self._context.gl.clock:  # the list, its count and the blocks the draw wrote
            self._context.gl.ctx.memory_barrier(moderngl.ALL_BARRIER_BITS)
        built = self._grid.build(particles, support, cull)
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
        self._grid.release()
        self._rims.release()
        self._count.release()
        self._blocks.release()
