"""Render-against-truth metrics of the benchmark table.

* normal error (degrees, mean and p95) over pixels that both the render and the truth cover and
  where the true surface faces the camera (n . v >= 0.3; grazing pixels measure the silhouette,
  which IoU covers); for a single ball, against the radial direction at the rendered point (the
  engine's bound, `analytic.ball_errors`), else against the true normal at the pixel;
* depth error in particle radii: mean |z_render - z_true| / r over the same pixels;
* silhouette IoU of the coverage masks;
* image error against a high-quality render of the same scene: PSNR (dB) of the display-referred
  (tone-mapped, sRGB) RGB, composited on black.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from sphrender.server.bench.analytic import angle_deg, iou, reconstruct_world_positions
from sphrender.server.bench.scenes import Truth
from sphrender.server.engine.frame_output import RenderedFrame
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.output import encoders

MIN_FACING = 0.3


@dataclass(frozen=True)
class SurfaceMetrics:
    normal_mean_deg: float
    normal_p95_deg: float
    depth_err_radii: float
    silhouette_iou: float


def surface_metrics(
    frame: RenderedFrame, camera: Camera, truth: Truth, radius: float
) -> SurfaceMetrics:
    if frame.normals is None or frame.depth is None:
        raise ValueError("surface_metrics needs the depth and normal AOVs")
    covered = np.isfinite(frame.depth)
    directions = _directions(camera)
    facing = -np.einsum("ijk,ijk->ij", truth.normals, directions)
    mask = truth.hit & covered & (facing >= MIN_FACING)
    normals = frame.normals.astype(np.float64)
    if truth.sphere_center is not None:
        radial = reconstruct_world_positions(frame, camera) - truth.sphere_center
        reference = radial / np.linalg.norm(radial, axis=2, keepdims=True)
    else:
        reference = truth.normals
    nan = float("nan")
    if not mask.any():
        return SurfaceMetrics(nan, nan, nan, iou(covered, truth.hit))
    errors = angle_deg(normals[mask], reference[mask])
    depth_err = np.abs(frame.depth.astype(np.float64)[mask] - truth.depth[mask]) / radius
    return SurfaceMetrics(
        float(errors.mean()),
        float(np.percentile(errors, 95)),
        float(depth_err.mean()),
        iou(covered, truth.hit),
    )


def _directions(camera: Camera) -> npt.NDArray[np.float64]:
    from sphrender.server.bench.analytic import pixel_rays

    return pixel_rays(camera).directions


def display_rgb(frame: RenderedFrame) -> npt.NDArray[np.float32]:
    """Tone-mapped sRGB in [0, 1], premultiplied by coverage (on black), as the PNG shows it."""
    display = encoders.tone_map_for_display(frame.rgba, 0.0, "aces")
    return (display[:, :, :3] * display[:, :, 3:4]).astype(np.float32)


def psnr_db(image: npt.NDArray[np.float32], reference: npt.NDArray[np.float32]) -> float:
    mse = float(np.mean((image.astype(np.float64) - reference.astype(np.float64)) ** 2))
    return math.inf if mse == 0.0 else 10.0 * math.log10(1.0 / mse)


@dataclass(frozen=True)
class SolidMetrics:
    """A solid scene's normal error on flat faces and within `band` of an edge (degrees), and
    the IoU of the pixels seen through its root gap (NaN without a gap)."""

    face_mean_deg: float
    face_p95_deg: float
    edge_mean_deg: float
    edge_p95_deg: float
    gap_iou: float


def solid_metrics(
    frame: RenderedFrame, camera: Camera, truth: Truth, radius: float, band_radii: float = 3.0
) -> SolidMetrics:
    """Normal errors split at `band_radii` r from the true face's nearest edge (same pixel
    rule as `surface_metrics`), and the see-through IoU inside the truth's gap window."""
    if frame.normals is None or frame.depth is None or truth.edge_distance is None:
        raise ValueError("solid_metrics needs the depth and normal AOVs and an edge truth")
    covered = np.isfinite(frame.depth)
    facing = -np.einsum("ijk,ijk->ij", truth.normals, _directions(camera))
    mask = truth.hit & covered & (facing >= MIN_FACING)
    errors = angle_deg(frame.normals.astype(np.float64), truth.normals)
    near_edge = truth.edge_distance <= band_radii * radius

    def stats(where: npt.NDArray[np.bool_]) -> tuple[float, float]:
        values = errors[where]
        if values.size == 0:
            return float("nan"), float("nan")
        return float(values.mean()), float(np.percentile(values, 95))

    gap = float("nan")
    if truth.gap_window is not None:
        window = truth.gap_window
        gap = iou(window & ~covered, window & ~truth.hit)
    return SolidMetrics(*stats(mask & ~near_edge), *stats(mask & near_edge), gap)
