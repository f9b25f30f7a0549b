"""The surface-detail pass: world normals tilted by a procedural brushed pattern and / or an
image's height, both fixed in world space (`shaders/detail/detail_normals.frag.glsl`, pattern in
`detail/surface_detail.glsl`, image in `detail/detail_image.glsl`), for scenes whose ``[finish]
detail`` is not ``none`` or that name a ``detail_image``; the shade pass and the N AOV read its
output, and the shade pass evaluates the same detail for the roughness (`detail_uniforms`).

The pattern is projected triplanar: on each axis plane, coordinates across and along the brush
direction projected into it; the eye's coordinates modulo the pattern's period are taken here
in float64 so that a workpiece at 1e5 scene units keeps its grooves (and the image's tiles: the
eye's position in tiles modulo 1). Owns its program (through the `ProgramCache`), its RGBA32F
target and the image textures (`DetailImages`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import moderngl
import numpy as np
import numpy.typing as npt

from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.geometry.screen_box import ScreenBox
from sphrender.server.engine.gpu.draw import PerSize, Target, clear_and_scissor, set_scissor
from sphrender.server.engine.gpu.uniforms import set_group, set_if_used, uses, write_matrix
from sphrender.server.engine.passes.context import FULLSCREEN_VERT, PassContext
from sphrender.server.engine.passes.detail_images import DetailImages, DetailTexture
from sphrender.server.scene import FinishConfig

SHADER = "detail/detail_normals.frag.glsl"
#: The pattern's hash repeats every this many cells (surface_detail.glsl's DETAIL_PERIOD).
DETAIL_PERIOD = 256.0
#: Groove length over groove width (surface_detail.glsl's DETAIL_GROOVE_LENGTH).
GROOVE_LENGTH = 40.0
#: The widest octave over the finest: the offset repeats after DETAIL_PERIOD of its cells.
COARSEST_WIDTH = 4.0


def detail_planes(finish: FinishConfig, eye: npt.NDArray[np.float64]) -> npt.NDArray[np.float32]:
    """Per axis plane k (coordinates k+1, k+2): the brush direction projected into the plane
    (unit; the plane's first axis where the brush is normal to the plane) and the eye's
    (across, along) pattern coordinates modulo the period, in float64 before rounding."""
    brush = np.asarray(finish.brush_direction, dtype=np.float64)
    eye = np.asarray(eye, dtype=np.float64)
    planes = np.zeros((3, 4), dtype=np.float64)
    for k in range(3):
        axes = [(k + 1) % 3, (k + 2) % 3]
        along = brush[axes]
        length = float(np.hypot(*along))
        along = along / length if length > 1e-9 * np.linalg.norm(brush) else np.array([1.0, 0.0])
        across = np.array([-along[1], along[0]])
        p = eye[axes] / finish.detail_scale
        q = np.array([p @ across, p @ along / GROOVE_LENGTH])
        planes[k] = (*along, *np.mod(q, DETAIL_PERIOD * COARSEST_WIDTH))
    return planes.astype(np.float32)


def detail_uniforms(finish: FinishConfig, camera: Camera) -> dict[str, object]:
    """The pattern's and the image's scalar uniforms (the planes are written with
    `write_planes`, the image's texel count with `set_image_texels`)."""
    size = finish.detail_image_size
    return {
        "u_detail_pixel_angle": 2.0 * camera.tan_half_fov_y / camera.height,
        "u_detail_scale": finish.detail_scale,
        "u_detail_normal_strength": finish.detail_normal_strength,
        "u_detail_roughness_strength": finish.detail_roughness_strength,
        "u_detail_image_offset": tuple(float(c) for c in np.mod(camera.eye / size, 1.0)),
        "u_detail_image_size": size,
        "u_detail_image_depth": finish.detail_image_depth,
        "u_detail_image_roughness": finish.detail_image_roughness,
    }


def set_image_texels(program: moderngl.Program, image: DetailTexture) -> None:
    """The image's texels along the tile's longer side (its mip level's scale) and its slope
    scale."""
    set_if_used(program, "u_detail_image_texels", float(max(image.texture.size)))
    set_if_used(program, "u_detail_image_slope_scale", image.slope_scale)


def has_detail(finish: FinishConfig) -> bool:
    """Whether the finish tilts the normals (the pass runs) or may move the roughness."""
    return finish.detail != "none" or finish.detail_image is not None


def write_planes(
    program: moderngl.Program, finish: FinishConfig, eye: npt.NDArray[np.float64]
) -> None:
    """Upload `detail_planes` when the variant uses them."""
    if uses(program, "u_detail_plane"):
        program["u_detail_plane"].write(detail_planes(finish, eye).tobytes())  # type: ignore[union-attr]


def _planes_written(
    program: moderngl.Program, finish: FinishConfig, camera: Camera
) -> dict[str, object]:
    write_planes(program, finish, camera.eye)
    return detail_uniforms(finish, camera)


class SurfaceDetailPass:
    def __init__(self, context: PassContext, image_dirs: Sequence[str | Path] = ()) -> None:
        """`image_dirs`: the only directories `[finish] detail_image` may name files in."""
        self._context = context
        self._target = PerSize(lambda size: Target.float(context.gl.ctx, size, 4))
        self._images = DetailImages(context, image_dirs)

    def image_texture(self, finish: FinishConfig) -> DetailTexture:
        """The texture of `finish.detail_image` (read on first use, again when it changes)."""
        assert finish.detail_image is not None
        return self._images.texture(finish.detail_image)

    def run(
        self,
        finish: FinishConfig,
        camera: Camera,
        normal_depth: Target,
        box: ScreenBox | None,
    ) -> Target:
        """`normal_depth` (world normal xyz, eye depth w) with the detail on its normals, in
        this pass's own target; only `box` holds surface (outside it stays empty). Without
        detail, `normal_depth` itself."""
        if not has_detail(finish):
            return normal_depth
        image = None if finish.detail_image is None else self.image_texture(finish)
        program = self._context.programs.get(
            FULLSCREEN_VERT,
            SHADER,
            {"DETAIL_PATTERN": finish.detail != "none", "DETAIL_IMAGE": image is not None},
        )
        set_group(
            program,
            "scene",
            (finish, camera),
            lambda: {
                **_planes_written(program, finish, camera),
                "u_tan_half_fov": (camera.tan_half_fov_y * camera.aspect, camera.tan_half_fov_y),
            },
        )
        write_matrix(program, "u_view_to_world", lambda: camera.rotation.T, camera)
        normal_depth.texture.use(0)
        set_if_used(program, "u_normal_depth", 0)
        if image is not None:
            image.texture.use(1)
            set_if_used(program, "u_detail_image", 1)
            set_image_texels(program, image)
        target = self._target.get(normal_depth.texture.size)
        clear_and_scissor(target.fbo, box)
        target.fbo.use()
        self._context.fullscreen.draw(program)
        set_scissor(target.fbo, None)
        return target

    def release(self) -> None:
        self._target.release()
        self._images.release()
