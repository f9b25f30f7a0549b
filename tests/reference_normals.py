"""Float64 numpy reference of `shaders/normals/surface_normals.frag.glsl` (view-space normals,
rows bottom first as the GL image): the 1-pixel one-sided differences weighted by the other
side's squared depth step, and the wide central difference with its discontinuity test, blended
with them by the kink test's smooth weight."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]


def reference_normals(
    depth: F64,
    tan_half_fov: tuple[float, float],
    focal_px: float,
    radius: float,
    edge_jump: float,
    edge_jump_px: float,
    stencil_radii: float,
    stencil_max_px: int,
    kink: float,
    smooth: bool = True,
) -> F64:
    """View-space unit normals (H, W, 3) of the eye-depth image (0 = none, rows bottom first);
    `smooth`: quality.normal_rules "smooth" (else "hard")."""
    h, w = depth.shape

    def z_at(y: int, x: int) -> float:
        return float(depth[y, x]) if 0 <= y < h and 0 <= x < w else 0.0

    def position(y: int, x: int, z: float) -> F64:
        ndc = (np.array([x, y], float) + 0.5) / np.array([w, h], float) * 2.0 - 1.0
        return np.array([ndc[0] * tan_half_fov[0] * z, ndc[1] * tan_half_fov[1] * z, -z])

    out = np.zeros((h, w, 3))
    for y in range(h):
        for x in range(w):
            zc = z_at(y, x)
            if zc <= 0.0:
                continue
            p = position(y, x, zc)
            jump = max(edge_jump, edge_jump_px * zc / focal_px)
            s = 0
            if stencil_radii > 0.0:
                s = int(
                    np.clip(np.round(stencil_radii * radius * focal_px / zc), 1, stencil_max_px)
                )
            axes = []
            for dy, dx in ((0, 1), (1, 0)):
                axes.append(
                    _axis(z_at, position, y, x, dy, dx, zc, p, jump, s, kink, focal_px, smooth)
                )
            n = np.cross(axes[0], axes[1])
            length = np.linalg.norm(n)
            n = n / length if length > 0 else -p / np.linalg.norm(p)
            out[y, x] = -n if n @ p > 0 else n
    return out


def _axis(z_at, position, y, x, dy, dx, zc, p, jump, s, kink, focal_px, smooth):
    if s >= 1:
        same, prev_p, prev_m = True, zc, zc
        for k in range(1, s + 1):
            zp, zm = z_at(y + k * dy, x + k * dx), z_at(y - k * dy, x - k * dx)
            same = same and zp > 0 and zm > 0 and abs(zp - prev_p) <= jump
            same = same and abs(zm - prev_m) <= jump
            prev_p, prev_m = zp, zm
        d_plus, d_minus = prev_p - zc, zc - prev_m
        limit = kink * max(abs(d_plus), abs(d_minus), s * zc / focal_px)
        ratio = abs(d_plus - d_minus) / limit  # the kink test: 1 at its limit
        if not same:
            wide = 0.0
        elif smooth:
            wide = 1.0 - _smoothstep(ratio / 2.0)
        else:
            wide = 1.0 if ratio <= 1.0 else 0.0
        if wide > 0.0:
            a = position(y + s * dy, x + s * dx, prev_p)
            b = position(y - s * dy, x - s * dx, prev_m)
            one = _one_sided(z_at, position, y, x, dy, dx, zc, p, jump, smooth)
            return wide * (a - b) / (2.0 * s) + (1.0 - wide) * one
    return _one_sided(z_at, position, y, x, dy, dx, zc, p, jump, smooth)


def _smoothstep(t):
    t = min(max(t, 0.0), 1.0)
    return t * t * (3.0 - 2.0 * t)


def _one_sided(z_at, position, y, x, dy, dx, zc, p, jump, smooth):
    zp, zm = z_at(y + dy, x + dx), z_at(y - dy, x - dx)
    has_p = zp > 0 and abs(zp - zc) <= jump
    has_m = zm > 0 and abs(zm - zc) <= jump
    if has_p and has_m and smooth:
        plus, minus = position(y + dy, x + dx, zp) - p, p - position(y - dy, x - dx, zm)
        step_p, step_m = (zp - zc) ** 2, (zc - zm) ** 2
        total = step_p + step_m
        return (step_m * plus + step_p * minus) / total if total > 0 else plus
    if has_p and (not has_m or abs(zp - zc) <= abs(zc - zm)):
        return position(y + dy, x + dx, zp) - p
    if has_m:
        return p - position(y - dy, x - dx, zm)
    # no neighbour of this surface: toward the one nearer neighbour (an edge-on rim behind it)
    near_p, near_m = 0 < zp < zc, 0 < zm < zc
    if near_p and not near_m:
        return position(y + dy, x + dx, zp) - p
    if near_m and not near_p:
        return p - position(y - dy, x - dx, zm)
    return position(y + dy, x + dx, zc) - p
