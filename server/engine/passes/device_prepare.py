"""Device prepare: the frame's arrays go to the GPU as they are; a compute shader does the rest.

What `geometry/prepare.py` (view transform, culling, float32), `occlusion.sphere_bounds` and
`screen_box` do per particle on the CPU, `shaders/splat/particles_to_view.comp.glsl` does on
the device, in float64 where the CPU does, writing the splat's spheres in place
(`splat_buffers.py`). The host's work is the upload of the client's arrays (float64 positions,
float32 radii / temperatures / axes, the droplet mask's bytes: no conversion, no copy) and one
32-byte read-back of what the scissored passes need before they are recorded: the screen box, the
far distance and the counts. Occlusion culling is a host-prepare feature (it pays on llvmpipe,
whose rasteriser is the cost; see `SurfaceRenderer` for the switch).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import moderngl
import numpy as np
import numpy.typing as npt

from sphrender.core.frame import ParticleFrame
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.geometry.prepare import frame_reference_radius
from sphrender.server.engine.geometry.screen_box import ScreenBox, clip_box
from sphrender.server.engine.gpu.dispatch import dispatch_1d
from sphrender.server.engine.gpu.uniforms import set_group, set_if_used
from sphrender.server.engine.passes.context import PassContext
from sphrender.server.engine.passes.splat import SplatBatch
from sphrender.server.engine.passes.splat_buffers import (
    AXES,
    DROPLETS,
    PEAKS,
    POSITIONS,
    RADII,
    SPHERES,
    SUMMARY,
    TEMPERATURES,
    SplatBuffers,
)
from sphrender.server.scene import Scene

COMPUTE_SHADER = "splat/particles_to_view.comp.glsl"
GROUP_SIZE = 256  # local_size_x of the compute shader
_SUMMARY_INIT = np.array([2**31 - 1] * 4 + [0] * 4 + [0x7F800000, 0, 0, 0], dtype=np.int32)


@dataclass(frozen=True)
class DevicePrepared:
    """What the host learns from the device prepare: the batches to splat and the box."""

    bulk: SplatBatch
    droplets: SplatBatch | None  # None: no particle is an exact droplet
    visible: int
    box: ScreenBox | None
    reference_radius: float
    nearest: float  # the smallest nearest eye depth of a visible particle (inf: none)


class DevicePrepare:
    def __init__(self, context: PassContext, buffers: SplatBuffers) -> None:
        self._context = context
        self._buffers = buffers

    def run(
        self,
        frame: ParticleFrame,
        camera: Camera,
        scene: Scene,
        *,
        reference_radius: float | None = None,
        droplets: npt.NDArray[np.bool_] | None = None,
        ellipsoids: tuple[npt.NDArray[np.float64], npt.NDArray[np.float32]] | None = None,
    ) -> DevicePrepared:
        """Upload `frame` (or the ellipsoid centres and axes) and run the compute shader; the
        arguments mean what they mean for `geometry.prepare.prepare_particles`."""
        count = frame.count
        if frame.peak_temperatures is not None and not scene.material.heat_tint:
            frame = replace(frame, peak_temperatures=None)  # only the heat tint reads them
        self._upload(frame, droplets, ellipsoids)
        summary = self._dispatch(camera, scene, frame, count, droplets, ellipsoids)
        box_min_x, box_min_y, neg_max_x, neg_max_y, _, visible, drops, unbounded = summary[
            :8
        ].tolist()
        far_reduced, nearest = summary[4:9:4].view(np.float32).tolist()
        far_config = scene.camera.far
        if far_config is not None:
            far = far_config
        elif visible:
            far = far_reduced * 1.001
        else:
            far = camera.near * 2.0
        far = max(far, camera.near * 1.001)
        box = None
        if visible and not unbounded:
            box = clip_box(box_min_x, -neg_max_x, box_min_y, -neg_max_y, camera)
        if reference_radius is None:
            reference_radius = frame_reference_radius(frame, scene.particles.radius)
        has_temperature = frame.temperatures is not None
        ellipsoid = ellipsoids is not None
        peak = frame.peak_temperatures is not None
        bulk = SplatBatch(count, far, has_temperature, ellipsoid, has_peak=peak)
        drop_batch = SplatBatch(
            count, far, has_temperature, ellipsoid, droplets=True, has_peak=peak
        )
        return DevicePrepared(
            bulk, drop_batch if drops else None, visible, box, reference_radius, nearest
        )

    def _upload(
        self,
        frame: ParticleFrame,
        droplets: npt.NDArray[np.bool_] | None,
        ellipsoids: tuple[npt.NDArray[np.float64], npt.NDArray[np.float32]] | None,
    ) -> None:
        buffers = self._buffers
        count = frame.count
        buffers.reserve(SPHERES, count)
        positions = frame.positions if ellipsoids is None else ellipsoids[0]
        buffers.write(POSITIONS, np.asarray(positions, dtype=np.float64))
        if ellipsoids is not None:
            buffers.write(AXES, np.asarray(ellipsoids[1], dtype=np.float32))
        elif frame.radii is not None:
            buffers.write(RADII, np.asarray(frame.radii, dtype=np.float32))
        if frame.temperatures is not None:
            buffers.write(TEMPERATURES, np.asarray(frame.temperatures, dtype=np.float32))
        if frame.peak_temperatures is not None:
            buffers.write(PEAKS, np.asarray(frame.peak_temperatures, dtype=np.float32))
        if droplets is not None:
            buffers.write(DROPLETS, droplets.view(np.uint8))
        with self._context.gl.clock:
            buffers.buffer(SUMMARY).write(_SUMMARY_INIT)

    def _dispatch(
        self,
        camera: Camera,
        scene: Scene,
        frame: ParticleFrame,
        count: int,
        droplets: npt.NDArray[np.bool_] | None,
        ellipsoids: object | None,
    ) -> npt.NDArray[np.int32]:
        """Run the compute shader over every particle; the summary it reduced (read back)."""
        shader = self._context.programs.compute(COMPUTE_SHADER)
        far_limit = scene.camera.far
        has_radii = frame.radii is not None and ellipsoids is None
        flags = (has_radii, droplets is not None, ellipsoids is not None)

        def values() -> dict[str, object]:
            tan_y = camera.tan_half_fov_y
            return {
                "u_eye": tuple(float(v) for v in camera.eye),
                "u_rotation": tuple(float(v) for v in camera.rotation.T.ravel()),  # column-major
                "u_radius": float(scene.particles.radius),
                "u_has_radii": flags[0],
                "u_has_droplets": flags[1],
                "u_ellipsoid": flags[2],
                "u_near": float(camera.near),
                "u_far_limit": float(far_limit) if far_limit is not None else -1.0,
                "u_tan_half_fov": (tan_y * camera.aspect, tan_y),
                "u_size": (camera.width, camera.height),
            }

        set_group(shader, "frame", (camera, scene.particles.radius, far_limit, flags), values)
        self._buffers.bind()
        set_if_used(shader, "u_count", count)
        ctx = self._context.gl.ctx
        with self._context.gl.clock:
            dispatch_1d(shader, count, GROUP_SIZE)
            ctx.memory_barrier(moderngl.ALL_BARRIER_BITS)
            summary = self._buffers.buffer(SUMMARY).read()
        return np.frombuffer(summary, dtype=np.int32)
