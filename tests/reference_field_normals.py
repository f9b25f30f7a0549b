"""Float64 numpy reference of the field normals (shaders/field/field_normals.glsl) on an
eye-depth image (rows bottom first, as the GL image), view space, by brute force over every
particle (no grid, no tiles: the shader's grid finds exactly the centres within h, and its
tiles skip only pixels without a rim within reach)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]


MAX_REACH_PX = 5  # the shader's FIELD_MAX_REACH


RIM_FEATHER = 2.0  # the shader's FIELD_RIM_FEATHER


def _smoothstep(edge0: F64, edge1: F64, x: F64) -> F64:
    t = np.clip((x - edge0) / (edge1 - edge0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _shifted(image: F64, dy: int, dx: int) -> tuple[F64, npt.NDArray[np.bool_]]:
    """`image` at each pixel's neighbour (+dx, +dy), 0 off the image, and where it is inside."""
    h, w = image.shape
    shifted = np.zeros((h, w))
    inside = np.zeros((h, w), bool)
    ys = slice(max(dy, 0), h + min(dy, 0))
    xs = slice(max(dx, 0), w + min(dx, 0))
    yt = slice(max(-dy, 0), h + min(-dy, 0))
    xt = slice(max(-dx, 0), w + min(-dx, 0))
    shifted[yt, xt] = image[ys, xs]
    inside[yt, xt] = True
    return shifted, inside


def rim_weights(
    depth: F64,
    edge_jump: float,
    footprint_jump: F64,
    reach: npt.NDArray[np.int64],
    bulk: F64 | None = None,
) -> F64:
    """Per pixel the field's weight: the largest over the pixels q at d = |dx| + |dy| <= reach
    + 1 of strength(q) x (1 - (d - 1) / (reach + 1)), strength 1 without surface and, for a
    depth step beyond jump = max(edge_jump, d footprint_jump) (the pixel's own), smoothstep
    from 1 to RIM_FEATHER jumps; 0 on the pixel's own surface and off the image.
    `bulk`: the bulk's depth before the droplets drew over it (None: `depth` is the bulk's);
    at a pixel of the bulk (bulk == depth) a nearer q is measured at the bulk's depth there,
    at most the pixel's (a droplet in front of the bulk is no rim of it)."""
    h, w = depth.shape
    bulk = depth if bulk is None else bulk
    bulk_pixel = bulk == depth
    out = np.zeros((h, w))
    limit = MAX_REACH_PX + 1
    for dy in range(-limit, limit + 1):
        for dx in range(-limit, limit + 1):
            d = abs(dx) + abs(dy)
            if d == 0 or d > limit:
                continue
            shifted, inside = _shifted(depth, dy, dx)
            under, _ = _shifted(bulk, dy, dx)
            behind_droplet = bulk_pixel & (shifted > 0.0) & (shifted < depth) & (under > 0.0)
            z = np.where(behind_droplet, np.minimum(under, depth), shifted)
            jump = np.maximum(edge_jump, d * footprint_jump)
            step = _smoothstep(jump, RIM_FEATHER * jump, np.abs(z - depth))
            strength = np.where(inside, np.where(shifted <= 0.0, 1.0, step), 0.0)
            ring = np.where(d <= reach + 1, 1.0 - (d - 1) / (reach + 1), 0.0)
            out = np.maximum(out, strength * ring)
    return out


def field_gradient(points: F64, centres: F64, support: float) -> tuple[F64, F64]:
    """-grad phi at each point (unnormalised, the shader's constants) and the sum of the
    terms' magnitudes."""
    d = points[:, None, :] - centres[None, :, :]
    r = np.linalg.norm(d, axis=-1)
    q = r / support
    with np.errstate(divide="ignore", invalid="ignore"):
        dw_over_q = np.where(q <= 0.5, 6.0 * (3.0 * q - 2.0), -6.0 * (1.0 - q) ** 2 / q)
    dw_over_q = np.where(q < 1.0, dw_over_q, 0.0)
    terms = -dw_over_q[..., None] * d
    return terms.sum(axis=1), np.linalg.norm(terms, axis=-1).sum(axis=1)


def field_normals_reference(
    depth: F64,
    normals: F64,
    centres: F64,
    *,
    tan_half_fov: tuple[float, float],
    focal_px: float,
    particle_radius: float,
    support: float,
    reach_radii: float,
    edge_jump: float,
    edge_jump_px: float,
    bulk: F64 | None = None,
) -> tuple[F64, npt.NDArray[np.bool_]]:
    """View-space normals (H, W, 3) after the field blend of the depth normals `normals`, and
    which pixels the field changed (`bulk`: see `rim_weights`)."""
    h, w = depth.shape
    with np.errstate(divide="ignore"):
        radius_px = np.where(depth > 0.0, particle_radius * focal_px / depth, 0.0)
    # GLSL round() may go either way at .5; the scenes here keep away from it.
    reach = np.clip(np.floor(reach_radii * radius_px + 0.5), 1, MAX_REACH_PX).astype(np.int64)
    weight = rim_weights(depth, edge_jump, edge_jump_px * depth / focal_px, reach, bulk)
    rim = (depth > 0.0) & (weight > 0.0)
    ys, xs = np.nonzero(rim)
    ndc_x = (xs + 0.5) / w * 2.0 - 1.0
    ndc_y = (ys + 0.5) / h * 2.0 - 1.0
    z = depth[ys, xs]
    x = np.stack([ndc_x * tan_half_fov[0] * z, ndc_y * tan_half_fov[1] * z, -z], axis=-1)
    g, scale = field_gradient(x, centres, support)
    out = normals.copy()
    changed = np.zeros((h, w), bool)
    for k in range(len(ys)):
        length = np.linalg.norm(g[k])
        if not (length > 1e-4 * scale[k]) or not length > 0.0:
            continue
        n_field = g[k] / length
        ray = x[k] / np.linalg.norm(x[k])
        away = float(n_field @ ray)
        if away > 0.0:  # facing away: mirrored at the plane perpendicular to the ray
            n_field = n_field - 2.0 * away * ray
            n_field /= np.linalg.norm(n_field)
        t = weight[ys[k], xs[k]]
        n = normals[ys[k], xs[k]]
        blended = (1.0 - t) * n + t * n_field
        if np.linalg.norm(blended) > 1e-3:
            out[ys[k], xs[k]] = blended / np.linalg.norm(blended)
            changed[ys[k], xs[k]] = True
    return out, changed
