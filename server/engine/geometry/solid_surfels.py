"""Flat faces and sharp edges for solid particles: feature-aware surfels, built once per shape.

A solid's surface is drawn as flat discs (surfels), one per face a surface particle lies on,
in that face's plane grown by r and clipped by the particle's other faces: the depth test
composes them into planes meeting at sharp creases. The faces come from the particles alone:

1. surface particles: fewer neighbours than a full ball, or the neighbours' centroid off-centre;
2. face directions: votes from the surface particles (a flat neighbourhood's PCA normal, both
   ways on a sheet one particle thick, else the lean away from the neighbours' centroid),
   gathered into peaks on the sphere;
3. a particle lies on a face of direction n when no neighbour rises above it along n (it is
   extremal); the face's plane is fitted over its extremal neighbours on the same plane, so
   jitter averages out and parallel faces (a root gap's two sides) stay apart.

Particles with no face (thin rods, curved or rough bits) are drawn as spheres, and so are the
cores of particles on more than one face (edges), which the discs hide wherever they are whole.
numpy + scipy (cKDTree) on the host; `SolidSurfelCache` keeps the result while the solid
particles do not move.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

F64 = npt.NDArray[np.float64]
F32 = npt.NDArray[np.float32]

MAX_CLIP_PLANES = 3
NEIGHBOUR_SPACINGS = 2.1  # PCA and extremal tests: neighbours within this many spacings
FACE_SPACINGS = 3.1  # a face's plane is fitted over its particles within this many spacings
FLATNESS = 0.02  # smallest / middle PCA eigenvalue below this: the points lie on a plane
SAME_FACE_COS = float(np.cos(np.radians(15.0)))  # votes within 15 degrees are one direction
ON_PLANE_SPACINGS = 0.3  # a particle this close to a face's plane (in spacings) lies on it
SKIN_SPACINGS = 0.15  # a face's outer layer: within this of the local top (jitter is 0.05 s)
MAX_DIRECTIONS = 32
MAX_NEIGHBOURS = 48  # nearest neighbours looked at (a jittered lattice has 33 within 2.1 s)
ARC_SIN = float(np.sin(np.radians(5.0)))  # face directions looked for per solid
MIN_FACE_VOTES = 12  # fewer votes than this: no face (curved or rough bits stay spheres)
# Disc radius: covers the holes of a square lattice (0.71 s) and of a bevel's sheared rows
# (0.76 s at 30 degrees), with jitter to spare.
DISC_SPACINGS = 0.9
CORE_RADII = 0.75  # spheres under the discs: inside the faces whatever the jitter


@dataclass(frozen=True)
class SolidSurfels:
    """World-space surfels and fill spheres of one solid shape.

    discs: centre (on the face plane), unit normal, radius; clip planes (normal, offset: a
    fragment x is kept where n . x <= offset), unused planes have a zero normal and offset 1.
    spheres: centre, radius. `source` maps each disc / sphere to its particle (temperatures).
    """

    disc_centers: F64
    disc_normals: F64
    disc_radius: float
    clip_normals: F64  # (D, MAX_CLIP_PLANES, 3)
    clip_offsets: F64  # (D, MAX_CLIP_PLANES), world
    disc_source: npt.NDArray[np.int64]
    sphere_centers: F64
    sphere_radii: F64
    sphere_source: npt.NDArray[np.int64]
    spacing: float

    @property
    def count(self) -> int:
        return int(len(self.disc_centers) + len(self.sphere_centers))


def _padded_neighbours(
    tree: cKDTree, points: F64, radius: float, k: int = MAX_NEIGHBOURS
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.bool_]]:
    """The nearest `k` neighbours within `radius` as an (N, k) index array (self included;
    padding repeats the particle itself) and the mask of the real ones."""
    k = min(k, tree.n)
    distance, index = tree.query(points, k=k, distance_upper_bound=radius, workers=-1)
    distance, index = distance.reshape(len(points), k), index.reshape(len(points), k)
    mask = np.isfinite(distance)
    own = np.broadcast_to(np.arange(len(points))[:, None], index.shape)
    return np.where(mask, index, own).astype(np.int64), mask


def _spacing(tree: cKDTree, points: F64) -> float:
    """Median distance to the six nearest neighbours (a cubic lattice's spacing, jitter or not)."""
    distance, _ = tree.query(points, k=min(7, len(points)), workers=-1)
    return float(np.median(distance[:, 1:]))


def _pca(offsets: F64, mask: npt.NDArray[np.bool_]) -> tuple[F64, F64]:
    """Eigenvalues (ascending) and eigenvectors of each row's masked offsets' covariance."""
    weight = mask[..., None].astype(np.float64)
    count = np.maximum(weight.sum(axis=1), 1.0)
    mean = (offsets * weight).sum(axis=1) / count
    centred = (offsets - mean[:, None, :]) * weight
    covariance = np.einsum("nki,nkj->nij", centred, centred) / count[..., None]
    return np.linalg.eigh(covariance)


def _surface_and_directions(
    points: F64, index: npt.NDArray[np.int64], mask: npt.NDArray[np.bool_], spacing: float
) -> tuple[npt.NDArray[np.bool_], F64]:
    """Surface flags, and unit vectors voting for face directions: each flat surface
    particle's plane normal (both ways on a sheet one particle thick), each other surface
    particle's lean away from its neighbours' centroid."""
    offsets = points[index] - points[:, None, :]
    count = mask.sum(axis=1)
    full_ball = 4.0 / 3.0 * np.pi * NEIGHBOUR_SPACINGS**3
    centroid = (offsets * mask[..., None]).sum(axis=1) / count[:, None]
    lean = np.linalg.norm(centroid, axis=1)
    surface = (count < 0.7 * full_ball) | (lean > 0.25 * spacing)
    rows = np.flatnonzero(surface)
    values, vectors = _pca(offsets[rows], mask[rows] & surface[index[rows]])
    flat = values[:, 0] < FLATNESS * np.maximum(values[:, 1], 1e-30)
    normals = vectors[:, :, 0]
    side = np.einsum("ni,ni->n", normals, centroid[rows])
    normals = np.where((side > 0)[:, None], -normals, normals)
    two_sided = np.abs(side) < 0.25 * spacing
    leaning = ~flat & (lean[rows] > 0.15 * spacing)
    away = -centroid[rows][leaning] / lean[rows][leaning][:, None]
    votes = np.concatenate([normals[flat], -normals[flat & two_sided], away])
    return surface, votes


def _dominant_directions(votes: F64, min_votes: int) -> F64:
    """The face directions the votes agree on: greedy peaks of the votes' density on the
    sphere (votes within 15 degrees of a peak averaged into it and removed)."""
    directions: list[F64] = []
    remaining = votes
    while len(remaining) >= min_votes and len(directions) < MAX_DIRECTIONS:
        step = max(len(remaining) // 1024, 1)  # peaks found on a sample, averaged over all
        sample = remaining[::step]
        support = (sample @ sample.T > SAME_FACE_COS).sum(axis=1)
        best = sample[int(np.argmax(support))]
        near = remaining @ best > SAME_FACE_COS
        if near.sum() < min_votes:
            break
        mean = remaining[near].sum(axis=0)
        directions.append(mean / np.linalg.norm(mean))
        remaining = remaining[remaining @ directions[-1] <= SAME_FACE_COS]
    return np.array(directions).reshape(-1, 3)


@dataclass(frozen=True)
class _Faces:
    particle: npt.NDArray[np.int64]  # one row per (particle, face) the particle lies on, sorted
    normal: F64
    offset: F64  # plane n . x = offset, grown by r
    direction: npt.NDArray[np.int64]  # which face direction the row came from


def _extremal(
    points: F64,
    surface_rows: npt.NDArray[np.int64],
    neighbours: tuple[npt.NDArray[np.int64], npt.NDArray[np.bool_]],
    directions: F64,
    spacing: float,
) -> npt.NDArray[np.bool_]:
    """(surface particles, directions): no neighbour rises above the particle along the
    direction by more than the on-plane tolerance (in row blocks, float32 offsets)."""
    index, mask = neighbours
    out = np.zeros((len(surface_rows), len(directions)), np.bool_)
    towards = directions.T.astype(np.float32)
    for start in range(0, len(surface_rows), 8192):
        rows = surface_rows[start : start + 8192]
        offsets = (points[index[rows]] - points[rows][:, None, :]).astype(np.float32)
        offsets[~mask[rows]] = 0.0  # padding: the particle itself, which rises 0
        out[start : start + 8192] = (offsets @ towards).max(axis=1) < ON_PLANE_SPACINGS * spacing
    return out


def _faces_along(
    points: F64, rows: npt.NDArray[np.int64], direction: F64, spacing: float
) -> tuple[npt.NDArray[np.int64], F64, npt.NDArray[np.float64]]:
    """Of the surface particles extremal along `direction` (`rows`), those on faces: each
    one's face normal (refined over its connected patch) and plane offset (before growing by r,
    fitted over its patch's outer layer nearby)."""
    label = _patches(points[rows], direction, spacing) if len(rows) else np.zeros(0, np.int64)
    # A patch that is a row of particles is an edge (rounded), not a face: a chamfer the votes
    # made up, or a sheet's rim.
    lines = np.flatnonzero(_patch_spread(points[rows], label) < (0.3 * spacing) ** 2)
    if len(lines):
        keep = ~np.isin(label, lines)
        rows, label = rows[keep], np.unique(label[keep], return_inverse=True)[1]
    if len(rows) == 0:
        return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0)
    normal = np.empty((len(rows), 3))
    for patch in range(int(label.max()) + 1):
        members = label == patch
        normal[members] = _refined(points[rows][members], direction, spacing)
    height = np.einsum("ni,ni->n", points[rows], normal)
    near, real = _padded_neighbours(cKDTree(points[rows]), points[rows], FACE_SPACINGS * spacing)
    owner = np.broadcast_to(np.arange(len(rows))[:, None], near.shape)[real]
    other = near[real]
    same = label[other] == label[owner]
    top = np.full(len(rows), -np.inf)
    np.maximum.at(top, owner[same], height[other][same])
    # The plane is the outermost layer: heights near the local top, not a particle set back
    # at an obtuse edge that the on-plane tolerance let in.
    outer = same & (height[other] > top[owner] - SKIN_SPACINGS * spacing)
    total = np.bincount(owner[outer], weights=height[other][outer], minlength=len(rows))
    count = np.bincount(owner[outer], minlength=len(rows))
    return rows, normal, total / np.maximum(count, 1)


def _patches(face_points: F64, direction: F64, spacing: float) -> npt.NDArray[np.int64]:
    """Connected patches of particles extremal along one direction: neighbours on the same
    plane (a root gap's two sides, the two plates' far sides are different patches)."""
    pairs = cKDTree(face_points).query_pairs(NEIGHBOUR_SPACINGS * spacing, output_type="ndarray")
    height = face_points @ direction
    pairs = pairs[np.abs(height[pairs[:, 0]] - height[pairs[:, 1]]) < ON_PLANE_SPACINGS * spacing]
    n = len(face_points)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[1].astype(np.int64)


def _patch_spread(face_points: F64, label: npt.NDArray[np.int64]) -> F64:
    """Per patch, the variance across its main axis (0 for fewer than three points): small
    for a row of particles, about a spacing squared or more for a face."""
    if len(label) == 0:
        return np.zeros(0)
    count = np.bincount(label).astype(np.float64)
    mean = np.stack([np.bincount(label, face_points[:, i]) for i in range(3)], 1) / count[:, None]
    centred = face_points - mean[label]
    second = np.zeros((len(count), 3, 3))
    for i in range(3):
        for j in range(3):
            second[:, i, j] = np.bincount(label, centred[:, i] * centred[:, j]) / count
    spread = np.linalg.eigvalsh(second)[:, 1]
    return np.where(count >= 3, spread, 0.0)


def _refined(face_points: F64, direction: F64, spacing: float) -> F64:
    """The plane normal of `face_points` (PCA, refitted over the points near the first fit's
    outer layer) when they are planar and it agrees with the direction the votes found; else
    that direction."""
    normal = direction
    keep = np.ones(len(face_points), np.bool_)
    for _ in range(2):
        chosen = face_points[keep]
        centred = chosen - chosen.mean(axis=0)
        values, vectors = np.linalg.eigh(centred.T @ centred)
        candidate = vectors[:, 0] * np.sign(vectors[:, 0] @ direction)
        if not (
            values[0] < FLATNESS * max(values[1], 1e-30) and candidate @ direction > SAME_FACE_COS
        ):
            return normal
        normal = candidate
        height = face_points @ normal
        keep = height > height.max() - SKIN_SPACINGS * spacing - 0.1 * spacing
        if keep.sum() < 3:
            return normal
    return normal


def build_surfels(points: F64, radius: float) -> SolidSurfels:
    """Surfels and fill spheres for solid particles at `points` (world, float64) of radius r."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    if len(points) < 8:
        return _spheres_only(points, radius)
    tree = cKDTree(points)
    spacing = _spacing(tree, points)
    neighbours = _padded_neighbours(tree, points, NEIGHBOUR_SPACINGS * spacing)
    surface, votes = _surface_and_directions(points, *neighbours, spacing)
    surface_rows = np.flatnonzero(surface)
    directions = _dominant_directions(votes, MIN_FACE_VOTES)
    extremal = _extremal(points, surface_rows, neighbours, directions, spacing)
    parts = [
        _faces_along(points, surface_rows[extremal[:, k]], d, spacing)
        for k, d in enumerate(directions)
    ]
    particle = np.concatenate([p for p, _, _ in parts] + [np.zeros(0, np.int64)])
    normal = np.concatenate([n for _, n, _ in parts] + [np.zeros((0, 3))])
    offset = np.concatenate([o for _, _, o in parts] + [np.zeros(0)]) + radius
    direction = np.repeat(np.arange(len(parts)), [len(p) for p, _, _ in parts])
    order = np.argsort(particle, kind="stable")
    faces = _without_between(
        _Faces(particle[order], normal[order], offset[order], direction[order])
    )
    return _assemble(points, radius, spacing, surface_rows, faces)


def _without_between(faces: _Faces) -> _Faces:
    """Drop the face directions that are chamfers: where over a quarter of a direction's
    particles have it between two of their other faces (on the arc between their normals),
    the direction only rounds an edge those faces already make sharp."""
    counts = np.bincount(faces.particle) if len(faces.particle) else np.zeros(0, np.int64)
    between = np.zeros(len(faces.particle), np.bool_)
    starts = np.concatenate([[0], np.cumsum(counts)])
    for particle in np.flatnonzero(counts >= 3):
        rows = np.arange(starts[particle], starts[particle + 1])
        normals = faces.normal[rows]
        for k, n in enumerate(normals):
            others = np.delete(normals, k, axis=0)
            between[rows[k]] = any(
                _on_arc(n, others[a], others[b])
                for a in range(len(others))
                for b in range(a + 1, len(others))
            )
    total = np.bincount(faces.direction, minlength=1)
    flagged = np.bincount(faces.direction[between], minlength=len(total))
    chamfer = flagged > total / 4
    keep = ~chamfer[faces.direction]
    return _Faces(
        faces.particle[keep], faces.normal[keep], faces.offset[keep], faces.direction[keep]
    )


def _on_arc(n: F64, a: F64, b: F64) -> bool:
    """n lies on the shorter great-circle arc from a to b (within 5 degrees of it)."""
    axis = np.cross(a, b)
    length = float(np.linalg.norm(axis))
    if length < 1e-6:
        return False
    return bool(abs(n @ axis) / length < ARC_SIN and n @ a > a @ b and n @ b > a @ b)


def _assemble(
    points: F64, radius: float, spacing: float, surface_rows: npt.NDArray[np.int64], faces: _Faces
) -> SolidSurfels:
    """Discs from the faces (clipped by the particle's other faces), spheres under them."""
    count = len(faces.particle)
    # faces.particle is sorted (np.unique on keys led by the particle): group rows by particle.
    starts = np.searchsorted(faces.particle, faces.particle, side="left")
    clip_normals = np.zeros((count, MAX_CLIP_PLANES, 3))
    clip_offsets = np.ones((count, MAX_CLIP_PLANES))
    slot = np.zeros(count, np.int64)
    per_particle = np.bincount(faces.particle, minlength=len(points))[faces.particle]
    for shift in range(1, MAX_CLIP_PLANES + 1):
        other = starts + (np.arange(count) - starts + shift) % np.maximum(per_particle, 1)
        use = (per_particle > shift) & (slot < MAX_CLIP_PLANES)
        rows = np.flatnonzero(use)
        clip_normals[rows, slot[rows]] = faces.normal[other[rows]]
        clip_offsets[rows, slot[rows]] = faces.offset[other[rows]]
        slot[rows] += 1
    along = np.einsum("ni,ni->n", faces.normal, points[faces.particle])
    centers = points[faces.particle] + faces.normal * (faces.offset - along)[:, None]
    face_count = np.bincount(faces.particle, minlength=len(points))
    # Spheres where the discs may leave a hole: particles with no face, and those on more than
    # one (along edges); a face's inside is covered by its discs (0.9 s over a lattice's 0.71 s).
    cores = surface_rows[face_count[surface_rows] != 1]
    sphere_radii = np.where(face_count[cores] > 0, CORE_RADII * radius, radius)
    return SolidSurfels(
        centers,
        faces.normal,
        DISC_SPACINGS * spacing,
        clip_normals,
        clip_offsets,
        faces.particle,
        points[cores],
        sphere_radii,
        cores,
        spacing,
    )


def _spheres_only(points: F64, radius: float) -> SolidSurfels:
    n = len(points)
    return SolidSurfels(
        np.zeros((0, 3)),
        np.zeros((0, 3)),
        radius,
        np.zeros((0, MAX_CLIP_PLANES, 3)),
        np.ones((0, MAX_CLIP_PLANES)),
        np.zeros(0, np.int64),
        points.copy(),
        np.full(n, radius),
        np.arange(n, dtype=np.int64),
        2.0 * radius,
    )


def shape_key(points: F64, radius: float) -> str:
    """A digest of the solid's positions and radius: equal keys, equal surfels."""
    digest = hashlib.blake2b(
        np.ascontiguousarray(points, dtype=np.float64).tobytes(), digest_size=16
    )
    digest.update(np.float64(radius).tobytes())
    return digest.hexdigest()


class SolidSurfelCache:
    """The last shape's surfels, rebuilt only when the solid particles or the radius change;
    `builds` counts the reconstructions (a static solid: one per session)."""

    def __init__(self) -> None:
        self._key: str | None = None
        self._surfels: SolidSurfels | None = None
        self.builds = 0

    def get(self, points: F64, radius: float) -> SolidSurfels:
        key = shape_key(points, radius)
        if self._surfels is None or key != self._key:
            self._surfels = build_surfels(points, radius)
            self._key = key
            self.builds += 1
        return self._surfels
