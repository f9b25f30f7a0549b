"""Solid workpieces with analytic truth: a plate, a single-V bevelled butt joint, and fluid
pressed against a wall.

The plate and the joint are jittered lattices (up to 0.1 r per axis) flagged solid; the
intended surface is the analytic solid grown by r, a union of convex polytopes (planes
n . x <= c). The truth carries each pixel's distance to the nearest edge of its face, so the
metrics split flat faces from the band within 3 r of an edge, and for the joint the window
where the root gap is seen through.

* plate: a lattice box (80 x 4 x 80 particles at the bench's r), yawed 30 degrees, seen
  obliquely; truth = the unjittered lattice box grown by r.
* bevel joint: two plates (8 layers) with 30-degree bevels (a 60-degree V), a root face of two
  layers and a root gap of 4 r between the true surfaces, seen from above along the joint. Each
  layer's row starts on the bevel plane (moved in by r), so the bevel is a plane of particles.
* wall: a fluid lattice block (30 x 12 x 30, not flagged) whose +x face is flush against a
  solid plate (4 x 24 x 50, flagged): the fluid's flat faces and edges beside a solid, as in a
  container; truth = the union of the two boxes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from sphrender.server.bench.analytic import pixel_rays
from sphrender.server.bench.scenes import BenchScene, Truth
from sphrender.server.engine.geometry.camera import Camera

F64 = npt.NDArray[np.float64]
JITTER = 0.1  # of r, per axis, uniform (as the ball's lattice)
EDGE_BAND_RADII = 3.0  # pixels whose true point lies within 3 r of an edge: the edge band


@dataclass(frozen=True)
class Polytope:
    """A convex solid: the points with normals @ x <= offsets (unit normals, outward)."""

    normals: F64  # (P, 3)
    offsets: F64  # (P,)


def polytope_truth(camera: Camera, solids: list[Polytope], window: Polytope | None) -> Truth:
    """Nearest hit of the union of convex `solids` per pixel: eye depth, normal, distance to the
    nearest edge of the face hit (in that face's plane); `window`: the see-through window."""
    rays = pixel_rays(camera)
    shape = rays.directions.shape[:2]
    best = np.full(shape, np.inf)
    normals = np.zeros((*shape, 3))
    edge = np.full(shape, np.inf)
    for solid in solids:
        t, face = _ray_polytope(rays.origin, rays.directions, solid)
        nearer = t < best
        best = np.where(nearer, t, best)
        normals[nearer] = solid.normals[face[nearer]]
        point = rays.origin + rays.directions * np.where(np.isfinite(t), t, 0.0)[..., None]
        edge = np.where(nearer, _edge_distance(point, face, solid), edge)
    hit = np.isfinite(best)
    gap_window = None
    if window is not None:
        t_window, _ = _ray_polytope(rays.origin, rays.directions, window)
        gap_window = np.isfinite(t_window)
    return Truth(
        hit,
        np.where(hit, best * rays.view_z, np.inf),
        normals,
        edge_distance=np.where(hit, edge, np.inf),
        gap_window=gap_window,
    )


def _ray_polytope(
    origin: F64, directions: F64, solid: Polytope
) -> tuple[F64, npt.NDArray[np.int64]]:
    """Entry distance along each ray (inf: a miss) and the index of the plane entered."""
    along = directions @ solid.normals.T  # (H, W, P)
    height = solid.offsets - solid.normals @ origin  # (P,) >= 0: the eye is inside that plane
    with np.errstate(divide="ignore", invalid="ignore"):
        t = height / along
    entering = along < 0
    t_enter = np.where(entering, t, -np.inf)
    t_exit = np.where(along > 0, t, np.inf)
    outside_parallel = (along == 0) & (height < 0)
    near = t_enter.max(axis=2)
    far = t_exit.min(axis=2)
    hit = (near <= far) & (near > 0) & ~outside_parallel.any(axis=2)
    return np.where(hit, near, np.inf), np.argmax(t_enter, axis=2)


def _edge_distance(point: F64, face: npt.NDArray[np.int64], solid: Polytope) -> F64:
    """In-plane distance from `point` on plane `face` to each other plane's line, the least."""
    own = solid.normals[face]  # (H, W, 3)
    cos = own @ solid.normals.T  # (H, W, P)
    sin = np.sqrt(np.clip(1.0 - cos * cos, 0.0, 1.0))
    room = solid.offsets - point @ solid.normals.T
    with np.errstate(divide="ignore", invalid="ignore"):
        distance = np.where(sin > 1e-6, room / sin, np.inf)
    return np.maximum(distance.min(axis=2), 0.0)


def _box(lower: F64, upper: F64, rotation: F64) -> Polytope:
    """An axis-aligned box turned by `rotation` (world = rotation @ local)."""
    axes = np.vstack([np.eye(3), -np.eye(3)])
    offsets = np.concatenate([upper, -lower])
    return Polytope(axes @ rotation.T, offsets)


def _yaw(degrees: float) -> F64:
    a = np.radians(degrees)
    return np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])


