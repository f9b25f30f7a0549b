"""Encode a `RenderedFrame` to PNG (display-referred) or OpenEXR (scene-linear plus AOVs).

Encoding is a separate step from rendering: the engine returns float arrays, these functions turn
them into bytes (for the service) or files (for the CLI).

PNG (via OpenImageIO)
    Scene-linear RGB is scaled by ``2**exposure``, tone mapped (`TONE_MAPPERS`: ``"aces"``, a
    filmic curve, or ``"clamp"``; `PngOptions` defaults to clamp, the scene's ``[output]`` to aces)
    and encoded with the exact sRGB OETF. Quantisation is done here, in numpy, as
    ``floor(v * maxcode + 0.5)`` (round half up), and OpenImageIO receives integer pixels, so it
    performs no float conversion of its own. Alpha is *straight* coverage: the spec carries
    ``oiio:UnassociatedAlpha = 1`` because without it OpenImageIO's PNG writer assumes the data is
    premultiplied and divides RGB by alpha (rgb 0.5, a 0.5 would be stored as 1.0). The file is
    tagged sRGB (``sRGB``/``gAMA``/``cHRM`` chunks). OpenImageIO's Python API has no in-memory
    output (IOProxy is C++ only), so `encode_png` writes into a private temporary directory and
    reads the file back.

OpenEXR (via the ``OpenEXR`` module, >= 3.5, which writes to binary streams)
    Single-part scanline image, rows top-first (``INCREASING_Y``); `encode_exr` writes straight
    into an ``io.BytesIO``, no temporary file. Channels:

    * ``R, G, B, A``: half or float per `ExrOptions.pixel_type`. RGB is premultiplied by A, as the
      OpenEXR convention requires, unless ``ExrOptions.associated_alpha`` is False. NaN → 0.
    * ``Z``: always float32 (half has an 11-bit significand, so at depth 100 it resolves only
      ~0.06 units, useless for depth compositing); +inf where no surface, NaN → +inf.
    * ``N.X, N.Y, N.Z``: world-space normals, half or float, NaN → 0.

    The largest finite half is 65504 and anything above becomes +inf, so in half mode RGB
    is clamped to +-65504; molten metal emission can exceed that, use ``pixel_type="float"`` to
    keep it, or ``"auto"``: half unless some colour value exceeds half's range, then float.
    Every channel is passed to OpenEXR as a C-contiguous array: its Python binding ignores
    numpy strides, and a strided view such as ``rgba[..., 0]`` is written as garbage.
"""

from __future__ import annotations

import io
import os
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, TypeAlias

import numpy as np
import numpy.typing as npt
import OpenEXR
import OpenImageIO as oiio

from sphrender.server.engine.frame_output import RenderedFrame
from sphrender.server.output.display import (
    TONE_MAPPERS,
    display_codes,
    engine_codes,
    srgb_oetf,
    tone_map_aces,
    tone_map_clamp,
    tone_map_for_display,
)
from sphrender.server.output.frame_formats import (
    JpegOptions,
    RawOptions,
    encode_jpeg,
    encode_raw,
    raw_arrays,
)

__all__ = [
    "EXR_AOVS",
    "EXR_COMPRESSIONS",
    "FORMATS",
    "HALF_MAX",
    "TONE_MAPPERS",
    "ExrOptions",
    "ImageFormat",
    "JpegOptions",
    "PngOptions",
    "RawOptions",
    "encode",
    "encode_exr",
    "encode_jpeg",
    "encode_png",
    "encode_raw",
    "file_suffix",
    "raw_arrays",
    "read_exr",
    "srgb_oetf",
    "tone_map_aces",
    "tone_map_clamp",
    "tone_map_for_display",
    "write",
    "write_exr",
    "write_png",
]

ImageFormat: TypeAlias = Literal["png", "exr", "jpeg", "raw"]
#: Every image format, in the order error messages list them.
FORMATS: tuple[str, ...] = ("png", "exr", "jpeg", "raw")
#: Options per format.
Options: TypeAlias = "PngOptions | ExrOptions | JpegOptions | RawOptions"
StrPath: TypeAlias = str | os.PathLike[str]
Float32Array: TypeAlias = npt.NDArray[np.float32]

