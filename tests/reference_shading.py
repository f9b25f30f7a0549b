"""Numpy references for the shading tests, written from the formulas (thesis chapter 4 and
validation-data.md), independently of the GLSL: float64 BRDF terms, directional albedo by
deterministic quadrature, Hammersley estimators, brute-force environment integrals, and
normal/depth images of exact spheres for `SinglePasses.shade_normal_depth` (tests/single_passes.py).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from sphrender.server.bench.analytic import pixel_rays
from sphrender.server.engine.geometry.camera import Camera

F64 = npt.NDArray[np.float64]
MIN_ROUGHNESS = 0.045


def alpha_of(roughness: F64 | float) -> F64:
    r = np.clip(np.asarray(roughness, dtype=np.float64), MIN_ROUGHNESS, 1.0)
    result: F64 = r * r
    return result


def d_ggx(nh: F64, alpha: F64 | float) -> F64:
    a2 = np.asarray(alpha, dtype=np.float64) ** 2
    result: F64 = a2 / (np.pi * (nh * nh * (a2 - 1.0) + 1.0) ** 2)
    return result


def visibility(g_term: str, nl: F64, nv: F64, nh: F64, vh: F64, alpha: F64 | float) -> F64:
    """V = G / (4 nl nv) for 'smith_height_correlated', 'separable' (Smith G1 G1) or
    'cook_torrance'."""
    a2 = np.asarray(alpha, dtype=np.float64) ** 2
    if g_term == "smith_height_correlated":
        result: F64 = 0.5 / (
            nl * np.sqrt(nv * nv * (1 - a2) + a2) + nv * np.sqrt(nl * nl * (1 - a2) + a2)
        )
        return result
    if g_term == "separable":

        def g1(c: F64) -> F64:
            out: F64 = 2.0 * c / (c + np.sqrt(a2 + (1 - a2) * c * c))
            return out

        result = g1(nl) * g1(nv) / (4.0 * nl * nv)
        return result
    if g_term == "cook_torrance":
        g = np.minimum(1.0, np.minimum(2 * nh * nv / vh, 2 * nh * nl / vh))
        result = g / (4.0 * nl * nv)
        return result
    raise ValueError(g_term)


def schlick(f0: F64, cos: F64) -> F64:
    result: F64 = f0 + (1.0 - f0) * (1.0 - cos) ** 5
    return result


def ggx_half_vectors(s: F64, t: F64, alpha: F64 | float) -> F64:
    """Half vectors (tangent frame, z = n) for uniform (s, t): the inverse CDF of D (n.h)."""
    a2 = np.asarray(alpha, dtype=np.float64) ** 2
    s, t = np.broadcast_arrays(np.asarray(s, dtype=np.float64), np.asarray(t, dtype=np.float64))
    cos2 = (1.0 - s) / (1.0 + (a2 - 1.0) * s)
    sin = np.sqrt(np.maximum(1.0 - cos2, 0.0))
    phi = 2 * np.pi * t
    return np.stack([sin * np.cos(phi), sin * np.sin(phi), np.sqrt(cos2)], axis=-1)


def albedo_weights(g_term: str, nv: float, alpha: float, h: F64) -> tuple[F64, F64]:
    """Per half-vector sample h (..., 3) with v in the xz plane: (G_vis, Fc) such that the
    directional albedo for F0 is mean(G_vis ((1 - Fc) F0 + Fc)) under h ~ D (n.h)."""
    v = np.array([np.sqrt(max(1 - nv * nv, 0.0)), 0.0, nv])
    vh = h @ v
    light = 2 * vh[..., None] * h - v
    nl = light[..., 2]
    nh = h[..., 2]
    ok = (nl > 0) & (vh > 0)
    nl_s = np.where(ok, nl, 1.0)
    vh_s = np.where(ok, vh, 1.0)
    g_vis = np.where(
        ok,
        visibility(g_term, nl_s, np.full_like(nl_s, nv), nh, vh_s, alpha) * 4 * nl_s * vh_s / nh,
        0.0,
    )
    fc = (1.0 - np.clip(vh, 0, 1)) ** 5
    return g_vis, fc


def albedo_quadrature(g_term: str, nv: float, alpha: float, f0: float = 1.0, n: int = 768) -> float:
    """Directional albedo by Gauss-Legendre quadrature over (s, t) of the GGX sampling map
    (the integrand is smooth except along the horizon kink; n = 768 per axis puts the error
    well below 1e-4, checked against n = 1536 in the tests)."""
    x, w = np.polynomial.legendre.leggauss(n)
    s = 0.5 * (x + 1.0)
    ws = 0.5 * w
    t = s[:, None]
    h = ggx_half_vectors(s[None, :], t, alpha)
    g_vis, fc = albedo_weights(g_term, nv, alpha, h)
    weights = ws[:, None] * ws[None, :]
    return float(np.sum(weights * g_vis * ((1 - fc) * f0 + fc)))


def radical_inverse(i: npt.NDArray[np.int64]) -> F64:
    bits: npt.NDArray[np.integer] = i.astype(np.uint32)
    bits = ((bits << 16) | (bits >> 16)) & 0xFFFFFFFF
    bits = ((bits & 0x55555555) << 1) | ((bits & 0xAAAAAAAA) >> 1)
    bits = ((bits & 0x33333333) << 2) | ((bits & 0xCCCCCCCC) >> 2)
    bits = ((bits & 0x0F0F0F0F) << 4) | ((bits & 0xF0F0F0F0) >> 4)
    bits = ((bits & 0x00FF00FF) << 8) | ((bits & 0xFF00FF00) >> 8)
    result: F64 = bits.astype(np.float64) / 2.0**32
    return result


def hammersley(count: int) -> tuple[F64, F64]:
    i = np.arange(count)
    return (i + 0.5) / count, radical_inverse(i)


def albedo_hammersley(g_term: str, nv: float, alpha: float, count: int) -> tuple[float, float]:
    """(A, B) of the split-sum table as the shaders estimate them with `count` points."""
    s, t = hammersley(count)
    h = ggx_half_vectors(s, t, alpha)
    g_vis, fc = albedo_weights(g_term, nv, alpha, h)
    return float(np.mean((1 - fc) * g_vis)), float(np.mean(fc * g_vis))


def tangent_frame(n: F64) -> tuple[F64, F64]:
    """The shaders' orthonormal basis around n (Duff et al. 2017), so sample patterns match."""
    sign = np.where(n[..., 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n[..., 2])
    c = n[..., 0] * n[..., 1] * a
    t = np.stack([1 + sign * n[..., 0] ** 2 * a, sign * c, -sign * n[..., 0]], axis=-1)
    b = np.stack([c, sign + n[..., 1] ** 2 * a, -n[..., 1]], axis=-1)
    return t, b


def albedo_hammersley_at(g_term: str, n: F64, v: F64, alpha: float, count: int) -> F64:
    """The per-pixel sampled estimate of the albedo (F0 = 1) for normals n and view vectors v
    (..., 3): the same Hammersley points in the same tangent frames as the shade shader."""
    s, t = hammersley(count)
    h_t = ggx_half_vectors(s, t, alpha)  # (N, 3)
    tx, bx = tangent_frame(n)
    h = (
        tx[..., None, :] * h_t[:, 0, None]
        + bx[..., None, :] * h_t[:, 1, None]
        + n[..., None, :] * h_t[:, 2, None]
    )
    vh = np.einsum("...sk,...k->...s", h, v)
    light = 2 * vh[..., None] * h - v[..., None, :]
    nl = np.einsum("...sk,...k->...s", light, n)
    nh = h_t[:, 2]
    nv = np.maximum(np.einsum("...k,...k->...", n, v), 1e-4)[..., None]
    ok = (nl > 0) & (vh > 0)
    nl_s, vh_s = np.where(ok, nl, 1.0), np.where(ok, vh, 1.0)
    g_vis = ref_visibility_weight(g_term, nl_s, nv, nh, vh_s, alpha)
    result: F64 = np.where(ok, g_vis, 0.0).mean(axis=-1)
    return result


def ref_visibility_weight(g_term: str, nl: F64, nv: F64, nh: F64, vh: F64, alpha: float) -> F64:
    nv_b = np.broadcast_to(nv, nl.shape)
    result: F64 = visibility(g_term, nl, nv_b, np.broadcast_to(nh, nl.shape), vh, alpha) * (
        4 * nl * vh / nh
    )
    return result


def directions_with_nv(view_to_eye: F64, nv: F64, azimuth: F64) -> F64:
    """Unit normals n with n . v = nv for unit vectors v (..., 3), rotated by `azimuth` about v."""
    v = view_to_eye
    helper = np.where(np.abs(v[..., 1:2]) < 0.9, [0.0, 1.0, 0.0], [1.0, 0.0, 0.0])
    t = np.cross(helper, v)
    t /= np.linalg.norm(t, axis=-1, keepdims=True)
    b = np.cross(v, t)
    sin = np.sqrt(np.maximum(1 - nv**2, 0.0))
    n = nv[..., None] * v + sin[..., None] * (
        np.cos(azimuth)[..., None] * t + np.sin(azimuth)[..., None] * b
    )
    result: F64 = n / np.linalg.norm(n, axis=-1, keepdims=True)
    return result


def normal_depth_image(camera: Camera, normals: F64, depth: float = 2.0) -> npt.NDArray[np.float32]:
    """(H, W, 4) world normals + constant eye depth for `shade_normal_depth`."""
    image = np.zeros((camera.height, camera.width, 4), dtype=np.float32)
    image[..., :3] = normals
    image[..., 3] = depth
    return image


def view_vectors(camera: Camera) -> F64:
    """Unit vectors from each pixel's surface point towards the eye (= -ray direction)."""
    result: F64 = -pixel_rays(camera).directions
    return result


def sphere_normal_depth(
    camera: Camera, center: F64, radius: float
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.bool_]]:
    """Exact sphere: normals + eye depth image (0 off the sphere) and the hit mask."""
    rays = pixel_rays(camera)
    oc = center - rays.origin
    b = rays.directions @ oc
    perp = oc[None, None, :] - b[..., None] * rays.directions
    disc = radius**2 - np.einsum("ijk,ijk->ij", perp, perp)
    hit = (disc >= 0) & (b > 0)
    t = b - np.sqrt(np.maximum(disc, 0))
    point = rays.origin + rays.directions * t[..., None]
    normal = (point - center) / radius
    image = np.zeros((camera.height, camera.width, 4), dtype=np.float32)
    image[..., :3] = np.where(hit[..., None], normal, 0.0)
    image[..., 3] = np.where(hit, t * rays.view_z, 0.0)
    return image, hit
