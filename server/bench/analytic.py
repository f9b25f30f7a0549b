"""Scenes with known answers, and the metrics that compare a render against them.

Used by the tests (ground truth with derived tolerances) and by `sphrender bench`; the product
never imports it. Everything here is numpy on the CPU; nothing touches GL. The particle lattices
the scenes are made of live in `sphrender.server.content.lattice` (the demo uses them too).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from sphrender.server.engine.frame_output import RenderedFrame
from sphrender.server.engine.geometry.camera import Camera

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class PixelRays:
    """World-space rays through every pixel centre, rows top first (as `RenderedFrame`)."""

    origin: F64  # (3,)
    directions: F64  # (H, W, 3) unit vectors
    view_z: F64  # (H, W) -z_view component of each unit direction (cosine to the view axis)


def pixel_rays(camera: Camera) -> PixelRays:
    h, w = camera.height, camera.width
    ys = (np.arange(h)[::-1] + 0.5) / h * 2.0 - 1.0  # row 0 = top = ndc +1
    xs = (np.arange(w) + 0.5) / w * 2.0 - 1.0
    ty = camera.tan_half_fov_y
    tx = ty * camera.aspect
    view = np.empty((h, w, 3))
    view[:, :, 0] = xs[None, :] * tx
    view[:, :, 1] = ys[:, None] * ty
    view[:, :, 2] = -1.0
    view /= np.linalg.norm(view, axis=2, keepdims=True)
    world = view @ camera.rotation  # R^T applied to row vectors
    return PixelRays(camera.eye.copy(), world, -view[:, :, 2])


def sphere_hits(camera: Camera, center: F64, radius: float) -> tuple[npt.NDArray[np.bool_], F64]:
    """Pixels whose centre ray hits the sphere, and the eye depth of the front hit (inf else)."""
    rays = pixel_rays(camera)
    oc = center - rays.origin
    b = rays.directions @ oc
    perp = oc[None, None, :] - b[..., None] * rays.directions
    disc = radius * radius - np.einsum("ijk,ijk->ij", perp, perp)
    hit = (disc >= 0.0) & (b > 0.0)
    t = b - np.sqrt(np.maximum(disc, 0.0))
    depth = np.where(hit, t * rays.view_z, np.inf)
    return hit, depth


def reconstruct_world_positions(frame: RenderedFrame, camera: Camera) -> F64:
    """World position of every pixel's surface point from the Z AOV (NaN where no surface)."""
    if frame.depth is None:
        raise ValueError("the frame has no depth AOV")
    rays = pixel_rays(camera)
    t = frame.depth.astype(np.float64) / rays.view_z
    t = np.where(np.isfinite(t), t, np.nan)
    return rays.origin + rays.directions * t[..., None]


@dataclass(frozen=True)
class SurfaceErrors:
    """Angle errors (degrees) over the evaluated pixels, and the silhouette IoU."""

    mean_deg: float
    p95_deg: float
    max_deg: float
    evaluated_pixels: int
    silhouette_iou: float

    def __str__(self) -> str:
        return (
            f"normal error mean {self.mean_deg:.2f} deg, p95 {self.p95_deg:.2f} deg "
            f"over {self.evaluated_pixels} px; silhouette IoU {self.silhouette_iou:.4f}"
        )


def angle_deg(a: F64, b: F64) -> F64:
    cos = np.clip(np.einsum("...k,...k->...", a, b), -1.0, 1.0)
    return np.degrees(np.arccos(cos))


def iou(a: npt.NDArray[np.bool_], b: npt.NDArray[np.bool_]) -> float:
    union = np.count_nonzero(a | b)
    return 1.0 if union == 0 else np.count_nonzero(a & b) / union


def ball_errors(
    frame: RenderedFrame,
    camera: Camera,
    center: F64,
    surface_radius: float,
    *,
    min_facing: float = 0.3,
) -> SurfaceErrors:
    """Normal error against the radial direction at the reconstructed point, over pixels where
    the true sphere faces the camera (n . v >= `min_facing`) and the render has a surface; IoU of
    the coverage against the projected true sphere."""
    if frame.normals is None:
        raise ValueError("the frame has no normal AOV")
    true_hit, _ = sphere_hits(camera, center, surface_radius)
    covered = frame.rgba[:, :, 3] > 0.5
    rays = pixel_rays(camera)
    # facing of the true sphere at the true hit point
    oc = center - rays.origin
    b = rays.directions @ oc
    perp = oc[None, None, :] - b[..., None] * rays.directions
    disc = surface_radius**2 - np.einsum("ijk,ijk->ij", perp, perp)
    t_true = b - np.sqrt(np.maximum(disc, 0.0))
    true_point = rays.origin + rays.directions * t_true[..., None]
    true_normal = (true_point - center) / surface_radius
    facing = -np.einsum("ijk,ijk->ij", true_normal, rays.directions)
    mask = true_hit & covered & (facing >= min_facing)
    positions = reconstruct_world_positions(frame, camera)
    radial = positions - center
    radial /= np.linalg.norm(radial, axis=2, keepdims=True)
    errors = angle_deg(frame.normals.astype(np.float64)[mask], radial[mask])
    if errors.size == 0:
        return SurfaceErrors(float("nan"), float("nan"), float("nan"), 0, iou(covered, true_hit))
    return SurfaceErrors(
        float(errors.mean()),
        float(np.percentile(errors, 95)),
        float(errors.max()),
        int(errors.size),
        iou(covered, true_hit),
    )
