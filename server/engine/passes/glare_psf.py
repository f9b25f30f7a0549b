"""The glare pass's point-spread function and the pyramid that approximates it (numpy, no GL).

The PSF is Spencer, Shirley, Zimmerman & Greenberg's 1995 photopic one (θ in degrees):
P(θ) = 0.384 f0 + 0.478 f1 + 0.138 f2 with f0 = 2.61e6 exp(-(θ/0.02)^2), f1 = 20.91/(θ+0.02)^3,
f2 = 72.37/(θ+0.02)^2, its halo truncated at `HALO_DEG` and normalised to 1 over the disc. It is
sampled on the pixel grid from the camera's degrees per pixel (`psf_kernel`).

The GL pass (glare.py) does not convolve with it directly (a 100-px-radius kernel is 40k taps a
pixel); it builds a pyramid of the excess light (2x2 means), blurs each level with one small
Gaussian (`BLUR_SIGMA` level pixels) and sums the levels, bilinearly upsampled, with weights:
out = c0 x + Σ w_l U_l(x). `fit_pyramid` finds c0 and w_l (non-negative, summing to 1) by least
squares against the sampled PSF, from each level's exact effective kernel (the same operations
simulated along one axis, averaged over the 2^l alignments). `PyramidFit.l1_bound` bounds the
pass's error against a true convolution with the PSF, as a fraction of the spread light.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

#: Angle at which the halo is cut (degrees); what lies beyond is not spread.
HALO_DEG = 8.0
#: Gaussian blur of each pyramid level, in that level's pixels, and its tap radius.
BLUR_SIGMA = 1.0
BLUR_RADIUS = 3
#: Most pyramid levels the pass builds (level 0 is the full image).
MAX_LEVELS = 10
#: Rows of the fit weighted by distance^this: 1 weighs each ring by its area, as an L1 error does.
_RING_POWER = 1.0


def spencer_photopic(theta_deg: FloatArray) -> FloatArray:
    """Spencer et al.'s photopic PSF at angles in degrees (per square degree, unnormalised)."""
    t = np.asarray(theta_deg, np.float64)
    f0 = 2.61e6 * np.exp(-((t / 0.02) ** 2))
    f1 = 20.91 / (t + 0.02) ** 3
    f2 = 72.37 / (t + 0.02) ** 2
    return 0.384 * f0 + 0.478 * f1 + 0.138 * f2


def blur_weights() -> FloatArray:
    """The normalised 1-D Gaussian taps of each level's blur, offsets -R..R."""
    x = np.arange(-BLUR_RADIUS, BLUR_RADIUS + 1, dtype=np.float64)
    w = np.exp(-0.5 * (x / BLUR_SIGMA) ** 2)
    return w / w.sum()


def kernel_radius_px(deg_per_px: float) -> int:
    return max(int(np.ceil(HALO_DEG / deg_per_px)), 1)


def psf_kernel(deg_per_px: float, radius: int | None = None) -> FloatArray:
    """The PSF integrated over each pixel of a (2R+1)^2 grid centred on the source, normalised
    over the halo's disc (zero outside it). The core (f0, 0.02 deg) and the centre pixel are
    integrated finely, pixels within 4 px by 8x8 samples, the others at their centre."""
    r = kernel_radius_px(deg_per_px) if radius is None else radius
    x = np.arange(-r, r + 1, dtype=np.float64)
    theta = np.hypot(x[None, :], x[:, None]) * deg_per_px
    kernel = np.where(theta <= HALO_DEG, spencer_photopic(theta), 0.0)
    near = min(r, 4)  # where the PSF bends within a pixel: 8x8 samples a pixel
    offsets = (np.arange(8) + 0.5) / 8 - 0.5
    sx = (np.arange(-near, near + 1)[:, None] + offsets[None, :]).ravel()
    fine = spencer_photopic(np.hypot(sx[None, :], sx[:, None]) * deg_per_px)
    m = 2 * near + 1
    kernel[r - near : r + near + 1, r - near : r + near + 1] = fine.reshape(m, 8, m, 8).mean(
        axis=(1, 3)
    )
    kernel[r, r] = _centre_pixel(deg_per_px)
    return kernel / kernel.sum()


def _centre_pixel(deg_per_px: float) -> float:
    """The PSF's mean over the centre pixel: f0 analytically (all of it lies inside), the rest
    on a 401^2 grid (spacing far below f1's 0.02 deg scale)."""
    s = (np.arange(401) + 0.5) / 401 - 0.5
    theta = np.hypot(s[None, :], s[:, None]) * deg_per_px
    rest = 0.478 * 20.91 / (theta + 0.02) ** 3 + 0.138 * 72.37 / (theta + 0.02) ** 2
    core = 0.384 * 2.61e6 * np.pi * 0.02**2 / deg_per_px**2
    return float(core + rest.mean())


