"""Silhouette pass: normals near a silhouette turned towards the silhouette's own outward
direction (`[quality] silhouette_normals`), after the normals pass.

Near a silhouette the true normal is almost perpendicular to the view ray, and its direction on
screen is the outward normal of the silhouette curve. The normals differenced from the depth
follow the beads a rim of particles leaves and flip sideways there. This pass estimates the
silhouette's outward direction and the distance to it from coverage moments over a Gaussian
window (sigma = half the rim reach, in projected particle radii) and blends the depth normal
towards it by the distance to the rim: it moves no silhouette and changes no depth. The rule
in full: `shaders/silhouette/silhouette_normals.frag.glsl`.

Shader: `shaders/silhouette/silhouette_normals.frag.glsl`; it reads the rim tiles
(`rim_tiles.py`: the inside of a surface skips the window).
Owns: its RGBA32F normal + depth target (the layout of the normals pass's), per image size.
"""

from __future__ import annotations

import moderngl

from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.geometry.screen_box import ScreenBox
from sphrender.server.engine.gpu.draw import PerSize, Target, clear_and_scissor, set_scissor
from sphrender.server.engine.gpu.uniforms import set_group, write_matrix
from sphrender.server.engine.passes.context import FULLSCREEN_VERT, PassContext
from sphrender.server.engine.passes.gaps import EDGE_JUMP_RADII

SHADER = "silhouette/silhouette_normals.frag.glsl"


class SilhouettePass:
    def __init__(self, context: PassContext) -> None:
        self._context = context
        self._targets = PerSize(lambda size: Target.float(context.gl.ctx, size, 4))

    def run(
        self,
        normal_depth: Target,
        tiles: moderngl.Texture,
        camera: Camera,
        *,
        particle_radius: float,
        rim_radii: float,
        box: ScreenBox | None = None,
    ) -> Target:
        """`normal_depth` (the normals pass's target) with the normals near silhouettes turned
        (`normal_depth` itself when `rim_radii` is 0); `tiles`: its rim tiles (`RimTiles`);
        inside `box` only, on a target cleared outside it."""
        if rim_radii <= 0.0:
            return normal_depth
        target = self._targets.get(normal_depth.texture.size)
        program = self._context.programs.get(FULLSCREEN_VERT, SHADER)
        normal_depth.texture.use(0)
        tiles.use(1)

        def values() -> dict[str, object]:
            tan_y = camera.tan_half_fov_y
            return {
                "u_normal_depth": 0,
                "u_tiles": 1,
                "u_tan_half_fov": (tan_y * camera.aspect, tan_y),
                "u_focal_px": camera.pixels_per_unit_at_unit_depth,
                "u_particle_radius": particle_radius,
                "u_rim_radii": rim_radii,
                "u_edge_jump": EDGE_JUMP_RADII * particle_radius,
            }

        set_group(program, "frame", (camera, particle_radius, rim_radii), values)
        write_matrix(program, "u_view_to_world", lambda: camera.rotation.T, camera)
        clear_and_scissor(target.fbo, box)
        target.fbo.use()
        self._context.fullscreen.draw(program)
        set_scissor(target.fbo, None)
        return target

    def release(self) -> None:
        self._targets.release()
