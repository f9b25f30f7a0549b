"""Normals pass: world-space normals from the smoothed eye depth.

Shader: `shaders/normals/surface_normals.frag.glsl`: the view position of each pixel from its
depth through the inverse projection, the smaller one-sided difference per axis (so a depth
edge does not bend the normal), their cross product, rotated to world space.
Owns: the RGBA32F normal + depth target (xyz = world normal, w = eye depth, 0 = no surface),
which the shade pass reads and the read-back returns as the Z and N AOVs.
"""

from __future__ import annotations

import moderngl

from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.geometry.screen_box import ScreenBox
from sphrender.server.engine.gpu.draw import Target, clear_and_scissor, set_scissor, write_matrix
from sphrender.server.engine.passes.context import FULLSCREEN_VERT, PassContext

SHADER = "normals/surface_normals.frag.glsl"
#: A depth step between neighbouring pixels larger than this many particle radii, or than
#: EDGE_JUMP_FOOTPRINTS pixel footprints (grazing surfaces far away), is an edge, not a slope.
EDGE_JUMP_RADII = 4.0
EDGE_JUMP_FOOTPRINTS = 8.0


class NormalsPass:
    def __init__(self, context: PassContext) -> None:
        self._context = context
        self._target: Target | None = None

    def target(self, size: tuple[int, int]) -> Target:
        """The normal + depth target for `size` (rebuilt only when the size changes)."""
        if self._target is None or self._target.texture.size != size:
            if self._target is not None:
                self._target.release()
            self._target = Target.float(self._context.gl.ctx, size, 4)
        return self._target

    def run(
        self,
        surface: moderngl.Texture,
        camera: Camera,
        box: ScreenBox | None,
        particle_radius: float = 0.0,
    ) -> Target:
        """Normals of the eye-depth image `surface`, inside `box` (None: everywhere);
        `particle_radius` sizes the largest depth step that still counts as one surface."""
        target = self.target(surface.size)
        program = self._context.programs.get(FULLSCREEN_VERT, SHADER)
        surface.use(0)
        program["u_depth"] = 0
        program["u_tan_half_fov"] = (camera.tan_half_fov_y * camera.aspect, camera.tan_half_fov_y)
        write_matrix(program, "u_view_to_world", camera.rotation.T)
        program["u_edge_jump"] = EDGE_JUMP_RADII * particle_radius
        program["u_edge_jump_px"] = EDGE_JUMP_FOOTPRINTS
        program["u_focal_px"] = camera.pixels_per_unit_at_unit_depth
        clear_and_scissor(target.fbo, box)
        target.fbo.use()
        self._context.fullscreen.draw(program)
        set_scissor(target.fbo, None)
        return target

    def release(self) -> None:
        if self._target is not None:
            self._target.release()
            self._target = None