def level_kernels_1d(level: int, half: int) -> FloatArray:
    """(2^level, 2 half + 1): the 1-D response of level `level` (downsample, blur, bilinear
    upsample, zero outside as in the shaders) to a unit impulse at each alignment, offsets
    -half..half around the impulse."""
    step = 2**level
    taps = blur_weights()
    out = np.zeros((step, 2 * half + 1))
    size = 2 * half + 4 * step + 2 * BLUR_RADIUS * step
    size += -size % step
    for phase in range(step):
        pos = (size // 2 // step) * step + phase
        signal = np.zeros(size)
        signal[pos] = 1.0
        coarse = signal.reshape(-1, step).mean(axis=1)  # 2x2 means, level by level = block mean
        blurred = np.convolve(coarse, taps, mode="same")
        p = np.arange(size, dtype=np.float64)
        u = (p + 0.5) / step - 0.5
        j = np.floor(u).astype(np.int64)
        f = u - j
        lo = np.where((j >= 0) & (j < blurred.size), blurred[np.clip(j, 0, blurred.size - 1)], 0)
        j1 = j + 1
        hi = np.where((j1 >= 0) & (j1 < blurred.size), blurred[np.clip(j1, 0, blurred.size - 1)], 0)
        response = (1 - f) * lo + f * hi
        out[phase] = response[pos - half : pos + half + 1]
    return out


@dataclass(frozen=True)
class PyramidFit:
    """The pyramid's weights: `centre` (c0, the light kept in its pixel) and `weights` (w_l per
    level); `l1_error` = ||model - PSF||_1 of the alignment-averaged model, `l1_spread` the
    worst alignment's extra (Σ w_l 2 max ||g_l(phase) - mean g_l||_1, g the 1-D kernels):
    their sum bounds the pass's L1 error against a convolution with `psf_kernel`, per unit of
    spread light."""

    centre: float
    weights: tuple[float, ...]
    l1_error: float
    l1_spread: float

    @property
    def l1_bound(self) -> float:
        return self.l1_error + self.l1_spread


def level_count(deg_per_px: float, width: int, height: int) -> int:
    """Levels until a level's blur spans half the halo or the level is under 2 px."""
    radius = kernel_radius_px(deg_per_px)
    levels = 1
    while levels < MAX_LEVELS:
        step = 2**levels
        if BLUR_SIGMA * step > radius / 2 or min(width, height) / step < 2:
            break
        levels += 1
    return levels


@lru_cache(maxsize=16)
def fit_pyramid(deg_per_px: float, levels: int) -> PyramidFit:
    """c0 and w_l minimising the squared difference to `psf_kernel` (weighted by ring area so
    the halo's far pixels count), with Σ = 1; cached per camera scale."""
    radius = max(kernel_radius_px(deg_per_px), 2 ** (levels - 1) * 4)
    target = psf_kernel(deg_per_px, radius)
    n = 2 * radius + 1
    columns = [np.zeros((n, n))]
    columns[0][radius, radius] = 1.0
    spreads = []
    for level in range(levels):
        per_phase = level_kernels_1d(level, radius)
        mean = per_phase.mean(axis=0)
        columns.append(np.outer(mean, mean))
        # ||k x k - m x m||_1 <= ||k - m||_1 (||k||_1 + ||m||_1) = 2 ||k - m||_1
        spreads.append(2.0 * float(np.abs(per_phase - mean).sum(axis=1).max()))
    # One quadrant, rows weighted by how many pixels they stand for and by distance^_RING_POWER.
    quadrant = (slice(radius, None), slice(radius, None))
    ys, xs = np.mgrid[0 : radius + 1, 0 : radius + 1]
    copies = np.where(xs > 0, 2.0, 1.0) * np.where(ys > 0, 2.0, 1.0)
    weight = (np.sqrt(copies) * np.maximum(np.hypot(xs, ys), 0.5) ** _RING_POWER).ravel()
    a = np.stack([c[quadrant].ravel() * weight for c in columns], axis=1)
    b = target[quadrant].ravel() * weight
    penalty = 10.0 * np.abs(b).max()
    a = np.vstack([a, np.full((1, a.shape[1]), penalty)])
    b = np.append(b, penalty)
    solution = _nonnegative_lstsq(a, b)
    solution = solution / solution.sum()
    model = sum(w * c for w, c in zip(solution, columns, strict=True))
    return PyramidFit(
        centre=float(solution[0]),
        weights=tuple(float(w) for w in solution[1:]),
        l1_error=float(np.abs(model - target).sum()),
        l1_spread=float(sum(w * s for w, s in zip(solution[1:], spreads, strict=True))),
    )


def _nonnegative_lstsq(a: FloatArray, b: FloatArray) -> FloatArray:
    """Least squares over non-negative x for a few columns: solve on the columns kept, drop
    those that come out negative, repeat (the bound is computed from whatever this returns)."""
    keep = np.ones(a.shape[1], bool)
    x = np.zeros(a.shape[1])
    while keep.any():
        x[:] = 0.0
        x[keep] = np.linalg.lstsq(a[:, keep], b, rcond=None)[0]
        if (x >= 0.0).all():
            break
        keep &= x > 0.0
    return np.maximum(x, 0.0)


def degrees_per_pixel(fov_y_deg: float, height: int) -> float:
    """The angle one pixel spans at the image centre (degrees)."""
    t = np.tan(np.radians(fov_y_deg) / 2)
    return float(np.degrees(2 * np.arctan(t / height)))