#: Largest finite IEEE half value; larger values round to +inf when stored as half.
HALF_MAX = 65504.0

#: AOV name -> EXR channel names written for it.
EXR_AOVS: dict[str, tuple[str, ...]] = {"Z": ("Z",), "N": ("N.X", "N.Y", "N.Z")}

#: Accepted `ExrOptions.compression` names. "zip", "zips", "piz", "rle" and "none" are lossless;
#: "pxr24" rounds float32 channels (including Z) to 24 bits; "b44"/"b44a" and "dwaa"/"dwab" are
#: lossy.
EXR_COMPRESSIONS: dict[str, object] = {
    "none": OpenEXR.NO_COMPRESSION,
    "rle": OpenEXR.RLE_COMPRESSION,
    "zips": OpenEXR.ZIPS_COMPRESSION,
    "zip": OpenEXR.ZIP_COMPRESSION,
    "piz": OpenEXR.PIZ_COMPRESSION,
    "pxr24": OpenEXR.PXR24_COMPRESSION,
    "b44": OpenEXR.B44_COMPRESSION,
    "b44a": OpenEXR.B44A_COMPRESSION,
    "dwaa": OpenEXR.DWAA_COMPRESSION,
    "dwab": OpenEXR.DWAB_COMPRESSION,
}


# --------------------------------------------------------------------------------------------
# Options


PNG_FILTER_SUB = 0x10  # libpng's PNG_FILTER_SUB flag (OpenImageIO's "png:filter")


@dataclass(frozen=True)
class PngOptions:
    """PNG encoding: 8 or 16 bits per channel, exposure in stops, tone mapper name, zlib level.

    Rows are written with zlib level 3 and PNG's "sub" row filter instead of libpng's level 6
    with adaptive filter choice: on a 1280x720 render of a ball that measured 26 ms against
    79-102 ms, and the file came out 25% larger (171 vs 138 kB)."""

    bits: Literal[8, 16] = 8
    exposure: float = 0.0
    tone_mapper: str = "clamp"
    compression_level: int = 3

    def __post_init__(self) -> None:
        if self.bits not in (8, 16):
            raise ValueError(f"PngOptions.bits must be 8 or 16, got {self.bits!r}")
        if not np.isfinite(self.exposure):
            raise ValueError(f"PngOptions.exposure must be finite, got {self.exposure!r}")
        if not 0 <= self.compression_level <= 9:
            raise ValueError(
                f"PngOptions.compression_level must be 0..9, got {self.compression_level!r}"
            )
        if self.tone_mapper not in TONE_MAPPERS:
            raise ValueError(
                f"PngOptions.tone_mapper must be one of {sorted(TONE_MAPPERS)}, "
                f"got {self.tone_mapper!r}"
            )


@dataclass(frozen=True)
class ExrOptions:
    """EXR encoding: colour/normal pixel type, AOVs to write (subset of Z, N), compression.

    ``associated_alpha`` (default True) stores RGB premultiplied by A, as the OpenEXR convention
    requires (compositors such as Nuke assume it); False stores the frame's straight RGB as is.
    """

    pixel_type: Literal["half", "float", "auto"] = "half"
    aovs: tuple[str, ...] = ("Z", "N")
    compression: str = "zip"
    associated_alpha: bool = True

    def __post_init__(self) -> None:
        if self.pixel_type not in ("half", "float", "auto"):
            raise ValueError(
                f"ExrOptions.pixel_type must be 'half', 'float' or 'auto', got {self.pixel_type!r}"
            )
        unknown = [aov for aov in self.aovs if aov not in EXR_AOVS]
        if unknown:
            raise ValueError(f"ExrOptions.aovs: unknown AOV(s) {unknown}, known: {list(EXR_AOVS)}")
        if len(set(self.aovs)) != len(self.aovs):
            raise ValueError(f"ExrOptions.aovs has duplicates: {self.aovs}")
        if self.compression not in EXR_COMPRESSIONS:
            raise ValueError(
                f"ExrOptions.compression must be one of {sorted(EXR_COMPRESSIONS)}, "
                f"got {self.compression!r}"
            )


