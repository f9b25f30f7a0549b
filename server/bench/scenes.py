"""Reference scenes for the benchmark and the surfaces they should render as.

Every scene carries particles, a particle radius, a camera and a `Truth`: per pixel, whether the
intended surface is hit, its eye depth and its world normal. Analytic scenes compute the truth
by ray casting the surface the particles sample (a ball, a box for the slab and the sheet, the
spheres themselves for isolated droplets); the dam break's truth is a pysplashsurf reconstruction
(cubic spline, support 4 r, iso 0.6, fine cubes, smoothed mesh) rasterised with the same camera
(`mesh_reference.py`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from sphrender.server.bench.analytic import pixel_rays
from sphrender.server.content.lattice import jittered_lattice_ball, lattice_slab
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.scene import CameraConfig

F64 = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]

DAMBREAK_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data"


@dataclass(frozen=True)
class Truth:
    """Intended surface per pixel, rows top first: hit mask, eye depth (inf = none), unit world
    normals (0 = none). `sphere_center` is set for a single ball: its normal error is measured
    against the radial direction at the *rendered* point, as the engine's accuracy bound is."""

    hit: Mask
    depth: F64
    normals: F64
    sphere_center: F64 | None = None
    #: Distance (scene units) from the true hit point to the nearest edge of its face, for the
    #: faces / edge band split of a solid (polytope) scene; None elsewhere.
    edge_distance: F64 | None = None
    #: Pixels where the see-through IoU is measured (a root gap's window); None elsewhere.
    gap_window: Mask | None = None


@dataclass(frozen=True)
class BenchScene:
    name: str
    description: str
    positions: F64
    radius: float
    camera: dict[str, Any]  # a [camera] section
    truth: Callable[[Camera], Truth]  # computed on demand (per resolution)
    solid: bool | npt.NDArray[np.bool_] = False  # True: every particle solid; or per particle

    def solid_flags(self) -> npt.NDArray[np.bool_] | None:
        """The frame's ``solid`` array (None: all fluid)."""
        if isinstance(self.solid, np.ndarray):
            return self.solid
        return np.ones(len(self.positions), np.bool_) if self.solid else None

    def camera_config(self) -> CameraConfig:
        return CameraConfig(
            eye=tuple(self.camera["eye"]),
            target=tuple(self.camera["target"]),
            fov_y=float(self.camera.get("fov_y", 40.0)),
        )


def sphere_truth(camera: Camera, center: F64, radius: float) -> Truth:
    rays = pixel_rays(camera)
    oc = center - rays.origin
    b = rays.directions @ oc
    perp = oc[None, None, :] - b[..., None] * rays.directions
    disc = radius * radius - np.einsum("ijk,ijk->ij", perp, perp)
    hit = (disc >= 0.0) & (b > 0.0)
    t = np.where(hit, b - np.sqrt(np.maximum(disc, 0.0)), np.inf)
    point = rays.origin + rays.directions * np.where(hit, t, 0.0)[..., None]
    normals = np.where(hit[..., None], (point - center) / radius, 0.0)
    return Truth(hit, np.where(hit, t * rays.view_z, np.inf), normals, center)


def spheres_truth(camera: Camera, centers: F64, radius: float) -> Truth:
    """Union of equal spheres, nearest hit per pixel (each sphere only within its screen box)."""
    rays = pixel_rays(camera)
    h, w = camera.height, camera.width
    t_best = np.full((h, w), np.inf)
    normals = np.zeros((h, w, 3))
    view = camera.to_view(centers)
    scale = camera.pixels_per_unit_at_unit_depth
    for center, v in zip(centers, view, strict=True):
        z = -v[2]
        if z <= radius:
            continue
        cx = w / 2 + v[0] / z * scale
        cy = h / 2 - v[1] / z * scale
        reach = 2.0 * radius * scale / z + 2
        x0, x1 = max(int(cx - reach), 0), min(int(cx + reach) + 1, w)
        y0, y1 = max(int(cy - reach), 0), min(int(cy + reach) + 1, h)
        if x0 >= x1 or y0 >= y1:
            continue
        d = rays.directions[y0:y1, x0:x1]
        oc = center - rays.origin
        b = d @ oc
        perp = oc - b[..., None] * d
        disc = radius * radius - np.einsum("ijk,ijk->ij", perp, perp)
        t = np.where((disc >= 0) & (b > 0), b - np.sqrt(np.maximum(disc, 0.0)), np.inf)
        nearer = t < t_best[y0:y1, x0:x1]
        t_best[y0:y1, x0:x1] = np.where(nearer, t, t_best[y0:y1, x0:x1])
        point = rays.origin + d * np.where(np.isfinite(t), t, 0.0)[..., None]
        block = normals[y0:y1, x0:x1]
        block[nearer] = ((point - center) / radius)[nearer]
    hit = np.isfinite(t_best)
    return Truth(hit, np.where(hit, t_best * rays.view_z, np.inf), normals)