def _jitter(points: F64, radius: float, seed: int, jitter: float = JITTER) -> F64:
    rng = np.random.default_rng(seed)
    return points + rng.uniform(-jitter, jitter, points.shape) * radius


def plate_scene(
    radius: float = 0.01,
    counts: tuple[int, int, int] = (80, 4, 80),
    yaw_deg: float = 30.0,
    jitter: float = JITTER,
) -> BenchScene:
    """A jittered lattice plate (`jitter` r per axis; 0: a perfectly regular lattice), yawed
    and seen obliquely (see the module docstring)."""
    spacing = 2.0 * radius
    axes = [(np.arange(n) - (n - 1) / 2) * spacing for n in counts]
    lattice = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    rotation = _yaw(yaw_deg)
    positions = _jitter(lattice, radius, seed=5, jitter=jitter) @ rotation.T
    lower = lattice.min(axis=0) - radius
    upper = lattice.max(axis=0) + radius
    solid = _box(lower, upper, rotation)
    extent = float(np.max(upper - lower))
    eye = np.array([0.55, 0.62, 0.95]) * extent * 1.25
    return BenchScene(
        "plate",
        f"workpiece plate (jittered lattice {counts[0]}x{counts[1]}x{counts[2]}, yawed), "
        f"{len(positions)} particles",
        positions,
        radius,
        {"eye": eye.tolist(), "target": [0.0, -0.05 * extent, 0.0], "fov_y": 40.0},
        lambda camera: polytope_truth(camera, [solid], None),
        solid=True,
    )


@dataclass(frozen=True)
class JointShape:
    """A single-V butt joint in units of r: plate width, layers, length in particles."""

    width: int = 28  # particles across each plate (the jagged far sides out of view)
    layers: int = 8
    length: int = 60  # particles along the joint (z)
    root_layers: int = 2  # layers of the vertical root face
    gap_radii: float = 4.0  # root gap between the true surfaces
    bevel_deg: float = 30.0  # each bevel's angle from the vertical


