"""float64 numpy reference of the anisotropic GGX lobe (lighting/anisotropic_ggx.glsl), written
from the formulas (Heitz 2014): the brushed frame at a normal, D, Smith's Lambda with its
height-correlated and separable G2, the BRDF, and its directional albedo by quadrature over the
hemisphere of light directions (no importance sampling, so it shares nothing with the shader's
sampling). Vectors are in the local frame (t, b, n) = (x, y, z) unless they say otherwise.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import reference_shading as ref

F64 = npt.NDArray[np.float64]
MIN_ALPHA = 0.045**2
BRUSH_FADE_SIN2 = 0.01


def brushed_frame(n: F64, brush: F64, alpha: float, anisotropy: float) -> tuple[F64, F64, F64, F64]:
    """World t, b and alpha_t, alpha_b at unit normals n (..., 3) for a unit brush direction."""
    along = brush - n * np.einsum("...k,k->...", n, brush)[..., None]
    sin2 = np.einsum("...k,...k->...", along, along)
    t = along / np.sqrt(sin2)[..., None]
    b = np.cross(n, t)
    strength = anisotropy * np.clip(sin2 / BRUSH_FADE_SIN2, 0.0, 1.0)
    alpha_t = np.clip(alpha * (1 - strength), MIN_ALPHA, 1.0)
    alpha_b = np.clip(alpha * (1 + strength), MIN_ALPHA, 1.0)
    return t, b, alpha_t, alpha_b


def to_local(w: F64, t: F64, b: F64, n: F64) -> F64:
    return np.stack([np.einsum("...k,...k->...", w, axis) for axis in (t, b, n)], axis=-1)


def d_aniso(h: F64, alpha_t: F64 | float, alpha_b: F64 | float) -> F64:
    x, y, z = h[..., 0] / alpha_t, h[..., 1] / alpha_b, h[..., 2]
    s = x * x + y * y + z * z
    result: F64 = np.where(z > 0, 1.0 / (np.pi * alpha_t * alpha_b * s * s), 0.0)
    return result


def smith_lambda(w: F64, alpha_t: F64 | float, alpha_b: F64 | float) -> F64:
    tan2 = ((alpha_t * w[..., 0]) ** 2 + (alpha_b * w[..., 1]) ** 2) / w[..., 2] ** 2
    result: F64 = 0.5 * (np.sqrt(1.0 + tan2) - 1.0)
    return result


def brdf_specular(
    v: F64, light: F64, alpha_t: F64 | float, alpha_b: F64 | float, f0: F64, *, separable: bool
) -> F64:
    """D G F / (4 n.l n.v) per channel of f0 (..., 3); zero where n.l <= 0."""
    h = v + light
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    nl, nv = light[..., 2], v[..., 2]
    lv, ll = smith_lambda(v, alpha_t, alpha_b), smith_lambda(light, alpha_t, alpha_b)
    g = 1 / ((1 + lv) * (1 + ll)) if separable else 1 / (1 + lv + ll)
    vh = np.einsum("...k,...k->...", v, h)
    f = ref.schlick(f0, vh[..., None])
    scalar = np.where(
        nl > 0, d_aniso(h, alpha_t, alpha_b) * g / (4 * np.maximum(nl, 1e-30) * nv), 0
    )
    result: F64 = scalar[..., None] * f
    return result


def albedo(
    v: F64, alpha_t: float, alpha_b: float, f0: F64, *, separable: bool = False, n: int = 600
) -> F64:
    """Directional albedo  integral of f_r (n.l) over the hemisphere for one local view `v`: the
    midpoint rule on a (theta, phi) grid of n x 4n cells (the lobes checked are >= 0.1 rad wide,
    the cells 0.0026 rad, so the rule's error is far below the tests' 2 %)."""
    theta = (np.arange(n) + 0.5) * (0.5 * np.pi / n)
    phi = (np.arange(4 * n) + 0.5) * (2 * np.pi / (4 * n))
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    light = np.stack(
        np.broadcast_arrays(st * np.cos(phi), st * np.sin(phi), np.broadcast_to(ct, (n, 4 * n))),
        axis=-1,
    )
    f = brdf_specular(
        np.broadcast_to(v, light.shape), light, alpha_t, alpha_b, f0, separable=separable
    )
    weight = (ct * st)[..., None] * (0.5 * np.pi / n) * (2 * np.pi / (4 * n))
    result: F64 = (f * weight).sum(axis=(0, 1))
    return result
