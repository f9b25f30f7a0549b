"""Normals pass: world-space normals from the smoothed eye depth.

Shader: `shaders/normals/surface_normals.frag.glsl`: the view position of each pixel from its
depth through the inverse projection, the smaller one-sided difference per axis (so a depth
edge does not bend the normal), their cross product, rotated to world space.
When the quality asks for them, the field normals (`field_normals.py`: compute passes list the
pixels near rims and fix their normals up in place) and then the
silhouette normals (`silhouette.py`: a pass of its own) rework the normals near rims; both read
the rim tiles (`rim_tiles.py`), built once from the depth.
Owns: the RGBA32F normal + depth target (xyz = world normal, w = eye depth, 0 = no surface),
which the shade pass reads and the read-back returns as the Z and N AOVs; the rim tiles and
the two rim passes.
"""

from __future__ import annotations

import moderngl

from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.geometry.screen_box import ScreenBox
from sphrender.server.engine.gpu.draw import PerSize, Target, clear_and_scissor, set_scissor
from sphrender.server.engine.gpu.uniforms import set_group, write_matrix
from sphrender.server.engine.passes.context import FULLSCREEN_VERT, PassContext
from sphrender.server.engine.passes.field_grid import FieldParticles
from sphrender.server.engine.passes.field_normals import FieldNormals
from sphrender.server.engine.passes.rim_tiles import RimTiles
from sphrender.server.engine.passes.silhouette import SilhouettePass
from sphrender.server.scene import QualityConfig

SHADER = "normals/surface_normals.frag.glsl"
#: A depth step between neighbouring pixels larger than this many particle radii, or than
#: EDGE_JUMP_FOOTPRINTS pixel footprints (grazing surfaces far away), is an edge, not a slope.
EDGE_JUMP_RADII = 4.0
EDGE_JUMP_FOOTPRINTS = 8.0
#: The wide stencil's kink test: the two one-sided slopes over the stencil may differ by this
#: fraction of the larger (a crease, a rim or a junction differs by more).
KINK = 0.5


class NormalsPass:
    def __init__(self, context: PassContext) -> None:
        self._context = context
        self._target = PerSize(lambda size: Target.float(context.gl.ctx, size, 4))
        self._tiles = RimTiles(context)
        self._field = FieldNormals(context)  # quality.field_normals, on this pass's target
        self._silhouette = SilhouettePass(context)  # quality.silhouette_normals, then

    def target(self, size: tuple[int, int]) -> Target:
        """The normal + depth target for `size` (rebuilt only when the size changes)."""
        return self._target.get(size)

    def run(
        self,
        surface: moderngl.Texture,
        camera: Camera,
        box: ScreenBox | None,
        particle_radius: float = 0.0,
        quality: QualityConfig | None = None,
        field: FieldParticles | None = None,
        support: float = 0.0,
        bulk: moderngl.Texture | None = None,
    ) -> Target:
        """Normals of the eye-depth image `surface`, inside `box` (None: everywhere);
        `particle_radius` sizes the largest depth step that still counts as one surface;
        `quality` gives the wide stencil (`normal_stencil`, off without it), the field normals
        (`field_normals`, over the particles `field` with kernel support `support`) and the
        silhouette normals (`silhouette_normals`); the last of them that ran returns its
        target. `bulk`: the bulk's depth under the exact droplets drawn into `surface`
        (`SplatOutput.bulk_depth`), for the field normals' rims."""
        target = self.target(surface.size)
        reach = quality.field_normals if quality is not None and field is not None else 0.0
        rim = quality.silhouette_normals if quality is not None else 0.0
        tiles = self._tiles.build(surface) if reach > 0.0 or rim > 0.0 else None
        program = self._context.programs.get(FULLSCREEN_VERT, SHADER)
        surface.use(0)
        key = (camera, particle_radius, quality)

        def values() -> dict[str, object]:
            return _frame_uniforms(camera, particle_radius, quality)

        set_group(program, "frame", key, values)
        write_matrix(program, "u_view_to_world", lambda: camera.rotation.T, camera)
        built = None
        if reach > 0.0 and field is not None and tiles is not None:
            built = self._field.prepare(
                surface,
                (tiles, self._tiles.extremes(surface.size)),
                box,
                camera,
                (key, values),
                (field, support),
                reach_radii=reach,
                bulk=bulk,
            )
        clear_and_scissor(target.fbo, box)
        target.fbo.use()
        self._context.fullscreen.draw(program)
        set_scissor(target.fbo, None)
        if built is not None:
            self._field.blend(target, surface, camera, (key, values), built)
        if tiles is None:
            return target
        return self._silhouette.run(
            target, tiles, camera, particle_radius=particle_radius, rim_radii=rim, box=box
        )

    def release(self) -> None:
        self._target.release()
        self._tiles.release()
        self._field.release()
        self._silhouette.release()


def _frame_uniforms(
    camera: Camera, particle_radius: float, quality: QualityConfig | None
) -> dict[str, object]:
    """The normals pass's per-frame uniforms (the field normals' passes share the edge rule's
    and the camera's)."""
    tan_y = camera.tan_half_fov_y
    return {
        "u_depth": 0,
        "u_tan_half_fov": (tan_y * camera.aspect, tan_y),
        "u_edge_jump": EDGE_JUMP_RADII * particle_radius,
        "u_edge_jump_px": EDGE_JUMP_FOOTPRINTS,
        "u_focal_px": camera.pixels_per_unit_at_unit_depth,
        "u_particle_radius": particle_radius,
        "u_stencil_radii": quality.normal_stencil if quality is not None else 0.0,
        "u_stencil_max_px": quality.normal_stencil_max_px if quality is not None else 1,
        "u_kink": KINK,
        "u_smooth_rules": quality is None or quality.normal_rules == "smooth",
    }
