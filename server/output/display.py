"""The display transform: scene-linear RGBA -> display-referred sRGB code values.

Shared by every display-referred encoding (PNG, JPEG, raw ``rgba8``): RGB x 2**exposure, a tone
mapper (`TONE_MAPPERS`), the exact sRGB OETF, then quantisation ``floor(v * maxcode + 0.5)``.
Alpha is straight coverage, only clamped.

`display_codes` is the one entry point the encoders use. For 8 bits it replaces the OETF's
``power`` and the quantisation with a table (`_Oetf8`): the float32 bit pattern of the display-
linear value indexes the code of its bucket, and one comparison with the next code's threshold
corrects the buckets a threshold falls inside. The thresholds are found by bisection on the
float32 reference path itself (``_quantise(srgb_oetf(v), 8)``), so the table reproduces it bit
for bit (tests/test_encodings.py checks every threshold's neighbourhood and random values).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal, TypeAlias

import numpy as np
import numpy.typing as npt

from sphrender.server.engine.frame_output import RenderedFrame

__all__ = [
    "OETF8_THRESHOLDS",
    "TONE_MAPPERS",
    "display_codes",
    "engine_codes",
    "srgb_oetf",
    "tone_map_aces",
    "tone_map_clamp",
    "tone_map_for_display",
]

Float32Array: TypeAlias = npt.NDArray[np.float32]


ToneMapper: TypeAlias = Callable[[Float32Array], Float32Array]


def tone_map_clamp(rgb: Float32Array) -> Float32Array:
    """The simplest tone mapper: hard clip exposed linear RGB to [0, 1] (NaN propagates)."""
    return np.clip(rgb, 0.0, 1.0).astype(np.float32, copy=False)


#: Stephen Hill's fit of the ACES reference rendering transform + sRGB output transform
#: (as in MJP's BakingLab): linear sRGB -> (RRT_SAT · sRGB->AP1) -> rational curve ->
#: (ODT_SAT · AP1->sRGB). The matrices apply ACES's saturation tweak; the curve has a toe and
#: a long shoulder, so very bright values (molten metal at 1e3-1e4 x the walls) roll off to white
#: instead of clipping per channel with hue shifts.
ACES_INPUT = np.array(
    [[0.59719, 0.35458, 0.04823], [0.07600, 0.90834, 0.01566], [0.02840, 0.13383, 0.83777]],
    dtype=np.float32,
)
ACES_OUTPUT = np.array(
    [[1.60475, -0.53108, -0.07367], [-0.10208, 1.10813, -0.00605], [-0.00327, -0.07276, 1.07602]],
    dtype=np.float32,
)


def _apply_3x3(x: Float32Array, matrix: Float32Array) -> Float32Array:
    """`x @ matrix.T` over the last axis, written out per channel: for (N, 3) float32 inputs
    numpy's matmul takes a slow generic path (17 ms for 150k pixels vs ~1 ms here)."""
    out = np.empty(x.shape, dtype=np.float32)
    r, g, b = x[..., 0], x[..., 1], x[..., 2]
    for row in range(3):
        m0, m1, m2 = (np.float32(v) for v in matrix[row])
        out[..., row] = r * m0 + g * m1 + b * m2
    return out


def tone_map_aces(rgb: Float32Array) -> Float32Array:
    """Filmic ACES fit (Hill): 0.18 -> 0.106 display-linear (sRGB 0.36), 1 -> 0.62, white is
    approached asymptotically (0.97 at 10); negative input is treated as 0."""
    x = np.maximum(np.asarray(rgb, dtype=np.float32), 0.0)
    with np.errstate(over="ignore", invalid="ignore"):
        v = _apply_3x3(x, ACES_INPUT)
        # Rational fit of RRT + ODT; for huge v both polynomials are ~v^2, the ratio ~1.0165,
        # so divide by v^2 first where v is large to stay finite.
        big = v > 1e6
        safe = np.where(big, 1.0, v)
        a = safe * (safe + 0.0245786) - 0.000090537
        b = safe * (0.983729 * safe + 0.4329510) + 0.238081
        curve = np.where(big, 1.0 / 0.983729, a / b)
        out = _apply_3x3(curve.astype(np.float32, copy=False), ACES_OUTPUT)
    return np.clip(out, 0.0, 1.0).astype(np.float32, copy=False)


#: Tone mappers by name: exposed scene-linear RGB -> display-linear RGB in [0, 1].
TONE_MAPPERS: dict[str, ToneMapper] = {"clamp": tone_map_clamp, "aces": tone_map_aces}


def srgb_oetf(linear: Float32Array) -> Float32Array:
    """Exact sRGB OETF on [0, 1]: 12.92·L if L ≤ 0.0031308, else 1.055·L^(1/2.4) − 0.055."""
    lin = np.asarray(linear, dtype=np.float32)
    high = np.float32(1.055) * np.power(np.maximum(lin, np.float32(0.0031308)), np.float32(1 / 2.4))
    return np.where(lin <= 0.0031308, np.float32(12.92) * lin, high - np.float32(0.055)).astype(
        np.float32, copy=False
    )


