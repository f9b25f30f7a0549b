"""The shadow reference scene: a jittered particle ball over a particle plate (content/lattice.py)
under one light, rendered with and without its shadows (tests/test_shadows.py,
benchmarks/bench_shadows.py). Truth in `shadow_truth.py`. The product never imports it.

A pixel counts as shadowed when its colour is under half that of the same render without
shadows (the scene has direct light only: no IBL, no emission).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from sphrender.core.frame import ParticleFrame
from sphrender.server.bench.analytic import reconstruct_world_positions
from sphrender.server.bench.shadow_truth import occluded, penumbra_edges, visible_fraction
from sphrender.server.content.lattice import jittered_lattice_ball, lattice_slab
from sphrender.server.engine.frame_output import RenderedFrame
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import Scene, scene_from_dict

F64 = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]
BALL_RADIUS = 0.5


@dataclass(frozen=True)
class BallOverPlate:
    """The scene's particles and image: ball of BALL_RADIUS at height `ball_y`, everything moved
    by `offset` on every axis."""

    radius: float = 0.05
    size: int = 160
    ball_y: float = 1.0
    offset: float = 0.0
    #: Turn the ball's lattice 37 degrees about (1, 2, 3): its columns then let no axis-aligned
    #: rays through (a lattice of touching spheres has straight holes along its axes).
    turned: bool = False

    def ball(self) -> F64:
        local = jittered_lattice_ball(BALL_RADIUS, self.radius, seed=3)
        if self.turned:
            local = local @ _rotation(np.array([1.0, 2.0, 3.0]), np.radians(37.0)).T
        return local + np.array([0.0, self.ball_y, 0.0]) + self.offset

    def positions(self) -> F64:
        plate = lattice_slab(3.2, 3.2, 2, self.radius, top_y=0.0) + self.offset
        return np.concatenate([self.ball(), plate])

    def scene(self, lights: list[dict[str, Any]]) -> Scene:
        eye = np.array((0.0, 4.0, 3.6)) + self.offset
        return scene_from_dict(
            {
                "image": {"width": self.size, "height": self.size},
                "camera": {"eye": list(eye), "target": [self.offset] * 3, "fov_y": 50.0},
                "particles": {"radius": self.radius},
                "shading": {"ibl_mode": "none"},
                "material": {"preset": "iron", "roughness": 0.6},
                "lights": lights,
            }
        )

    def camera(self) -> Camera:
        return Camera.from_config(self.scene([]).camera, self.size, self.size)


def _rotation(axis: F64, angle: float) -> F64:
    """Rodrigues: the rotation by `angle` about `axis`."""
    k = axis / np.linalg.norm(axis)
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    rotation: F64 = np.eye(3) + np.sin(angle) * cross + (1.0 - np.cos(angle)) * cross @ cross
    return rotation


@dataclass(frozen=True)
class ShadowRender:
    """Shadowed / unshadowed colour per pixel, the surface's world points and normals, the plate's
    interior pixels and the ball's particle centres."""

    ratio: F64
    world: F64
    normals: npt.NDArray[np.float32]
    plate: Mask
    ball: F64


def render_both(
    renderer: SurfaceRenderer, light: dict[str, Any], setup: BallOverPlate
) -> ShadowRender:
    positions = setup.positions()
    lit = _render(renderer, positions, setup.scene([dict(light, shadows=False)]))
    shadowed = _render(renderer, positions, setup.scene([dict(light, shadows=True)]))
    world = reconstruct_world_positions(lit, setup.camera())
    luminance = lit.rgba[..., :3].sum(axis=2).astype(np.float64)
    ratio = shadowed.rgba[..., :3].sum(axis=2) / np.maximum(luminance, 1e-30)
    plate = np.isfinite(world[..., 1]) & (world[..., 1] < setup.offset + 0.2)
    plate &= (lit.rgba[..., 3] >= 1.0) & (luminance > 0.0)
    assert lit.normals is not None
    return ShadowRender(ratio, world, lit.normals, plate, setup.ball())


def _render(renderer: SurfaceRenderer, positions: F64, scene: Scene) -> RenderedFrame:
    frame, _ = renderer.render(ParticleFrame(positions), scene, depth=True, normals=True)
    if not np.isfinite(frame.rgba).all():
        raise AssertionError("a pixel is NaN or infinite")
    return frame


def iou(a: Mask, b: Mask) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


def shadow_iou(result: ShadowRender, light: F64, radius: float) -> tuple[float, int]:
    """IoU of the plate's shadowed pixels against the truth for a point `light` (a point far
    along a directional light's reverse travel stands in for it), and the truth's count."""
    points = result.world[result.plate]
    lights = light if light.ndim == 1 else light[result.plate]
    truth = occluded(points, lights, result.ball, radius)
    return iou(result.ratio[result.plate] < 0.5, truth), int(truth.sum())


def penumbra_width(rho: F64, value: F64, least: int = 5) -> float:
    """Distance between the radii where the radial profile (median per 0.02 bin) crosses 0.1 and
    0.9, the profile made monotone by a running maximum from the centre outwards."""
    bins = np.arange(0.0, rho.max(), 0.02)
    index = np.digitize(rho, bins)
    centres, medians = [], []
    for k in range(1, len(bins)):
        chosen = value[index == k]
        if chosen.size >= least:
            centres.append(0.5 * (bins[k - 1] + bins[k]))
            medians.append(float(np.median(chosen)))
    profile = np.maximum.accumulate(np.clip(medians, 0.0, 1.0))
    x = np.asarray(centres)
    return float(np.interp(0.9, profile, x) - np.interp(0.1, profile, x))


@dataclass(frozen=True)
class Penumbra:
    analytic: float  # full width, similar triangles
    exact_10_90: float  # 10-90 % width of the quadrature profile
    rendered_10_90: float

    @property
    def rendered_full(self) -> float:
        """The rendered 10-90 % width scaled to a full width by the exact profile's shape."""
        return self.rendered_10_90 * self.analytic / self.exact_10_90

    @property
    def error(self) -> float:
        return self.rendered_full / self.analytic - 1.0


def penumbra(
    result: ShadowRender, light_y: float, light_radius: float, ball_y: float, radius: float
) -> Penumbra:
    """The penumbra of a sphere light straight above the ball: analytic full width, the exact
    profile's 10-90 % width (quadrature along one radius) and the rendered one."""
    points = result.world[result.plate]
    rho = np.hypot(points[:, 0], points[:, 2])
    plane = float(np.median(points[:, 1]))
    silhouette = float(np.max(np.hypot(result.ball[:, 0], result.ball[:, 2]))) + radius
    inner, outer = penumbra_edges(light_y, light_radius, ball_y, silhouette, plane)
    radii = np.linspace(0.0, outer * 1.3, 80)
    line = np.stack([radii, np.full_like(radii, plane), np.zeros_like(radii)], axis=1)
    centre = np.array([0.0, light_y, 0.0])
    exact = visible_fraction(line, centre, light_radius, result.ball, radius)
    return Penumbra(
        outer - inner,
        penumbra_width(radii, exact, least=1),
        penumbra_width(rho, result.ratio[result.plate]),
    )
