"""Eq 29: the adaptive particle radius, from the SPH densities and the surface flags (numpy), and
the radius a frame's SPH parameters follow."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from sphrender.core.frame import ParticleFrame
from sphrender.server.scene import Scene

F32 = npt.NDArray[np.float32]
Bools = npt.NDArray[np.bool_]


def frame_particle_radius(frame: ParticleFrame, scene: Scene) -> float:
    """The radius that defines h and m: the median client radius, else the scene's."""
    if frame.radii is not None and frame.count:
        return float(np.median(frame.radii))
    return scene.particles.radius


def surface_density(density: npt.NDArray[np.floating], surface: Bools) -> float | None:
    """Eq 29's d_surface: mean density of the surface particles; None when there are none."""
    if not surface.any():
        return None
    return float(np.mean(density[surface], dtype=np.float64))


def adaptive_radii(
    density: npt.NDArray[np.floating],
    body_radius: float | npt.NDArray[np.floating],
    d_surface: float | None,
    *,
    min_fraction: float,
    decline: float,
) -> F32:
    """Eq 29 with a dimensionless decline k (see `SphConfig.radius_decline`)::

        r = r_body                                        d >= d_surface
        r = r_body (1 - ((d_surface - d) / d_surface)^2 / k)   d < d_surface
        r = max(r, min_fraction r_body)

    The thesis writes ``r_body - (d_surface - d)^2 / k_thesis``; with k_thesis = k d_surface^2 /
    r_body both agree, and k no longer depends on the scene's units. Without surface particles
    there is no d_surface and every particle keeps r_body.
    """
    density64 = np.asarray(density, dtype=np.float64)
    body = np.broadcast_to(np.asarray(body_radius, dtype=np.float64), density64.shape)
    if d_surface is None or d_surface <= 0.0:
        return np.ascontiguousarray(body, dtype=np.float32)
    deficit = np.clip((d_surface - density64) / d_surface, 0.0, None)
    radius = body * (1.0 - deficit**2 / decline)
    return np.maximum(radius, min_fraction * body).astype(np.float32)
