"""The analytic figures of a real frame (the dam break's), where the surface bench's spatter
scene has its own analytic truth: the union of the frame's particle spheres, ray cast.

* **edge alpha**: |alpha - coverage| over the pixels the spheres' silhouettes cross, coverage
  from the union ray cast at 4 x 4 sub-pixels (`surface_quality.supersampled_coverage`, as the
  spatter's), over all of them and over the silhouettes against background: the edge pixels
  next to a pixel that both the union and a reference reconstruction (pysplashsurf's, also
  supersampled) leave empty. The others are gaps between the spheres of sparse sheets, which
  the reference covers (`GapCoverage` measures how much) and the renderer's gap closing
  (`[quality] close_gaps`) draws whole: there the union's coverage is not the surface's;
* **droplet error**: the normal error over the pixels whose nearest sphere is a lone particle
  (no other within the SPH support), against that sphere's normal: the spatter's droplet
  figure on a real frame's spray.

Plain numpy (scipy's KD-tree for the neighbours), no GL of its own.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from sphrender.server.bench.analytic import angle_deg
from sphrender.server.bench.scenes import Truth, spheres_truth
from sphrender.server.bench.surface_quality import supersampled_coverage
from sphrender.server.engine.frame_output import RenderedFrame
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.scene import CameraConfig

F64 = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class SphereUnion:
    """The union of a frame's particle spheres seen by one camera: its 4 x 4 supersampled
    coverage per pixel, its truth (`Truth`: the nearest sphere's hit, depth and normal per
    pixel) and the pixels whose nearest sphere is a lone particle (`droplet`)."""

    coverage: F64
    truth: Truth
    droplet: Mask


@dataclass(frozen=True)
class EdgeAlpha:
    """Mean |alpha - coverage| over the union's edge pixels (0 < coverage < 1): all of them,
    the silhouettes against background (`edge_classes`), and the share of the others
    (the gaps)."""

    all: float
    silhouettes: float
    gap_share: float


@dataclass(frozen=True)
class GapCoverage:
    """Means over the union's gaps (`edge_classes`): the union's coverage, the render's alpha
    and the reference reconstruction's coverage."""

    spheres: float
    alpha: float
    reference: float


def lone_particles(positions: F64, support: float) -> Mask:
    """The particles with no other particle within `support` (coincident ones are not lone)."""
    from scipy.spatial import cKDTree

    if len(positions) < 2:
        return np.ones(len(positions), bool)
    distances, _ = cKDTree(positions).query(positions, k=2)
    return np.asarray(distances[:, 1] > support)


def sphere_union(
    config: CameraConfig, width: int, height: int, positions: F64, radius: float, support: float
) -> SphereUnion:
    """The union of the spheres of `radius` at `positions` through `config` at `width` x
    `height`; droplets are the lone particles (`lone_particles` with `support`)."""
    coverage = supersampled_coverage(
        lambda camera: spheres_truth(camera, positions, radius), config, width, height
    )
    camera = Camera.from_config(config, width, height)
    truth = spheres_truth(camera, positions, radius)
    lone = spheres_truth(camera, positions[lone_particles(positions, support)], radius)
    droplet = lone.hit & (lone.depth <= truth.depth)
    return SphereUnion(coverage, truth, droplet)


def edge_classes(coverage: F64, reference: F64) -> tuple[Mask, Mask]:
    """The edge pixels of the union's `coverage` (0 < c < 1) next to (8-neighbours) a pixel
    that both it and the `reference` coverage leave empty (a silhouette against background:
    both surfaces agree there is none), and the others (gaps between spheres that the
    reference covers)."""
    edge = (coverage > 0.0) & (coverage < 1.0)
    empty = np.pad((coverage <= 0.0) & (reference <= 0.0), 1)  # beyond the image: no pixel
    height, width = coverage.shape
    beside = np.zeros_like(edge)
    for dy in (0, 1, 2):
        for dx in (0, 1, 2):
            beside |= empty[dy : dy + height, dx : dx + width]
    return edge & beside, edge & ~beside


def edge_alpha(alpha: F64, coverage: F64, reference: F64) -> EdgeAlpha:
    """`EdgeAlpha` of the render's `alpha` against the union's `coverage`, its edge pixels
    told apart with the `reference` coverage (nan where a class is empty)."""
    error = np.abs(alpha - coverage)
    silhouettes, gaps = edge_classes(coverage, reference)
    edges = silhouettes | gaps

    def mean(mask: Mask) -> float:
        return float(error[mask].mean()) if mask.any() else float("nan")

    share = float(gaps.sum()) / max(int(edges.sum()), 1)
    return EdgeAlpha(mean(edges), mean(silhouettes), share)


def gap_coverage(alpha: F64, coverage: F64, reference: F64) -> GapCoverage:
    """`GapCoverage` of the render's `alpha` and the `reference` coverage (nan without gaps)."""
    _, gaps = edge_classes(coverage, reference)
    if not gaps.any():
        return GapCoverage(float("nan"), float("nan"), float("nan"))
    return GapCoverage(
        float(coverage[gaps].mean()), float(alpha[gaps].mean()), float(reference[gaps].mean())
    )


def droplet_error_deg(frame: RenderedFrame, union: SphereUnion) -> float:
    """Mean normal error over the droplet pixels the render covers (nan without any)."""
    assert frame.normals is not None and frame.depth is not None
    mask = union.droplet & np.isfinite(frame.depth)
    if not mask.any():
        return float("nan")
    normals = frame.normals.astype(np.float64)[mask]
    return float(angle_deg(normals, union.truth.normals[mask]).mean())
