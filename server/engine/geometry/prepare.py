"""Prepare: particles to the float32, view-space, culled array the splat uploads.

Float64 until the eye is subtracted and the positions are rotated to view space, so coordinates
of 1e5 render like coordinates near the origin; then the visible particles (in front of the
near plane, inside the side planes, before `far`) become one (N, 4) centre + radius array.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from sphrender.core.frame import ParticleFrame
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.scene import Scene


@dataclass(frozen=True)
class PreparedParticles:
    """Visible particles in view space, float32, ready to upload: (N, 4) centre xyz + radius."""

    center_radius: npt.NDArray[np.float32]
    far: float
    reference_radius: float
    temperatures: npt.NDArray[np.float32] | None = None  # (N,) kelvin of the kept particles
    droplets: npt.NDArray[np.bool_] | None = None  # (N,) which kept particles are droplets
    #: (N, 3, 3) world-space ellipsoid semi-axes (columns) when the particles are anisotropic
    #: (the splat's vertex stage rotates them to view space); `center_radius[:, 3]` is then each
    #: ellipsoid's bounding radius (its longest semi-axis).
    axes: npt.NDArray[np.float32] | None = None
    peak_temperatures: npt.NDArray[np.float32] | None = None  # (N,) kelvin, as temperatures

    def subset(self, rows: npt.NDArray[np.bool_]) -> PreparedParticles:
        """The particles where `rows` is true (same far and reference radius)."""
        return PreparedParticles(
            np.ascontiguousarray(self.center_radius[rows]),
            self.far,
            self.reference_radius,
            None if self.temperatures is None else np.ascontiguousarray(self.temperatures[rows]),
            None if self.droplets is None else self.droplets[rows],
            None if self.axes is None else np.ascontiguousarray(self.axes[rows]),
            None
            if self.peak_temperatures is None
            else np.ascontiguousarray(self.peak_temperatures[rows]),
        )


#: `typical_radius` reads at most this many radii (evenly strided), so its cost does not grow
#: with the frame: the median of 16384 samples is within a few per cent of the exact one for any
#: smooth distribution of radii, and it only sizes the smoothing kernel.
RADIUS_SAMPLES = 16384


def typical_radius(radii: npt.NDArray[np.floating]) -> float:
    """The median particle radius (of an even sample of at most RADIUS_SAMPLES radii): the radius
    the smoothing kernel follows when the SPH stage does not say."""
    step = max(1, -(-radii.shape[0] // RADIUS_SAMPLES))
    return float(np.median(radii[::step]))


def frame_reference_radius(frame: ParticleFrame, default: float) -> float:
    """The radius the smoothing kernel follows when the SPH stage does not say: the frame's
    typical radius when it has radii (and particles), else the scene's `default`."""
    return typical_radius(frame.radii) if frame.radii is not None and frame.count else default


def prepare_particles(
    frame: ParticleFrame,
    camera: Camera,
    scene: Scene,
    *,
    reference_radius: float | None = None,
    droplets: npt.NDArray[np.bool_] | None = None,
    ellipsoids: tuple[npt.NDArray[np.float64], npt.NDArray[np.float32]] | None = None,
) -> PreparedParticles:
    """Float64 eye-relative view-space positions, culled, then float32 (see module docstring).

    `reference_radius` (the radius the smoothing kernel follows) defaults to the frame's median
    radius; the SPH stage passes the radius from before eq 29 so adaptive radii do not resize
    the filter. `droplets` (per input particle) follows the culling like the temperatures.
    `ellipsoids` = (centres float64 (N, 3), world semi-axes float32 (N, 3, 3), columns): the
    particles are drawn as those ellipsoids, culled by their bounding spheres."""
    radius = scene.particles.radius
    radii: npt.NDArray[np.floating] = (
        frame.radii if frame.radii is not None else np.full(frame.count, radius, np.float32)
    )
    positions = frame.positions
    if ellipsoids is not None:
        positions = ellipsoids[0]
        radii = np.linalg.norm(ellipsoids[1], axis=1).max(axis=1)  # longest column
    view = camera.to_view(positions)
    far_config = scene.camera.far
    keep = camera.visible_mask(view, radii, far_config)
    view = view[keep]
    kept_radii = np.asarray(radii, dtype=np.float64)[keep]
    if far_config is not None:
        far = far_config
    elif view.shape[0]:
        far = float(np.max(-view[:, 2] + kept_radii)) * 1.001
    else:
        far = camera.near * 2.0
    far = max(far, camera.near * 1.001)
    center_radius = np.empty((view.shape[0], 4), dtype=np.float32)
    center_radius[:, :3] = view
    center_radius[:, 3] = kept_radii
    if reference_radius is None:
        reference_radius = frame_reference_radius(frame, radius)
    temperatures = (
        np.ascontiguousarray(frame.temperatures[keep], dtype=np.float32)
        if frame.temperatures is not None
        else None
    )
    peaks = (  # only the heat tint reads them
        np.ascontiguousarray(frame.peak_temperatures[keep], dtype=np.float32)
        if frame.peak_temperatures is not None and scene.material.heat_tint
        else None
    )
    kept_droplets = None if droplets is None else droplets[keep]
    axes = None if ellipsoids is None else np.ascontiguousarray(ellipsoids[1][keep])
    return PreparedParticles(
        center_radius, far, reference_radius, temperatures, kept_droplets, axes, peaks
    )
