"""Device occlusion culling: the host path's two-phase culling (geometry/occlusion.py), on the GPU.

For the spheres the device prepare wrote (`device_prepare.py`), three compute phases and a
pyramid (`shaders/splat/occlusion_cull.comp.glsl`, `depth_pyramid.comp.glsl`) set per-particle
flags that the splat's vertex stage reads (`u_flag_mask`, common/splat_particles.glsl):

1. `mark_front`: nearest depth per screen tile, then FRONT for the particles near their tile's
   front (and those without a rectangle) - drawn first;
2. `mark_rest` (after the front layer's draw): its max-depth pyramid, then SECOND for the other
   particles it does not hide and, with anti-aliasing, COVER for the drawn ones whose coverage
   the shade pass can read.

Nothing is read back in between; the counts of drawn particles are read when asked for
(`drawn`), after the frame. The test is conservative, so the depth image is that of drawing
every particle (equal up to depth-buffer ties, tests/test_device_prepare.py).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import moderngl
import numpy as np

from sphrender.server.engine.geometry import occlusion
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.geometry.screen_box import ScreenBox
from sphrender.server.engine.gpu.dispatch import dispatch_1d
from sphrender.server.engine.gpu.uniforms import set_group, set_if_used, write_array
from sphrender.server.engine.passes.context import PassContext
from sphrender.server.engine.passes.splat_buffers import (
    COUNTS,
    FLAGS,
    PYRAMID,
    TILES,
    SplatBuffers,
)

CULL_SHADER = "splat/occlusion_cull.comp.glsl"
PYRAMID_SHADER = "splat/depth_pyramid.comp.glsl"
FRONT, SECOND, COVER = 1, 2, 4  # the flags of occlusion_cull.comp.glsl
GROUP_SIZE = 256
#: Pyramid levels: blocks up to 64 pixels, as occlusion.DepthMaxTable's max_side (larger
#: rectangles are simply drawn); depth_pyramid.comp.glsl builds a 64-pixel block per group.
LEVELS = 7
PYRAMID_BLOCK = 2 ** (LEVELS - 1)
_INF_BITS = np.uint32(0x7F800000)


@dataclass(frozen=True)
class DeviceCullInput:
    """What the culling needs to know of the frame besides the buffers (from the prepare)."""

    count: int  # spheres in the buffers
    nearest: float  # smallest nearest eye depth of a visible particle
    far: float
    reference_radius: float


class DeviceCulling:
    def __init__(self, context: PassContext, buffers: SplatBuffers, coverage_need: int) -> None:
        """`coverage_need`: passes/splat.py's COVERAGE_NEED_PX."""
        self._context = context
        self._buffers = buffers
        self._coverage_need = coverage_need
        self._tile_init = np.zeros(0, np.uint32)

    def mark_front(self, camera: Camera, frame: DeviceCullInput, antialias: bool) -> None:
        """Phases 0 and 1: the front layer's FRONT flags (the draw follows)."""
        buffers = self._buffers
        typical_depth = 0.5 * (frame.nearest + frame.far / 1.001)
        radius_px = frame.reference_radius * camera.pixels_per_unit_at_unit_depth
        radius_px /= max(typical_depth, camera.near)
        tile = max(occlusion.TILE_RADII * radius_px, 1.0)
        tiles_x = int(camera.width // tile) + 2
        tiles = tiles_x * (int(camera.height // tile) + 2)
        if self._tile_init.size < tiles:
            self._tile_init = np.full(max(tiles, 2 * self._tile_init.size), _INF_BITS)
        buffers.write(TILES, self._tile_init[:tiles])
        buffers.reserve(FLAGS, frame.count)
        with self._context.gl.clock:
            buffers.buffer(COUNTS).write(np.zeros(4, np.uint32))
        shader = self._shader(camera, frame, antialias)
        set_if_used(shader, "u_tile", float(tile))
        set_if_used(shader, "u_tiles_x", tiles_x)
        self._run(shader, 0, frame.count)
        self._run(shader, 1, frame.count)

    def mark_rest(
        self,
        camera: Camera,
        frame: DeviceCullInput,
        depth: moderngl.Texture,
        box: ScreenBox | None,
        antialias: bool,
    ) -> None:
        """Phase 2 over the front layer's eye depth `depth`: SECOND and COVER flags."""
        x, y, width, height = box if box is not None else (0, 0, camera.width, camera.height)
        dims, offsets = levels(width, height)
        self._buffers.reserve(PYRAMID, offsets[-1] + dims[-1][0] * dims[-1][1])
        self.build_pyramid(depth, (x, y), dims, offsets)
        shader = self._shader(camera, frame, antialias)
        set_if_used(shader, "u_box", (x, y, width, height))
        _set_levels(shader, dims, offsets)
        self._run(shader, 2, frame.count)

    def drawn(self) -> int:
        """Particles the last culled splat drew (front layer + the rest); waits for the GPU."""
        with self._context.gl.clock:
            counts = np.frombuffer(self._buffers.buffer(COUNTS).read(), np.uint32)
        return int(counts[0]) + int(counts[1])

    def _shader(
        self, camera: Camera, frame: DeviceCullInput, antialias: bool
    ) -> moderngl.ComputeShader:
        shader = self._context.programs.compute(CULL_SHADER)
        set_if_used(shader, "u_count", frame.count)

        def values() -> dict[str, object]:
            tan_y = camera.tan_half_fov_y
            return {
                "u_tan_half_fov": (tan_y * camera.aspect, tan_y),
                "u_size": (camera.width, camera.height),
                "u_band": occlusion.FRONT_BAND_RADII,
                "u_antialias": antialias,
                "u_coverage_need": self._coverage_need,
            }

        set_group(shader, "camera", (camera, antialias), values)
        return shader

    def _run(self, shader: moderngl.ComputeShader, phase: int, count: int) -> None:
        set_if_used(shader, "u_phase", phase)
        with self._context.gl.clock:
            dispatch_1d(shader, count, GROUP_SIZE)
            self._context.gl.ctx.memory_barrier(moderngl.ALL_BARRIER_BITS)

    def build_pyramid(
        self,
        depth: moderngl.Texture,
        origin: tuple[int, int],
        dims: tuple[tuple[int, int], ...],
        offsets: tuple[int, ...],
    ) -> None:
        """The max-depth pyramid of `depth` from `origin` (the levels `levels(...)` of the box)
        into the PYRAMID buffer, which must hold them: every level in one dispatch, a work
        group per 64 x 64 block of level 0."""
        shader = self._context.programs.compute(PYRAMID_SHADER, samplers={"u_depth": 0})
        set_if_used(shader, "u_origin", origin)
        _set_levels(shader, dims, offsets)
        depth.use(0)
        width, height = dims[0]
        with self._context.gl.clock:
            shader.run(group_x=-(-width // PYRAMID_BLOCK), group_y=-(-height // PYRAMID_BLOCK))
            self._context.gl.ctx.memory_barrier(moderngl.ALL_BARRIER_BITS)


def _set_levels(
    shader: moderngl.ComputeShader, dims: tuple[tuple[int, int], ...], offsets: tuple[int, ...]
) -> None:
    """The pyramid's level table (uniform arrays; rewritten only when the box changed)."""
    set_if_used(shader, "u_levels", len(dims))
    write_array(shader, "u_offsets", offsets, np.int32)
    write_array(shader, "u_dims", dims, np.int32)


@functools.lru_cache(maxsize=16)
def levels(width: int, height: int) -> tuple[tuple[tuple[int, int], ...], tuple[int, ...]]:
    """Each pyramid level's (width, height) and where it starts in the pyramid buffer (cached:
    a stream's box rarely changes)."""
    dims = [(max(width, 1), max(height, 1))]
    while len(dims) < LEVELS and max(dims[-1]) > 1:
        w, h = dims[-1]
        dims.append(((w + 1) // 2, (h + 1) // 2))
    offsets = [0]
    for w, h in dims[:-1]:
        offsets.append(offsets[-1] + w * h)
    return tuple(dims), tuple(offsets)
