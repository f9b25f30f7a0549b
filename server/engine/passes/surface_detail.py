"""The surface-detail pass: world normals tilted by a procedural brushed pattern fixed in world
space (`shaders/detail/detail_normals.frag.glsl`, pattern in `detail/surface_detail.glsl`), for
scenes whose ``[finish] detail`` is not ``none``; the shade pass and the N AOV read its output,
and the shade pass evaluates the same pattern for the roughness detail (`detail_uniforms`).

The pattern lives in coordinates q = B p + o: B's rows are the two directions across the brush
over the groove width s and the brush direction over 40 s, o the eye's q modulo the pattern's
period, taken here in float64 so that a workpiece at 1e5 scene units keeps its grooves. Owns its
program (through the `ProgramCache`) and its RGBA32F target.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.geometry.screen_box import ScreenBox
from sphrender.server.engine.gpu.draw import PerSize, Target, clear_and_scissor, set_scissor
from sphrender.server.engine.gpu.uniforms import set_group, set_if_used, write_matrix
from sphrender.server.engine.passes.context import FULLSCREEN_VERT, PassContext
from sphrender.server.scene import FinishConfig

SHADER = "detail/detail_normals.frag.glsl"
#: The pattern's hash repeats every this many cells (surface_detail.glsl's DETAIL_PERIOD).
DETAIL_PERIOD = 256.0
#: Groove length over groove width (the third row of B).
GROOVE_LENGTH = 40.0


def brush_axes(brush_direction: tuple[float, float, float]) -> npt.NDArray[np.float64]:
    """Rows: the unit brush direction b and two unit directions across it, e1 and e2."""
    b = np.asarray(brush_direction, dtype=np.float64)
    b = b / np.linalg.norm(b)
    helper = np.array([0.0, 1.0, 0.0]) if abs(b[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(b, helper)
    e1 /= np.linalg.norm(e1)
    return np.stack([b, e1, np.cross(b, e1)])


def pattern_basis(finish: FinishConfig) -> npt.NDArray[np.float64]:
    """B: world -> pattern coordinates (rows e1 / s, e2 / s, b / (40 s))."""
    b, e1, e2 = brush_axes(finish.brush_direction)
    s = finish.detail_scale
    return np.stack([e1 / s, e2 / s, b / (GROOVE_LENGTH * s)])


def detail_uniforms(finish: FinishConfig, eye: npt.NDArray[np.float64]) -> dict[str, object]:
    """The pattern's scalar and vector uniforms for a camera at `eye` (B is `pattern_basis`)."""
    offset = np.mod(pattern_basis(finish) @ np.asarray(eye, dtype=np.float64), DETAIL_PERIOD)
    return {
        "u_detail_offset": tuple(float(c) for c in offset),
        "u_detail_scale": finish.detail_scale,
        "u_detail_normal_strength": finish.detail_normal_strength,
        "u_detail_roughness_strength": finish.detail_roughness_strength,
    }


class SurfaceDetailPass:
    def __init__(self, context: PassContext) -> None:
        self._context = context
        self._target = PerSize(lambda size: Target.float(context.gl.ctx, size, 4))

    def run(
        self,
        finish: FinishConfig,
        camera: Camera,
        normal_depth: Target,
        box: ScreenBox | None,
    ) -> Target:
        """`normal_depth` (world normal xyz, eye depth w) with the detail on its normals, in
        this pass's own target; only `box` holds surface (outside it stays empty)."""
        program = self._context.programs.get(FULLSCREEN_VERT, SHADER)
        set_group(
            program,
            "scene",
            (finish, camera),
            lambda: {
                **detail_uniforms(finish, camera.eye),
                "u_tan_half_fov": (camera.tan_half_fov_y * camera.aspect, camera.tan_half_fov_y),
            },
        )
        write_matrix(program, "u_detail_basis", lambda: pattern_basis(finish), finish)
        write_matrix(program, "u_view_to_world", lambda: camera.rotation.T, camera)
        normal_depth.texture.use(0)
        set_if_used(program, "u_normal_depth", 0)
        target = self._target.get(normal_depth.texture.size)
        clear_and_scissor(target.fbo, box)
        target.fbo.use()
        self._context.fullscreen.draw(program)
        set_scissor(target.fbo, None)
        return target

    def release(self) -> None:
        self._target.release()
