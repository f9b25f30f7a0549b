"""Silhouette pass: normals near a silhouette turned towards the silhouette's own outward
direction (`[quality] silhouette_normals`), after the normals pass.

Near a silhouette the true normal is almost perpendicular to the view ray, and its direction on
screen is the outward normal of the silhouette curve. The normals differenced from the depth
follow the beads a rim of particles leaves and flip sideways there. This pass estimates the
silhouette's outward direction and the distance to it from coverage moments over a Gaussian
window (sigma = half the rim reach, in projected particle radii) and blends the depth normal
towards it by the distance to the rim: it moves no silhouette and changes no depth. The rule
in full: `shaders/silhouette/silhouette_normals.frag.glsl`.

Shaders: `shaders/silhouette/rim_tiles.frag.glsl` (the farthest depth per 4 x 4 pixels, then
dilated over +-8 pixels: the inside of a surface skips the window),
`shaders/silhouette/silhouette_normals.frag.glsl`.
Owns: three tile targets (R32F, a quarter of the image per side) and its RGBA32F normal + depth
target (the layout of the normals pass's), per image size.
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
TILES_SHADER = "silhouette/rim_tiles.frag.glsl"
#: The tile steps' defines: farthest depth per tile, then its dilation along x and along y.
_TILE_STEPS = tuple({"RIM_DILATE": int(step > 0), "AXIS": max(step - 1, 0)} for step in range(3))


class _RimTargets:
    def __init__(self, ctx: moderngl.Context, size: tuple[int, int]) -> None:
        tiles = ((size[0] + 3) // 4, (size[1] + 3) // 4)
        # Farthest depth per 4 x 4 pixels; that dilated along x; then along y.
        self.tiles = [Target.float(ctx, tiles, 1) for _ in range(3)]
        self.result = Target.float(ctx, size, 4)

    def release(self) -> None:
        for target in (*self.tiles, self.result):
            target.release()


class SilhouettePass:
    def __init__(self, context: PassContext) -> None:
        self._context = context
        self._targets = PerSize(lambda size: _RimTargets(context.gl.ctx, size))

    def run(
        self,
        normal_depth: Target,
        camera: Camera,
        *,
        particle_radius: float,
        rim_radii: float,
        box: ScreenBox | None = None,
    ) -> Target:
        """`normal_depth` (the normals pass's target) with the normals near silhouettes turned
        (`normal_depth` itself when `rim_radii` is 0); inside `box` only, on a target cleared
        outside it."""
        if rim_radii <= 0.0:
            return normal_depth
        targets = self._targets.get(normal_depth.texture.size)
        target = targets.result
        programs, draw = self._context.programs, self._context.fullscreen.draw
        sources = (normal_depth.texture, targets.tiles[0].texture, targets.tiles[1].texture)
        for step, source in enumerate(sources):
            tiles = programs.get(
                FULLSCREEN_VERT, TILES_SHADER, _TILE_STEPS[step], {"u_normal_depth": 0}
            )
            source.use(0)
            targets.tiles[step].fbo.use()
            draw(tiles)
        program = programs.get(FULLSCREEN_VERT, SHADER)
        normal_depth.texture.use(0)
        targets.tiles[2].texture.use(1)

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
        draw(program)
        set_scissor(target.fbo, None)
        return target

    def release(self) -> None:
        self._targets.release()