# --------------------------------------------------------------------------------------------
# PNG


def _png_pixels(frame: RenderedFrame, options: PngOptions) -> npt.NDArray[np.uint8 | np.uint16]:
    """Code values per pixel: the engine's (8 bits, when it made them) or
    `display.display_codes`."""
    if options.bits == 8:
        codes = engine_codes(frame, options.exposure, options.tone_mapper)
        if codes is not None:
            return codes
    return display_codes(frame.rgba, options.bits, options.exposure, options.tone_mapper)


def write_png(frame: RenderedFrame, path: StrPath, options: PngOptions | None = None) -> None:
    """Write the frame as an sRGB PNG with straight alpha (any file name; format is forced)."""
    options = options or PngOptions()
    pixels = _png_pixels(frame, options)
    spec = oiio.ImageSpec(frame.width, frame.height, 4, "uint8" if options.bits == 8 else "uint16")
    spec.attribute("oiio:UnassociatedAlpha", 1)  # straight alpha: do not divide RGB by alpha
    spec.attribute("oiio:ColorSpace", "sRGB")
    spec.attribute("png:compressionLevel", options.compression_level)
    spec.attribute("png:filter", PNG_FILTER_SUB)
    filename = os.fspath(path)
    out = oiio.ImageOutput.create("png")  # by format name, so the path's suffix does not matter
    if out is None:
        raise RuntimeError(f"OpenImageIO cannot create a PNG writer: {oiio.geterror()}")
    try:
        if not out.open(filename, spec):
            raise OSError(f"cannot open {filename!r} for writing: {out.geterror()}")
        if not out.write_image(pixels):
            raise OSError(f"cannot write PNG {filename!r}: {out.geterror()}")
    finally:
        out.close()


def encode_png(frame: RenderedFrame, options: PngOptions | None = None) -> bytes:
    """PNG bytes of the frame (see `write_png`); goes through a private temporary directory."""
    with tempfile.TemporaryDirectory(prefix="sphrender-png-") as tmp:
        path = Path(tmp) / "frame.png"
        write_png(frame, path, options)
        return path.read_bytes()


# --------------------------------------------------------------------------------------------
# EXR


def exr_needs_float(frame: RenderedFrame) -> bool:
    """Whether some finite colour value lies outside half float's range (|v| > 65504)."""
    rgb = frame.rgba[..., :3]
    with np.errstate(invalid="ignore"):
        return bool(np.any(np.abs(np.where(np.isfinite(rgb), rgb, 0.0)) > HALF_MAX))


