"""The surface-quality figures of real splashy frames, beyond the per-scene normal error:

* **spatter**: isolated droplets over a pool (a lattice slab), analytic truth (the union of the
  slab's box and the droplets' spheres); the droplet error is the normal error over the pixels
  whose true surface is a droplet, compared with the same figure of the unfiltered splat;
* **edge alpha error**: |alpha - true sub-pixel coverage| over the pixels the true silhouette
  crosses, coverage from a 4 x 4 supersampled ray cast (the analytic truth at 4x resolution,
  box-filtered) of the union of the particle spheres (the impostor geometry: this measures the
  anti-aliasing, not the reconstruction);
* **silhouette band error**: the mean normal error over pixels within BAND_PX pixels of the
  reference's silhouette (where its coverage or depth jumps), which the interior figure hides:
  normals that flip at a beaded edge;
* **flicker**: the same frame with every particle moved by a small random offset (a fraction of
  r): the mean normal change over pixels covered in both renders (a live stream shows it as
  shimmer).

Plain numpy, no GL of its own: the caller renders (`SurfaceRenderer.render` with Z and N).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from sphrender.server.bench.analytic import angle_deg
from sphrender.server.bench.scenes import BenchScene, Truth, box_truth, spheres_truth
from sphrender.server.content.lattice import lattice_slab
from sphrender.server.engine.frame_output import RenderedFrame
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.scene import CameraConfig

F64 = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]
SUPERSAMPLE = 4
BAND_PX = 3


@dataclass(frozen=True)
class SpatterTruth(Truth):
    """`Truth` plus which pixels see a droplet (not the pool) first."""

    droplet: Mask = field(default_factory=lambda: np.zeros((0, 0), bool))


def union_truth(parts: list[Truth]) -> tuple[Truth, npt.NDArray[np.intp]]:
    """Nearest surface of several truths per pixel, and the index of the part it came from."""
    depth = np.stack([p.depth for p in parts])
    nearest = np.argmin(depth, axis=0)
    best = np.take_along_axis(depth, nearest[None], axis=0)[0]
    normals = np.stack([p.normals for p in parts])
    normal = np.take_along_axis(normals, nearest[None, ..., None], axis=0)[0]
    hit = np.isfinite(best)
    return Truth(hit, best, np.where(hit[..., None], normal, 0.0)), nearest


def spatter_scene(droplets: int = 40, radius: float = 0.01, seed: int = 5) -> BenchScene:
    """A pool (lattice slab, 4 layers) with `droplets` single-particle droplets 3-20 r above it,
    at least 5 r apart: weld spatter over the pool. The camera looks down at 35 degrees."""
    size = 0.5
    pool = lattice_slab(size, size, 4, radius)
    rng = np.random.default_rng(seed)
    centers: list[F64] = []
    while len(centers) < droplets:
        xz = rng.uniform(-0.4 * size, 0.4 * size, 2)
        candidate = np.array([xz[0], rng.uniform(3 * radius, 20 * radius), xz[1]])
        if all(np.linalg.norm(candidate - c) >= 5 * radius for c in centers):
            centers.append(candidate)
    drops = np.array(centers)
    truth = spatter_truth(pool, drops, radius)

    return BenchScene(
        "spatter",
        f"{droplets} droplets over a pool, {len(pool) + droplets} particles",
        np.concatenate([pool, drops]),
        radius,
        {"eye": [0.12, 0.26, 0.38], "target": [0.0, 0.02, 0.0], "fov_y": 40.0},
        truth,
    )


def spatter_truth(pool: F64, drops: F64, radius: float) -> Callable[[Camera], SpatterTruth]:
    """The truth of a spatter frame: the pool's box (its particles' extent + r) and the
    droplets' spheres, nearest first."""
    lower = pool.min(axis=0) - radius
    upper = pool.max(axis=0) + radius

    def truth(camera: Camera) -> SpatterTruth:
        combined, source = union_truth(
            [box_truth(camera, lower, upper), spheres_truth(camera, drops, radius)]
        )
        return SpatterTruth(
            combined.hit, combined.depth, combined.normals, droplet=combined.hit & (source == 1)
        )

    return truth


def droplet_error_deg(frame: RenderedFrame, truth: SpatterTruth) -> float:
    """Mean normal error over pixels whose true surface is a droplet and that the render covers
    (silhouette pixels facing away by more than ~73 degrees excluded, as `surface_metrics`)."""
    assert frame.normals is not None and frame.depth is not None
    mask = truth.droplet & np.isfinite(frame.depth)
    if not mask.any():
        return float("nan")
    return float(angle_deg(frame.normals.astype(np.float64)[mask], truth.normals[mask]).mean())


def supersampled_coverage(
    truth_of: Callable[[Camera], Truth], camera_config: CameraConfig, width: int, height: int
) -> F64:
    """True sub-pixel coverage per pixel: the truth at SUPERSAMPLE x resolution, box-filtered."""
    s = SUPERSAMPLE
    fine = Camera.from_config(camera_config, width * s, height * s)
    hit = truth_of(fine).hit.astype(np.float64)
    return hit.reshape(height, s, width, s).mean(axis=(1, 3))


def edge_alpha_error(alpha: F64, coverage: F64) -> float:
    """Mean |alpha - coverage| over the pixels the true silhouette crosses (0 < coverage < 1)."""
    edge = (coverage > 0.0) & (coverage < 1.0)
    return float(np.abs(alpha[edge] - coverage[edge]).mean()) if edge.any() else float("nan")