def _joint_plate(shape: JointShape, radius: float, side: float) -> tuple[F64, Polytope]:
    """One plate's particles and true solid; `side` -1: the left plate (x < 0), +1: the right."""
    spacing = 2.0 * radius
    half_gap = shape.gap_radii * radius / 2
    bevel = np.radians(shape.bevel_deg)
    root_top = shape.root_layers * spacing
    thickness = shape.layers * spacing
    length = shape.length * spacing
    # The left plate's planes (outward normals); the right plate mirrors x.
    n_bevel = np.array([np.cos(bevel), np.sin(bevel), 0.0])
    c_bevel = -half_gap * np.cos(bevel) + root_top * np.sin(bevel)
    far = -half_gap - thickness * np.tan(bevel) - shape.width * spacing
    normals = np.array(
        [
            [1.0, 0.0, 0.0],  # root face
            n_bevel,
            [0.0, 1.0, 0.0],  # top
            [0.0, -1.0, 0.0],  # bottom
            [-1.0, 0.0, 0.0],  # far side
            [0.0, 0.0, 1.0],
            [0.0, 0.0, -1.0],
        ]
    )
    offsets = np.array([-half_gap, c_bevel, thickness, 0.0, -far, length / 2, length / 2])
    rows = []
    zs = (np.arange(shape.length) - (shape.length - 1) / 2) * spacing
    for layer in range(shape.layers):
        y = radius + layer * spacing
        x_bevel = (c_bevel - radius - y * np.sin(bevel)) / np.cos(bevel)
        x_start = min(-half_gap - radius, x_bevel)
        # Rows start on the bevel (or root face) plane: the far side is jagged, out of view.
        xs = x_start - np.arange(int((x_start - far - radius) / spacing) + 1) * spacing
        grid = np.stack(np.meshgrid(xs, [y], zs, indexing="ij"), axis=-1).reshape(-1, 3)
        rows.append(grid)
    points = np.concatenate(rows)
    if side > 0:
        points = points * np.array([-1.0, 1.0, 1.0])
        normals = normals * np.array([-1.0, 1.0, 1.0])
    return points, Polytope(normals, offsets)


def bevel_joint_scene(radius: float = 0.01, shape: JointShape | None = None) -> BenchScene:
    """Two bevelled plates with a root gap, seen from above along the joint."""
    shape = shape or JointShape()
    left, left_solid = _joint_plate(shape, radius, -1.0)
    right, right_solid = _joint_plate(shape, radius, 1.0)
    positions = _jitter(np.concatenate([left, right]), radius, seed=7)
    spacing = 2.0 * radius
    half_length = shape.length * spacing / 2
    thickness = shape.layers * spacing
    half_gap = shape.gap_radii * radius / 2
    window = Polytope(  # the gap between the root faces, through the plates' thickness
        np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float),
        np.array([half_gap * 3, half_gap * 3, thickness, 0.0, half_length, half_length]),
    )
    eye = [0.0, 3.2 * thickness + 0.35 * half_length, -1.55 * half_length]
    return BenchScene(
        "bevel_joint",
        f"single-V butt joint (two bevelled plates, root gap {shape.gap_radii:g} r), "
        f"{len(positions)} particles",
        positions,
        radius,
        {"eye": eye, "target": [0.0, 0.3 * thickness, 0.15 * half_length], "fov_y": 40.0},
        lambda camera: polytope_truth(camera, [left_solid, right_solid], window),
        solid=True,
    )


def _grid(counts: tuple[int, int, int], origin: F64, spacing: float) -> F64:
    axes = [origin[i] + np.arange(n) * spacing for i, n in enumerate(counts)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def wall_scene(radius: float = 0.01) -> BenchScene:
    """A jittered fluid lattice block flush against a solid wall plate (see the module
    docstring); only the wall's particles are flagged solid."""
    spacing, unturned = 2.0 * radius, np.eye(3)
    block_counts, wall_counts = (30, 12, 30), (4, 24, 50)
    block_origin = np.array([-0.6, -0.24, -0.3])
    block = _jitter(_grid(block_counts, block_origin, spacing), radius, seed=7)
    block_lower = block_origin - radius
    block_upper = block_lower + np.array(block_counts) * spacing
    wall_origin = np.array([block_upper[0] + radius, -0.24, -0.5])
    wall = _grid(wall_counts, wall_origin, spacing)
    wall_lower = wall_origin - radius
    wall_upper = wall_lower + np.array(wall_counts) * spacing
    solids = [_box(block_lower, block_upper, unturned), _box(wall_lower, wall_upper, unturned)]
    return BenchScene(
        "wall",
        f"fluid block against a solid wall, {len(block)} + {len(wall)} particles",
        np.vstack([block, wall]),
        radius,
        {"eye": [-1.0, 0.55, 0.75], "target": [-0.25, -0.05, 0.0], "fov_y": 40.0},
        lambda camera: polytope_truth(camera, solids, None),
        solid=np.concatenate([np.zeros(len(block), np.bool_), np.ones(len(wall), np.bool_)]),
    )