def _sanitize_unit(mapped: Float32Array, source: Float32Array) -> Float32Array:
    """Clip to [0, 1]; where the *source* was NaN → 0, +inf → 1, −inf → 0 (whatever the mapper)."""
    out = np.clip(np.nan_to_num(mapped, nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0)
    if not np.isfinite(source).all():  # the usual frame is finite: skip three full masks
        out[np.isnan(source)] = 0.0
        out[np.isposinf(source)] = 1.0
        out[np.isneginf(source)] = 0.0
    return out.astype(np.float32, copy=False)


def tone_map_for_display(
    rgba: Float32Array, exposure: float = 0.0, tone_mapper: str = "clamp"
) -> Float32Array:
    """Scene-linear straight RGBA → display-referred sRGB-encoded RGBA in [0, 1], float32.

    RGB × 2**exposure, then ``TONE_MAPPERS[tone_mapper]``, then the sRGB OETF. Input NaN maps to
    0 and +inf to 1 (per channel), so no non-finite value ever reaches the output. Alpha is only
    clamped to [0, 1] (same NaN/inf rule).
    """
    if not np.isfinite(exposure):
        raise ValueError(f"exposure must be finite, got {exposure!r}")
    try:
        mapper = TONE_MAPPERS[tone_mapper]
    except KeyError:
        raise ValueError(
            f"unknown tone mapper {tone_mapper!r}, known: {sorted(TONE_MAPPERS)}"
        ) from None
    rgba = np.asarray(rgba, dtype=np.float32)
    if rgba.ndim != 3 or rgba.shape[-1] != 4:
        raise ValueError(f"rgba must have shape (H, W, 4), got {rgba.shape}")
    flat = np.ascontiguousarray(rgba).reshape(-1, 4)
    live = _live_pixels(flat)
    if live is None:
        return _tone_map_pixels(rgba, exposure, mapper)
    out = np.empty(flat.shape, dtype=np.float32)
    out[:, :3] = _tone_map_pixels(np.zeros((1, 1, 4), np.float32), exposure, mapper)[0, 0, :3]
    if live.size:
        sub = np.take(flat, live, axis=0)[None]
        out[live, :3] = _tone_map_pixels(sub, exposure, mapper)[0, :, :3]
    out[:, 3] = _display_alpha(flat[:, 3])
    return out.reshape(rgba.shape)


def _live_pixels(flat: Float32Array) -> npt.NDArray[np.intp] | None:
    """Indices of the (N, 4) pixels whose RGB is not exactly +0, or None when that is most of
    them. The display transform is per pixel and a render is mostly background with RGB exactly
    0, so only these need mapping; the rest get the mapped value of one zero pixel (the same
    function, so the output is identical). At 1280x720 this saved ~50-80 ms per PNG on a CPU."""
    bits = flat.view(np.uint32)  # any set bit: nonzero, -0.0 or NaN (all mapped as they are)
    live = np.flatnonzero((bits[:, 0] | bits[:, 1] | bits[:, 2]) != 0)
    return live if live.size < flat.shape[0] // 2 else None


def _display_alpha(alpha: Float32Array) -> Float32Array:
    """Alpha clamped to [0, 1], NaN -> 0, +inf -> 1 (as `tone_map_for_display` documents)."""
    return _sanitize_unit(np.clip(alpha, 0.0, 1.0), alpha)


def _tone_map_pixels(rgba: Float32Array, exposure: float, mapper: ToneMapper) -> Float32Array:
    """`tone_map_for_display` on every pixel of an (H, W, 4) array."""
    rgb = rgba[..., :3]
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        scale = np.float32(np.exp2(np.float64(exposure)))  # inf/0 for absurd exposures, no raise
        exposed = rgb * scale
        display_linear = _sanitize_unit(mapper(exposed), rgb)
    out = np.empty(rgba.shape, dtype=np.float32)
    out[..., :3] = srgb_oetf(display_linear)
    out[..., 3] = _display_alpha(rgba[..., 3])
    return out


def _quantise(display: Float32Array, bits: Literal[8, 16]) -> npt.NDArray[np.uint8 | np.uint16]:
    """[0, 1] floats → integer code values, rounding half up (floor(v·max + 0.5))."""
    max_code = (1 << bits) - 1
    dtype = np.uint8 if bits == 8 else np.uint16
    codes = np.floor(display * np.float32(max_code) + np.float32(0.5))
    return np.clip(codes, 0, max_code).astype(dtype)


def display_codes(
    rgba: Float32Array, bits: Literal[8, 16], exposure: float, tone_mapper: str
) -> npt.NDArray[np.uint8 | np.uint16]:
    """Code values per pixel, (H, W, 4): `_quantise(tone_map_for_display(...))`, computed only
    for the pixels with RGB (see `_live_pixels`); the rest get the code of one zero pixel.
    8 bits go through the OETF table (identical codes, several times faster)."""
    rgba = np.asarray(rgba, dtype=np.float32)
    if rgba.ndim != 3 or rgba.shape[-1] != 4:
        raise ValueError(f"rgba must have shape (H, W, 4), got {rgba.shape}")
    flat = np.ascontiguousarray(rgba).reshape(-1, 4)
    dtype = np.uint8 if bits == 8 else np.uint16
    codes = np.empty(flat.shape, dtype=dtype)
    live = _live_pixels(flat)
    zero = np.zeros((1, 4), np.float32)
    codes[:, :3] = _rgb_codes(zero, bits, exposure, tone_mapper)[0]
    if live is None:
        codes[:, :3] = _rgb_codes(flat, bits, exposure, tone_mapper)
    elif live.size:
        codes[live, :3] = _rgb_codes(np.take(flat, live, axis=0), bits, exposure, tone_mapper)
    codes[:, 3] = _alpha_codes(flat[:, 3], bits)
    return codes.reshape(rgba.shape)


def _rgb_codes(
    pixels: Float32Array, bits: Literal[8, 16], exposure: float, tone_mapper: str
) -> npt.NDArray[np.uint8 | np.uint16]:
    """(N, 4) scene-linear pixels -> (N, 3) RGB codes."""
    if bits == 16:
        return _quantise(tone_map_for_display(pixels[None], exposure, tone_mapper), 16)[0, :, :3]
    if not np.isfinite(exposure):
        raise ValueError(f"exposure must be finite, got {exposure}")
    mapper = TONE_MAPPERS[tone_mapper]
    rgb = pixels[:, :3]
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        scale = np.float32(np.exp2(np.float64(exposure)))
        display_linear = _sanitize_unit(mapper(rgb * scale), rgb)
    return _OETF8.codes(display_linear)


def _alpha_codes(alpha: Float32Array, bits: Literal[8, 16]) -> npt.NDArray[np.uint8 | np.uint16]:
    """`_quantise(_display_alpha(alpha), bits)`; finite alpha skips the NaN/inf masks (the
    same float32 operations, truncation = floor for the non-negative values)."""
    if not np.isfinite(alpha).all():
        return _quantise(_display_alpha(alpha), bits)
    max_code = np.float32((1 << bits) - 1)
    scaled = np.clip(alpha, np.float32(0.0), np.float32(1.0)) * max_code + np.float32(0.5)
    return scaled.astype(np.uint8 if bits == 8 else np.uint16)


class _Oetf8:
    """8-bit sRGB codes of display-linear [0, 1] float32 values by table (module docstring)."""

    SHIFT = 15  # buckets of 2**15 float32 patterns: 8 mantissa bits, 1/256 relative width
    ONE = int(np.float32(1.0).view(np.uint32))

    def __init__(self) -> None:
        def reference(pattern: npt.NDArray[np.uint32]) -> npt.NDArray[np.int64]:
            values = pattern.astype(np.uint32).view(np.float32)
            return _quantise(srgb_oetf(values), 8).astype(np.int64)

        wanted = np.arange(1, 256, dtype=np.int64)  # threshold k-1: first pattern with code >= k
        lo = np.zeros(255, np.int64)
        hi = np.full(255, self.ONE, np.int64)
        while np.any(lo < hi):
            mid = (lo + hi) // 2
            reached = reference(mid.astype(np.uint32)) >= wanted
            hi = np.where(reached, mid, hi)
            lo = np.where(reached, lo, mid + 1)
        buckets = lo >> self.SHIFT
        if np.any(np.diff(buckets) == 0):  # two thresholds in one bucket: one step is not enough
            raise AssertionError("sRGB table buckets too wide")
        starts = np.arange((self.ONE >> self.SHIFT) + 1, dtype=np.int64) << self.SHIFT
        self.bucket_code = np.searchsorted(lo, starts, side="right").astype(np.uint8)
        self.threshold = np.append(lo, 1 << 32).astype(np.uint64)  # code 255 never steps

    def codes(self, display_linear: Float32Array) -> npt.NDArray[np.uint8]:
        """Codes of finite values in [0, 1] (-0.0 included), any shape."""
        pattern = np.ascontiguousarray(display_linear, dtype=np.float32).view(np.uint32)
        pattern = np.where(pattern > self.ONE, np.uint32(0), pattern)  # -0.0 -> +0.0
        code = self.bucket_code[pattern >> self.SHIFT]
        step = pattern >= self.threshold[code]
        return code + step.view(np.uint8)


_OETF8 = _Oetf8()
#: Per 8-bit code k = 1..255 the first float32 bit pattern of display-linear value whose code is
#: >= k (and 2**32 after the last): what defines the codes, handed to the engine's display pass
#: (`DisplayRequest.thresholds`) so the GPU's codes are these.
OETF8_THRESHOLDS: npt.NDArray[np.uint64] = _OETF8.threshold
OETF8_THRESHOLDS.flags.writeable = False  # the engine uploads it once, keyed by identity


def engine_codes(
    frame: RenderedFrame,
    exposure: float,
    tone_mapper: str,
    background: tuple[float, float, float] | None = None,
) -> npt.NDArray[np.uint8] | None:
    """The 8-bit codes the engine made for this frame (passes/display.py) when they were made
    with these settings, else None (the caller runs `display_codes`)."""
    made = frame.display
    if made is None or not made.request.matches(exposure, tone_mapper, background):
        return None
    return made.codes