def _exr_channels(frame: RenderedFrame, options: ExrOptions) -> dict[str, np.ndarray]:
    half = options.pixel_type == "half" or (
        options.pixel_type == "auto" and not exr_needs_float(frame)
    )
    colour_type = np.float16 if half else np.float32
    colour_max = HALF_MAX if half else float(np.finfo(np.float32).max)

    def colour(plane: Float32Array, lo: float, hi: float) -> np.ndarray:
        # NaN → 0, ±inf and out-of-range values clamp to the limits (never inf in half).
        clean = np.clip(np.nan_to_num(plane, nan=0.0, posinf=hi, neginf=lo), lo, hi)
        return np.ascontiguousarray(clean.astype(colour_type))

    alpha = np.clip(np.nan_to_num(frame.rgba[..., 3], nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0)
    rgb = frame.rgba[..., :3]
    if options.associated_alpha:
        with np.errstate(invalid="ignore"):  # inf · 0 → NaN → 0 below
            rgb = rgb * alpha[..., np.newaxis]
    channels: dict[str, np.ndarray] = {}
    for index, name in enumerate("RGB"):
        channels[name] = colour(rgb[..., index], -colour_max, colour_max)
    channels["A"] = colour(alpha, 0.0, 1.0)

    for aov in options.aovs:
        if aov == "Z":
            if frame.depth is None:
                raise ValueError("EXR AOV 'Z' requested but the frame has no depth")
            depth = np.where(np.isnan(frame.depth), np.float32(np.inf), frame.depth)
            channels["Z"] = np.ascontiguousarray(depth, dtype=np.float32)  # always float32
        elif aov == "N":
            if frame.normals is None:
                raise ValueError("EXR AOV 'N' requested but the frame has no normals")
            for index, name in enumerate(EXR_AOVS["N"]):
                channels[name] = colour(frame.normals[..., index], -1.0, 1.0)
    return channels


def _exr_file(frame: RenderedFrame, options: ExrOptions) -> OpenEXR.File:
    header = {
        "compression": EXR_COMPRESSIONS[options.compression],
        "type": OpenEXR.scanlineimage,
        "lineOrder": OpenEXR.INCREASING_Y,
    }
    return OpenEXR.File(header, _exr_channels(frame, options))


def write_exr(frame: RenderedFrame, path: StrPath, options: ExrOptions | None = None) -> None:
    """Write the frame as a single-part scanline OpenEXR file (see module docstring)."""
    _exr_file(frame, options or ExrOptions()).write(os.fspath(path))


def encode_exr(frame: RenderedFrame, options: ExrOptions | None = None) -> bytes:
    """OpenEXR bytes of the frame, written in memory (no temporary file)."""
    stream = io.BytesIO()
    _exr_file(frame, options or ExrOptions()).write(stream)
    return stream.getvalue()


def read_exr(source: StrPath | bytes) -> dict[str, np.ndarray]:
    """Channel name → (H, W) array (float16 for half, float32 for float) of an EXR's first part.

    Rows come back top-first. ``source`` is a path or the bytes of a whole file.
    """
    if isinstance(source, bytes | bytearray | memoryview):
        exr = OpenEXR.File(io.BytesIO(bytes(source)), separate_channels=True)
    else:
        exr = OpenEXR.File(os.fspath(source), separate_channels=True)
    return {name: channel.pixels for name, channel in exr.channels().items()}


# --------------------------------------------------------------------------------------------
# Dispatch

_SUFFIXES: Mapping[str, str] = {"png": ".png", "exr": ".exr", "jpeg": ".jpg", "raw": ".raw"}
_OPTIONS: Mapping[str, type] = {
    "png": PngOptions,
    "exr": ExrOptions,
    "jpeg": JpegOptions,
    "raw": RawOptions,
}


def file_suffix(format: ImageFormat) -> str:
    """The file-name suffix (with dot) for an image format."""
    try:
        return _SUFFIXES[format]
    except (KeyError, TypeError):
        raise ValueError(f"unknown image format, known: {', '.join(FORMATS)}") from None


def _check_options(format: ImageFormat, options: Options | None) -> Options:
    file_suffix(format)  # validates the format name
    wanted = _OPTIONS[format]
    if options is None:
        return wanted()
    if not isinstance(options, wanted):
        raise TypeError(f"format {format} needs {wanted.__name__}")
    return options


def encode(frame: RenderedFrame, format: ImageFormat, options: Options | None = None) -> bytes:
    """Encode to ``format`` with matching options (defaults when None)."""
    checked = _check_options(format, options)
    if isinstance(checked, PngOptions):
        return encode_png(frame, checked)
    if isinstance(checked, JpegOptions):
        return encode_jpeg(frame, checked)
    if isinstance(checked, RawOptions):
        return encode_raw(frame, checked)
    return encode_exr(frame, checked)


def write(
    frame: RenderedFrame, path: StrPath, format: ImageFormat, options: Options | None = None
) -> None:
    """Write to ``path`` in ``format`` with matching options (defaults when None)."""
    checked = _check_options(format, options)
    if isinstance(checked, PngOptions):
        write_png(frame, path, checked)
    elif isinstance(checked, ExrOptions):
        write_exr(frame, path, checked)
    else:
        Path(path).write_bytes(encode(frame, format, checked))
