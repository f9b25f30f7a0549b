"""Field normals pass: the normals near a rim from the SPH field's gradient
(`[quality] field_normals`), after the normals pass.

A screen-space surface is the union of the particle spheres, smoothed. Near a rim (background,
or a depth step: a sheet over the bulk, a hole in a sheet) its depth-differenced normal follows
the spheres' beads and stays flat up to a hole's edge, where the surface a reconstruction
draws (splashsurf's iso-surface of the SPH field) turns smoothly towards the rim. The normal of
that iso-surface is -grad phi / |grad phi| of phi(x) = sum_j W(|x - x_j|, h), which this pass
evaluates at each pixel's own surface point within `field_normals` pixels of a rim and blends in
by the distance to it (full next to the rim, none beyond the reach). Droplets (lone particles)
get their exact sphere normal from it. Depth, coverage and the rim's place are unchanged. The
rule in full: `shaders/field/field_normals.frag.glsl`.

Measured (dam break 960x540, balanced, against pysplashsurf): silhouette band 34.6 -> 21.8 deg,
1-px tolerant 20.7 -> 10.9; spatter droplets 2.25 -> 1.45 deg (numpy prototype, issue 12).

The particles within h of a pixel's point come from the field grid (`field_grid.py`), built on
the device every frame the pass runs. Owns: the grid and its RGBA32F normal + depth target
(the normals pass's layout), per image size.
"""

from __future__ import annotations

import moderngl

from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.geometry.screen_box import ScreenBox
from sphrender.server.engine.gpu.draw import PerSize, Target, clear_and_scissor, set_scissor
from sphrender.server.engine.gpu.uniforms import set_group, set_if_used, write_matrix
from sphrender.server.engine.passes.context import FULLSCREEN_VERT, PassContext
from sphrender.server.engine.passes.field_grid import FieldGrid, FieldParticles
from sphrender.server.engine.passes.gaps import EDGE_JUMP_RADII

SHADER = "field/field_normals.frag.glsl"
#: The shader's FIELD_MAX_REACH: the rim tiles' +-8 pixels hold a rim at distance reach + 1.
MAX_REACH_PX = 7


class FieldNormalsPass:
    def __init__(self, context: PassContext) -> None:
        self._context = context
        self._grid = FieldGrid(context)
        self._targets = PerSize(lambda size: Target.float(context.gl.ctx, size, 4))

    def run(
        self,
        normal_depth: Target,
        tiles: moderngl.Texture,
        camera: Camera,
        particles: FieldParticles,
        *,
        particle_radius: float,
        support: float,
        reach_px: int,
        box: ScreenBox | None = None,
    ) -> Target:
        """`normal_depth` with the normals within `reach_px` pixels of a rim taken towards the
        field's (`tiles`: its rim tiles, `RimTiles`; `support`: h); `normal_depth` itself when
        the reach is 0 or there are no particles. Inside `box` only."""
        if reach_px <= 0 or particles.total == 0 or not support > 0.0:
            return normal_depth
        built = self._grid.build(particles, support)
        target = self._targets.get(normal_depth.texture.size)
        program = self._context.programs.get(
            FULLSCREEN_VERT, SHADER, samplers={"u_normal_depth": 0, "u_tiles": 1}
        )
        normal_depth.texture.use(0)
        tiles.use(1)
        self._grid.bind_for_reading()

        def values() -> dict[str, object]:
            tan_y = camera.tan_half_fov_y
            return {
                "u_tan_half_fov": (tan_y * camera.aspect, tan_y),
                "u_edge_jump": EDGE_JUMP_RADII * particle_radius,
                "u_reach": min(int(reach_px), MAX_REACH_PX),
            }

        set_group(program, "frame", (camera, particle_radius, reach_px), values)
        set_if_used(program, "u_support", built.support)
        set_if_used(program, "u_bucket_mask", built.bucket_mask)
        write_matrix(program, "u_view_to_world", lambda: camera.rotation.T, camera)
        clear_and_scissor(target.fbo, box)
        target.fbo.use()
        self._context.fullscreen.draw(program)
        set_scissor(target.fbo, None)
        return target

    def release(self) -> None:
        self._grid.release()
        self._targets.release()
