"""The encodings for live frontends: JPEG (small, lossy) and raw (no encoding at all).

JPEG (libjpeg-turbo through ``simplejpeg``)
    The frame's display-referred sRGB codes (`display.display_codes`, the same 8-bit codes a PNG
    of the frame stores), composited over `JpegOptions.background` by coverage, then
    compressed: ``out = (c * A + bg * (255 - A) + 127) // 255`` per channel in integer code
    values (A = the 8-bit alpha code), i.e. what a viewer shows when it draws the PNG over that
    colour in sRGB space. JPEG has no alpha channel. Default quality 90 with 4:2:0 chroma
    subsampling (benchmarks/bench_encoders.py measured simplejpeg against Pillow; both bundle
    libjpeg-turbo).

raw
    The arrays themselves, little-endian, rows top first, concatenated without padding in the
    order `raw_arrays` lists them (PROTOCOL.md §4.3 is the normative description):

    * ``rgba8``: ``rgba`` u1 (H, W, 4): the PNG's 8-bit sRGB codes, straight alpha;
    * ``float16`` / ``float32``: ``rgba`` (H, W, 4) scene-linear, straight (not premultiplied)
      RGB exactly as the renderer produced it (float16: IEEE round to nearest even, values
      beyond 65504 become +inf), then per `RawOptions.aovs` ``Z`` (H, W) float32 always (eye
      depth, +inf where no surface) and ``N`` (H, W, 3) in the pixel type (world normals, 0
      where no surface).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import numpy.typing as npt
import simplejpeg

from sphrender.server.engine.frame_output import RenderedFrame
from sphrender.server.output.display import TONE_MAPPERS, display_codes, engine_codes

__all__ = [
    "JPEG_SUBSAMPLING",
    "RAW_TYPES",
    "JpegOptions",
    "RawOptions",
    "encode_jpeg",
    "encode_raw",
    "raw_arrays",
]

#: Chroma subsampling names accepted by `JpegOptions.subsampling`.
JPEG_SUBSAMPLING = ("444", "422", "420")
#: Raw pixel types: 8-bit sRGB codes, or scene-linear half / single floats with the AOVs.
RAW_TYPES = ("rgba8", "float16", "float32")
_RAW_DTYPES = {"rgba8": "u1", "float16": "<f2", "float32": "<f4"}


def _check_display(exposure: float, tone_mapper: str, owner: str) -> None:
    if not np.isfinite(exposure):
        raise ValueError(f"{owner}.exposure must be finite")
    if tone_mapper not in TONE_MAPPERS:
        raise ValueError(f"{owner}.tone_mapper must be one of {', '.join(sorted(TONE_MAPPERS))}")


@dataclass(frozen=True)
class JpegOptions:
    """JPEG: quality 1..100, background as display sRGB in [0, 1], display transform."""

    quality: int = 90
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    subsampling: str = "420"
    exposure: float = 0.0
    tone_mapper: str = "clamp"

    def __post_init__(self) -> None:
        if not 1 <= self.quality <= 100:
            raise ValueError("JpegOptions.quality must be in [1, 100]")
        if len(self.background) != 3 or not all(0.0 <= c <= 1.0 for c in self.background):
            raise ValueError("JpegOptions.background must be 3 numbers in [0, 1]")
        if self.subsampling not in JPEG_SUBSAMPLING:
            allowed = ", ".join(JPEG_SUBSAMPLING)
            raise ValueError(f"JpegOptions.subsampling must be one of {allowed}")
        _check_display(self.exposure, self.tone_mapper, "JpegOptions")


@dataclass(frozen=True)
class RawOptions:
    """raw: pixel type (`RAW_TYPES`), the AOVs of the float types, the rgba8 display transform."""

    type: str = "rgba8"
    aovs: tuple[str, ...] = ("Z", "N")
    exposure: float = 0.0
    tone_mapper: str = "clamp"

    def __post_init__(self) -> None:
        if self.type not in RAW_TYPES:
            raise ValueError(f"RawOptions.type must be one of {', '.join(RAW_TYPES)}")
        if any(aov not in ("Z", "N") for aov in self.aovs) or len(set(self.aovs)) != len(self.aovs):
            raise ValueError("RawOptions.aovs must be distinct names out of Z, N")
        _check_display(self.exposure, self.tone_mapper, "RawOptions")

    @property
    def carried_aovs(self) -> tuple[str, ...]:
        """The AOVs the payload carries, in payload order (none for rgba8)."""
        if self.type == "rgba8":
            return ()
        return tuple(aov for aov in ("Z", "N") if aov in self.aovs)


def composite_codes(
    codes: npt.NDArray[np.uint8], background: tuple[float, float, float]
) -> npt.NDArray[np.uint8]:
    """(H, W, 4) straight 8-bit codes over an opaque background -> (H, W, 3) codes."""
    height, width, _ = codes.shape
    flat = codes.reshape(-1, 4)
    bg = np.array([int(np.floor(c * 255.0 + 0.5)) for c in background], dtype=np.uint16)
    out = np.empty((flat.shape[0], 3), dtype=np.uint8)
    out[:] = bg.astype(np.uint8)
    covered = np.flatnonzero(flat[:, 3])
    if covered.size:
        sub = np.take(flat, covered, axis=0).astype(np.uint16)
        alpha = sub[:, 3:4]
        blended = (sub[:, :3] * alpha + bg * (255 - alpha) + 127) // 255
        out[covered] = blended.astype(np.uint8)
    return out.reshape(height, width, 3)


def encode_jpeg(frame: RenderedFrame, options: JpegOptions | None = None) -> bytes:
    """Baseline JPEG bytes of the frame composited over the background (module docstring)."""
    options = options or JpegOptions()
    composited = engine_codes(frame, options.exposure, options.tone_mapper, options.background)
    if composited is not None:  # the engine composited them: RGB + opaque alpha, as they are
        pixels, colorspace = composited, "RGBX"
    else:
        codes = display_codes(frame.rgba, 8, options.exposure, options.tone_mapper)
        pixels = composite_codes(codes.astype(np.uint8, copy=False), options.background)
        colorspace = "RGB"
    data: bytes = simplejpeg.encode_jpeg(
        pixels, quality=options.quality, colorspace=colorspace, colorsubsampling=options.subsampling
    )
    return data


def raw_arrays(options: RawOptions, width: int, height: int) -> list[dict[str, Any]]:
    """The payload's array descriptors (``name``, ``dtype``, ``shape``), in payload order."""
    pixel = _RAW_DTYPES[options.type]
    arrays: list[dict[str, Any]] = [{"name": "rgba", "dtype": pixel, "shape": [height, width, 4]}]
    for aov in options.carried_aovs:
        if aov == "Z":
            arrays.append({"name": "Z", "dtype": "<f4", "shape": [height, width]})
        else:
            arrays.append({"name": "N", "dtype": pixel, "shape": [height, width, 3]})
    return arrays


def encode_raw(frame: RenderedFrame, options: RawOptions | None = None) -> bytes:
    """The frame's arrays as little-endian bytes in `raw_arrays` order (module docstring)."""
    options = options or RawOptions()
    if options.type == "rgba8":
        made = engine_codes(frame, options.exposure, options.tone_mapper)
        if made is not None:
            return made.tobytes()
        codes = display_codes(frame.rgba, 8, options.exposure, options.tone_mapper)
        return codes.astype(np.uint8, copy=False).tobytes()
    pixel: Literal["<f2", "<f4"] = "<f2" if options.type == "float16" else "<f4"
    with np.errstate(over="ignore"):  # float16: beyond 65504 is +inf, as documented
        parts = [np.ascontiguousarray(frame.rgba, dtype=pixel).tobytes()]
        for aov in options.carried_aovs:
            if aov == "Z":
                if frame.depth is None:
                    raise ValueError("raw AOV Z requested but the frame has no depth")
                parts.append(np.ascontiguousarray(frame.depth, dtype="<f4").tobytes())
            else:
                if frame.normals is None:
                    raise ValueError("raw AOV N requested but the frame has no normals")
                parts.append(np.ascontiguousarray(frame.normals, dtype=pixel).tobytes())
    return b"".join(parts)
