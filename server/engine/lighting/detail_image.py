"""Surface detail from an image file (`[finish] detail_image`): found in the environment
directories under the same rules as `[environment] file`, read with OpenImageIO, checked, and
turned into the texels the detail pass tiles over the faces (`passes/detail_images.py`).

Channel 0 is height (image values; `detail_image_depth` scene units per unit value), an optional
channel 1 a roughness map in [0, 1]. The height's slope is taken here once per file, by central
differences that wrap (the image tiles), in height per tile: row j, column i of a W x H image
sits at u = (i + 0.5) / W, v = (j + 0.5) / H of the tile. Half floats: a 2048 x 2048 tile is
45 MB with its mipmaps, and they halve the pass's texture reads. CPU and numpy only.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from sphrender.core.errors import InputError
from sphrender.server.engine.lighting.environment import find_asset

KEY = "finish.detail_image"
#: The largest side accepted, in pixels.
MAX_SIDE = 2048
#: The largest image value accepted (either sign): slopes stay finite in float32.
MAX_VALUE = 1e6
#: Suffixes accepted; OpenImageIO reads each as float (8- and 16-bit files scaled to [0, 1]).
SUFFIXES = (".png", ".exr", ".tif", ".tiff", ".hdr", ".pfm", ".jpg", ".jpeg")


@dataclass(frozen=True)
class DetailTexels:
    """(H, W, 4) float16 per texel: d height / du, d height / dv (per tile) over `slope_scale`
    (so within [-1, 1]: half floats keep 11 bits of them), height, and the roughness map
    (channel 1, else 1 - height); those two clipped to half's range."""

    texels: npt.NDArray[np.float16]
    slope_scale: float

    @property
    def size(self) -> tuple[int, int]:
        return int(self.texels.shape[1]), int(self.texels.shape[0])


def find_detail_image(directories: Sequence[Path], name: str) -> Path:
    """The file `[finish] detail_image` names, under `[environment] file`'s rules."""
    return find_asset(directories, name, KEY, SUFFIXES)


def read_detail_image(path: Path) -> DetailTexels:
    """Read and check the image at `path`; every failure is an `InputError` naming the field."""
    pixels = _read_pixels(path)
    if not np.isfinite(pixels).all():
        raise InputError(KEY, f"{path.name} contains NaN or infinite pixels")
    if np.abs(pixels).max(initial=0.0) > MAX_VALUE:
        raise InputError(KEY, f"{path.name} has values beyond -1e6 to 1e6; heights are 0 to 1")
    return detail_texels(pixels)


def detail_texels(pixels: npt.NDArray[np.float32]) -> DetailTexels:
    """(H, W, 1 or 2) image values -> `DetailTexels` (slopes by wrapping central differences)."""
    height = pixels[..., 0].astype(np.float64)
    rows, columns = height.shape
    du = (np.roll(height, -1, axis=1) - np.roll(height, 1, axis=1)) * (columns / 2.0)
    dv = (np.roll(height, -1, axis=0) - np.roll(height, 1, axis=0)) * (rows / 2.0)
    roughness = pixels[..., 1] if pixels.shape[2] > 1 else 1.0 - height
    scale = float(max(np.abs(du).max(), np.abs(dv).max(), 1e-30))
    half = float(np.finfo(np.float16).max)
    texels = np.stack(
        [du / scale, dv / scale, np.clip(height, -half, half), np.clip(roughness, -half, half)],
        axis=-1,
    )
    return DetailTexels(np.ascontiguousarray(texels.astype(np.float16)), scale)


def _read_pixels(path: Path) -> npt.NDArray[np.float32]:
    import OpenImageIO as oiio

    image = oiio.ImageInput.open(os.fspath(path))
    if image is None:
        oiio.geterror()  # clears the library's message; it is not the client's to read
        raise InputError(KEY, f"{path.name} cannot be read as an image (unknown format or damaged)")
    try:
        spec = image.spec()
        width, height, channels = spec.width, spec.height, spec.nchannels
        if channels not in (1, 2):
            raise InputError(
                KEY,
                f"{path.name} has {channels} channels; a detail image has 1 (height) or 2 "
                "(height, roughness)",
            )
        if max(width, height) > MAX_SIDE:
            raise InputError(
                KEY, f"{path.name} is {width}x{height} pixels; at most {MAX_SIDE} a side"
            )
        data = image.read_image(0, 0, 0, channels, "float")
    finally:
        image.close()
    if data is None or np.size(data) != width * height * channels:
        oiio.geterror()
        raise InputError(KEY, f"the pixels of {path.name} cannot be read (damaged file)")
    return np.asarray(data, dtype=np.float32).reshape(height, width, channels)