def box_truth(camera: Camera, lower: F64, upper: F64) -> Truth:
    """Ray / axis-aligned box (slab method); the normal is the axis of the entering face."""
    rays = pixel_rays(camera)
    d = rays.directions
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t0 = (lower - rays.origin) * inv
        t1 = (upper - rays.origin) * inv
    t_near_axes = np.minimum(t0, t1)
    t_far = np.min(np.maximum(t0, t1), axis=2)
    t_near = np.max(t_near_axes, axis=2)
    hit = (t_near <= t_far) & (t_near > 0)
    axis = np.argmax(t_near_axes, axis=2)
    normals = np.zeros(d.shape)
    sign = -np.sign(np.take_along_axis(d, axis[..., None], axis=2))[..., 0]
    np.put_along_axis(normals, axis[..., None], sign[..., None], axis=2)
    normals[~hit] = 0.0
    return Truth(hit, np.where(hit, t_near * rays.view_z, np.inf), normals)


def ball_scene(particles: int, radius: float = 0.01) -> BenchScene:
    """Jittered lattice ball with about `particles` particles (spacing 2 r, jitter 0.1 r)."""
    ball_radius = (particles * (2 * radius) ** 3 * 3 / (4 * np.pi)) ** (1 / 3)
    positions = jittered_lattice_ball(ball_radius, radius)
    surface = ball_radius + radius
    distance = 4.0 * surface  # the eye of bench_engine.py's ball, scaled to the ball
    eye = np.array([1.3, 1.0, 1.7]) / np.linalg.norm([1.3, 1.0, 1.7]) * distance
    return BenchScene(
        "ball",
        f"jittered-lattice ball, {len(positions)} particles",
        positions,
        radius,
        {"eye": eye.tolist(), "target": [0.0, 0.0, 0.0], "fov_y": 40.0},
        lambda camera: sphere_truth(camera, np.zeros(3), surface),
    )


def slab_scene(size: float, layers: int, name: str = "slab", radius: float = 0.01) -> BenchScene:
    """A lattice slab; the intended surface is its box (top particles' spheres reach y = r)."""
    positions = lattice_slab(size, size, layers, radius)
    lower = positions.min(axis=0) - radius
    upper = positions.max(axis=0) + radius
    what = "thin sheet (one layer)" if layers == 1 else f"slab ({layers} layers)"
    return BenchScene(
        name,
        f"{what}, {len(positions)} particles",
        positions,
        radius,
        {"eye": [0.35 * size, 0.7 * size, 1.1 * size], "target": [0.0, 0.0, 0.0], "fov_y": 40.0},
        lambda camera: box_truth(camera, lower, upper),
    )


def droplets_scene(count: int, radius: float = 0.01, seed: int = 3) -> BenchScene:
    """Isolated particles at least 6 r apart: each should render as its own sphere, which the
    smoothing must neither flatten nor erase."""
    rng = np.random.default_rng(seed)
    centers: list[F64] = []
    while len(centers) < count:
        candidate = rng.uniform(-0.25, 0.25, 3)
        if all(np.linalg.norm(candidate - c) >= 6 * radius for c in centers):
            centers.append(candidate)
    positions = np.array(centers)
    return BenchScene(
        "droplets",
        f"{count} isolated droplets (single particles)",
        positions,
        radius,
        {"eye": [0.45, 0.35, 0.6], "target": [0.0, 0.0, 0.0], "fov_y": 40.0},
        lambda camera: spheres_truth(camera, positions, radius),
    )


#: The data set's VTK frames (ParticleData_Fluid_<n>.vtk, n = 1, 3, ..., 15).
DAMBREAK_VTK = DAMBREAK_DIR / "dambreak-splishsplash" / "vtk"


def dambreak_frame() -> Path | None:
    path = DAMBREAK_VTK / "ParticleData_Fluid_5.vtk"
    return path if path.exists() else None


DAMBREAK_RADIUS = 0.015  # the data set's particleRadius (scene.json)


def dambreak_scene(
    path: Path, mesh_truth: Callable[[F64, float, Camera], Truth], radius: float
) -> BenchScene:
    from sphrender.core.readers import read_particles

    positions = read_particles(path).positions
    return BenchScene(
        "dambreak",
        f"dam break {path.name} (SPlisHSPlasH), {len(positions)} particles",
        positions,
        radius,
        {"eye": [0.5, 2.5, 4.0], "target": [-0.5, 0.4, 0.0], "fov_y": 40.0},
        lambda camera: mesh_truth(positions, radius, camera),
    )
