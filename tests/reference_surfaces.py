"""Ground-truth metrics of rendered surfaces that see depth as well as orientation.

`analytic_scenes.ball_errors` compares each rendered normal with the radial direction at the
*rendered* point, so a surface at the wrong depth whose normals are consistent with its own
shape scores as correct. Here every pixel's view ray is intersected with the true sphere: the
normal is compared with the true normal at that intersection and the depth with its depth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from sphrender.server.bench.analytic import angle_deg, iou, pixel_rays
from sphrender.server.engine.frame_output import RenderedFrame
from sphrender.server.engine.geometry.camera import Camera

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class SphereTruth:
    """Per pixel, rows top first: whether the pixel's ray hits the sphere, the eye depth of the
    front hit (inf = none), the unit world normal there and its facing n.v."""

    hit: npt.NDArray[np.bool_]
    depth: F64
    normals: F64
    facing: F64


def sphere_truth(camera: Camera, center: F64, radius: float) -> SphereTruth:
    rays = pixel_rays(camera)
    oc = np.asarray(center, dtype=np.float64) - rays.origin
    b = rays.directions @ oc
    perp = oc[None, None, :] - b[..., None] * rays.directions
    disc = radius * radius - np.einsum("ijk,ijk->ij", perp, perp)
    hit = (disc >= 0.0) & (b > 0.0)
    t = np.where(hit, b - np.sqrt(np.maximum(disc, 0.0)), 0.0)
    point = rays.origin + rays.directions * t[..., None]
    normals = np.where(hit[..., None], (point - center) / radius, 0.0)
    facing = -np.einsum("ijk,ijk->ij", normals, rays.directions)
    return SphereTruth(hit, np.where(hit, t * rays.view_z, np.inf), normals, facing)


@dataclass(frozen=True)
class SphereErrors:
    """Over pixels covered by both the render and the true sphere where the sphere faces the
    camera: normal error (degrees) against the true normal at the pixel's true hit, depth error
    |z_render - z_true| in particle radii, and the signed mean depth offset (positive = the
    render lies behind the true surface); IoU of the coverage."""

    normal_mean_deg: float
    normal_p95_deg: float
    normal_max_deg: float
    depth_mean_radii: float
    depth_p95_radii: float
    depth_bias_radii: float
    pixels: int
    silhouette_iou: float

    def __str__(self) -> str:
        return (
            f"normal error mean {self.normal_mean_deg:.2f} p95 {self.normal_p95_deg:.2f} "
            f"max {self.normal_max_deg:.2f} deg; depth error mean {self.depth_mean_radii:.3f} "
            f"p95 {self.depth_p95_radii:.3f} r, bias {self.depth_bias_radii:+.3f} r; "
            f"{self.pixels} px; IoU {self.silhouette_iou:.4f}"
        )


def sphere_errors(
    frame: RenderedFrame,
    camera: Camera,
    center: F64,
    surface_radius: float,
    particle_radius: float,
    *,
    min_facing: float = 0.3,
) -> SphereErrors:
    if frame.normals is None or frame.depth is None:
        raise ValueError("sphere_errors needs the depth and normal AOVs")
    truth = sphere_truth(camera, center, surface_radius)
    covered = np.isfinite(frame.depth)
    mask = truth.hit & covered & (truth.facing >= min_facing)
    normals = frame.normals.astype(np.float64)[mask]
    normal = angle_deg(normals, truth.normals[mask])
    offset = (frame.depth.astype(np.float64)[mask] - truth.depth[mask]) / particle_radius
    if not mask.any():
        nan = float("nan")
        return SphereErrors(nan, nan, nan, nan, nan, nan, 0, iou(covered, truth.hit))
    depth = np.abs(offset)
    return SphereErrors(
        float(normal.mean()),
        float(np.percentile(normal, 95)),
        float(normal.max()),
        float(depth.mean()),
        float(np.percentile(depth, 95)),
        float(offset.mean()),
        int(mask.sum()),
        iou(covered, truth.hit),
    )