def jittered(
    positions: F64, radius: float, fraction: float, seed: int = 11, *, fixed_length: bool = False
) -> F64:
    """Every particle moved by a Gaussian offset of `fraction` r per axis (on average by
    1.60 `fraction` r: the mean of a 3-D Gaussian's length), or with `fixed_length` by
    exactly `fraction` r in a uniformly random direction ("every particle moved by 2 % of r"
    read literally; benchmarks/studies/jitter_readings.py measures both)."""
    rng = np.random.default_rng(seed)
    offsets = rng.normal(0.0, fraction * radius, positions.shape)
    if fixed_length:
        lengths = np.linalg.norm(offsets, axis=-1, keepdims=True)
        offsets *= fraction * radius / np.maximum(lengths, np.finfo(np.float64).tiny)
    return positions + offsets


def flicker_deg(a: RenderedFrame, b: RenderedFrame) -> tuple[float, float]:
    """Mean and 99th-percentile normal change between two renders over pixels both cover."""
    assert a.normals is not None and b.normals is not None
    assert a.depth is not None and b.depth is not None
    mask = np.isfinite(a.depth) & np.isfinite(b.depth)
    if not mask.any():
        return float("nan"), float("nan")
    change = angle_deg(a.normals.astype(np.float64)[mask], b.normals.astype(np.float64)[mask])
    return float(change.mean()), float(np.percentile(change, 99))


def silhouette_band(truth: Truth, radius: float, width_px: int = BAND_PX) -> Mask:
    """Pixels within `width_px` of the truth's silhouettes: where the hit mask changes, or the
    depth between neighbours jumps by more than 4 particle radii (an edge in front of a
    farther surface)."""
    hit = truth.hit
    depth = np.where(hit, truth.depth, 0.0)
    edge = np.zeros_like(hit)
    for axis in (0, 1):
        a = np.moveaxis(hit, axis, 0)
        d = np.moveaxis(depth, axis, 0)
        jump = (a[1:] != a[:-1]) | (a[1:] & a[:-1] & (np.abs(d[1:] - d[:-1]) > 4.0 * radius))
        e = np.moveaxis(edge, axis, 0)
        e[1:] |= jump
        e[:-1] |= jump
    band = edge.copy()
    for _ in range(width_px - 1):
        grown = band.copy()
        grown[1:] |= band[:-1]
        grown[:-1] |= band[1:]
        grown[:, 1:] |= band[:, :-1]
        grown[:, :-1] |= band[:, 1:]
        band = grown
    return band & hit


def band_error_deg(frame: RenderedFrame, truth: Truth, band: Mask) -> float:
    """Mean normal error over the band pixels the render covers."""
    assert frame.normals is not None and frame.depth is not None
    mask = band & np.isfinite(frame.depth)
    if not mask.any():
        return float("nan")
    return float(angle_deg(frame.normals.astype(np.float64)[mask], truth.normals[mask]).mean())


def shift_tolerant_band_error_deg(
    frame: RenderedFrame, truth: Truth, band: Mask, shift_px: int = 1
) -> float:
    """The band error forgiving a rim placed up to `shift_px` pixels off the truth's: per band
    pixel the smallest angle between the render's normal and the truth's normals within
    +-shift_px (a square window; truth pixels without surface never match).

    Why: against an offline reconstruction that is not the renderer's surface (splashsurf's
    iso-0.6 level set lies about 0.2 r outside the particle spheres, half a pixel at the dam
    break's 2.4 px per radius), the normal 1 pixel inside a rim turns by tens of degrees, so the
    plain band error measures where two surface definitions put the rim, not whether the
    normals at the rim are right (the exact particle spheres score 47 deg there). A normal that
    flips or follows a bead matches no neighbour and still counts."""
    assert frame.normals is not None and frame.depth is not None
    mask = band & np.isfinite(frame.depth)
    if not mask.any():
        return float("nan")
    normals = frame.normals.astype(np.float64)
    height, width = mask.shape
    pad = shift_px
    ref = np.pad(truth.normals, ((pad, pad), (pad, pad), (0, 0)))
    hit = np.pad(truth.hit, pad)
    best = np.full(mask.shape, np.inf)
    for dy in range(-pad, pad + 1):
        for dx in range(-pad, pad + 1):
            window = (slice(pad + dy, pad + dy + height), slice(pad + dx, pad + dx + width))
            cos = np.clip(np.einsum("ijk,ijk->ij", normals, ref[window]), -1.0, 1.0)
            angle = np.where(hit[window], np.degrees(np.arccos(cos)), np.inf)
            best = np.minimum(best, angle)
    return float(best[mask].mean())


def split_flicker_deg(
    a: npt.NDArray[np.float64], b: npt.NDArray[np.float64], covered: Mask, band: Mask
) -> tuple[float, float, float]:
    """Mean normal change between the (H, W, 3) normals `a` and `b` over the `covered` pixels
    within `band` and outside it, and the band's share of them: where a flicker comes from
    (a rim's grazing normals turn by degrees when it moves by a fraction of a pixel, the
    inside by far less)."""
    inside, rim = covered & ~band, covered & band
    count = max(int(covered.sum()), 1)

    def mean(mask: Mask) -> float:
        return float(angle_deg(a[mask], b[mask]).mean()) if mask.any() else float("nan")

    return mean(rim), mean(inside), float(rim.sum()) / count


def truth_flicker_deg(a: Truth, b: Truth) -> float:
    """The truth's own flicker: mean normal change between the truths of a frame and of its
    jittered copy over pixels both cover (the floor of a renderer's flicker: the true surface
    of moved particles does move)."""
    mask = a.hit & b.hit
    if not mask.any():
        return float("nan")
    return float(angle_deg(a.normals[mask], b.normals[mask]).mean())
