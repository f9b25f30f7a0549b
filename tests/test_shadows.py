"""Shadows and sphere lights against ray-traced truth (real EGL): a jittered particle ball over
a particle plate (server/content/lattice.py), lit by point, sphere and directional lights.

Truth (tests/shadow_reference.py): each plate pixel's world point (from the Z AOV) is in shadow
when the segment to the light meets a ball particle's sphere; a sphere light's visible fraction is
a 256-point quadrature over its disc. A pixel counts as shadowed in the render when its colour is
under half the colour of the same render without shadows (the scenes have direct light only).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from sphrender.core.errors import InputError
from sphrender.core.frame import ParticleFrame
from sphrender.server.bench.analytic import reconstruct_world_positions
from sphrender.server.content.lattice import jittered_lattice_ball, lattice_slab
from sphrender.server.engine.frame_output import RenderedFrame
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import Scene, scene_from_dict
from sphrender.server.scene.layering import merge_scene_dicts
from tests.shadow_reference import occluded, penumbra_edges, visible_fraction

R = 0.05  # particle radius
SIZE = 160
BALL_RADIUS = 0.5


def _particles(
    ball_y: float, offset: float = 0.0
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    ball = jittered_lattice_ball(BALL_RADIUS, R, center=(0.0, ball_y, 0.0), seed=3)
    plate = lattice_slab(3.2, 3.2, 2, R, top_y=0.0)
    return ball + offset, np.concatenate([ball, plate]) + offset


def _scene(lights: list[dict[str, Any]], offset: float = 0.0, **camera: Any) -> Scene:
    eye = np.array(camera.pop("eye", (0.0, 4.0, 3.6))) + offset
    return scene_from_dict(
        {
            "image": {"width": SIZE, "height": SIZE},
            "camera": {"eye": list(eye), "target": [offset] * 3, "fov_y": 50.0, **camera},
            "particles": {"radius": R},
            "shading": {"ibl_mode": "none"},
            "material": {"preset": "iron", "roughness": 0.6},
            "lights": lights,
        }
    )


def _render(
    renderer: SurfaceRenderer, positions: npt.NDArray[np.float64], scene: Scene
) -> RenderedFrame:
    frame, stats = renderer.render(ParticleFrame(positions), scene, depth=True, normals=True)
    assert np.isfinite(frame.rgba).all()
    return frame


def _shadow_setup(
    renderer: SurfaceRenderer, light: dict[str, Any], ball_y: float = 1.0, offset: float = 0.0
):
    """(ratio shadowed / unshadowed, world points, normals, mask of interior plate pixels)."""
    ball, positions = _particles(ball_y, offset)
    lit = _render(renderer, positions, _scene([dict(light, shadows=False)], offset))
    shadowed = _render(renderer, positions, _scene([dict(light, shadows=True)], offset))
    camera = Camera.from_config(_scene([], offset).camera, SIZE, SIZE)
    world = reconstruct_world_positions(lit, camera)
    luminance_lit = lit.rgba[..., :3].sum(axis=2)
    ratio = shadowed.rgba[..., :3].sum(axis=2) / np.maximum(luminance_lit, 1e-30)
    plate = np.isfinite(world[..., 1]) & (world[..., 1] < offset + 0.2) & (lit.rgba[..., 3] >= 1.0)
    plate &= luminance_lit > 0.0
    return ratio, world, lit.normals, plate, ball


def _iou(a: npt.NDArray[np.bool_], b: npt.NDArray[np.bool_]) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


POINT = {"type": "point", "position": [-0.5, 3.0, -0.7], "intensity": 8.0}


def test_point_light_shadow_matches_ray_traced_truth(renderer: SurfaceRenderer) -> None:
    ratio, world, _, plate, ball = _shadow_setup(renderer, POINT)
    truth = occluded(world[plate], np.array(POINT["position"]), ball, R)
    ours = ratio[plate] < 0.5
    iou = _iou(ours, truth)
    print(f"point light: IoU {iou:.4f} over {truth.sum()} shadowed of {plate.sum()} plate pixels")
    assert truth.sum() > 500
    assert iou >= 0.95
