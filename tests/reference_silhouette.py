"""Numpy reference of the silhouette pass (shaders/silhouette/silhouette_normals.frag.glsl),
written from the rule in the shader's header, in float64, without its tile test (which only
skips pixels whose window is all covered, where the rule changes nothing)."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from scipy.special import erfinv

F64 = npt.NDArray[np.float64]
MAX_SIGMA_PX = 3.0
TILT = 0.8


def silhouette_reference(
    normal_depth: npt.NDArray[np.floating],
    *,
    tan_half_fov: tuple[float, float],
    view_to_world: F64,
    focal_px: float,
    particle_radius: float,
    rim_radii: float,
    edge_jump: float,
) -> F64:
    """`normal_depth` (H, W, 4): world normal, eye depth (0 = none), rows bottom first as GL
    stores them (x = column, y = row); returns the same layout."""
    nd = np.asarray(normal_depth, np.float64)
    height, width = nd.shape[:2]
    out = nd.copy()
    depth = nd[..., 3]
    world_to_view = view_to_world.T
    for y in range(height):
        for x in range(width):
            zc = depth[y, x]
            if zc <= 0.0:
                continue
            r_px = particle_radius * focal_px / zc
            sigma = min(0.5 * rim_radii * r_px, MAX_SIGMA_PX)
            reach = 2.5 * sigma
            k_max = math.floor(reach)
            if k_max < 1:
                continue
            limit = zc + edge_jump
            stride = 2 if sigma >= 2.0 else 1
            half = k_max // stride
            weight_sum = covered = 0.0
            moment = np.zeros(2)
            for j in range(-half, half + 1):
                for i in range(-half, half + 1):
                    ox, oy = i * stride, j * stride
                    if ox * ox + oy * oy > reach * reach:
                        continue
                    qx, qy = x + ox, y + oy
                    if not (0 <= qx < width and 0 <= qy < height):
                        continue
                    w = math.exp(-(ox * ox) / (2 * sigma**2)) * math.exp(
                        -(oy * oy) / (2 * sigma**2)
                    )
                    weight_sum += w
                    z = depth[qy, qx]
                    if 0.0 < z <= limit:
                        covered += w
                        moment += w * np.array([ox, oy], float)
            share = covered / weight_sum
            moment /= weight_sum
            if share > 0.999 or np.linalg.norm(moment) < 1e-3:
                continue
            outward = -moment / np.linalg.norm(moment)
            c_share = min(max(share, 1e-4), 1.0 - 1e-4)
            inside = sigma * math.sqrt(2.0) * float(erfinv(2.0 * c_share - 1.0))
            u = inside / sigma
            edge_moment = sigma * math.exp(-0.5 * u * u) / math.sqrt(2.0 * math.pi)
            edge_like = min(max(np.linalg.norm(moment) / edge_moment, 0.0), 1.0)
            t = min(max(1.0 - inside / (2.0 * sigma), 0.0), 1.0) * edge_like
            if t <= 0.0:
                continue
            ndc = (np.array([x, y], float) + 0.5) / np.array([width, height]) * 2.0 - 1.0
            ray = np.array([ndc[0] * tan_half_fov[0], ndc[1] * tan_half_fov[1], -1.0])
            ray /= np.linalg.norm(ray)
            n = world_to_view @ nd[y, x, :3]
            o = np.array([outward[0], outward[1], 0.0])
            o -= o.dot(ray) * ray
            o /= np.linalg.norm(o)
            c = min(max(n.dot(-ray), 0.0), 1.0)
            c = min(c, math.sqrt(1.0 - TILT * TILT * t * t))
            turned = math.sqrt(max(1.0 - c * c, 0.0)) * o - c * ray
            blended = n + (turned - n) * t
            blended /= np.linalg.norm(blended)
            world = view_to_world @ blended
            out[y, x, :3] = world / np.linalg.norm(world)
    return out
