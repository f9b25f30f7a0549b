"""Environments for image-based lighting: built-in procedural presets, uniform radiance, and
equirectangular HDR/EXR files read from configured directories only.

Everything here is CPU/numpy; the GPU side (textures, prefiltering, SH) is `ibl.py`.

Equirectangular convention (the same as Mitsuba 3's ``envmap``, so files render alike in both):
world +y is up; row 0 is the zenith; for a unit direction d,

    u = atan2(d.x, -d.z) / (2 pi)  (wrapped to [0, 1)),   v = acos(d.y) / pi

so u = 0 (the left edge) looks along -z, u = 0.25 along +x, the image centre u = 0.5 along +z and
u = 0.75 along -x.

Radiance units: scene-linear, with 1.0 = 1000 cd/m^2 by default (``shading.emission_scale``), so
the presets sit at plausible absolute levels next to hot-metal glow: a dim hall ~ 0.02-0.1,
fluorescent tubes ~ 5, a window ~ 2-6, an overcast zenith ~ 3.
"""

from __future__ import annotations

import functools
import hashlib
import math
import os
from collections import OrderedDict
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Generic, TypeVar

import numpy as np
import numpy.typing as npt

from sphrender.core.errors import InputError, show
from sphrender.server.scene import EnvironmentConfig

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]

DEFAULT_PRESET = "workshop"
#: Width x height of the generated presets.
PRESET_SIZE = (1024, 512)
#: Files wider than this are box-downsampled by an integer factor on load (GPU memory; the SH
#: and the prefiltered chain do not need more).
MAX_SOURCE_WIDTH = 2048
#: Size of the constant image that stands for a uniform environment.
UNIFORM_SIZE = (64, 32)
#: Environment file suffixes accepted (OpenImageIO reads them as float).
FILE_SUFFIXES = (".hdr", ".exr", ".pfm", ".tif", ".tiff")


@dataclass(frozen=True)
class EnvironmentImage:
    """Equirectangular radiance, (H, W, 3) float32, read-only, W = 2 H, plus a content key.

    `key` is a SHA-256 of the pixels and shape: GPU resources and SH coefficients are cached by it,
    so two scenes naming the same image (or an unchanged file) share them."""

    pixels: F32
    key: str
    label: str

    @property
    def width(self) -> int:
        return int(self.pixels.shape[1])

    @property
    def height(self) -> int:
        return int(self.pixels.shape[0])


def make_image(pixels: npt.ArrayLike, label: str) -> EnvironmentImage:
    array = np.ascontiguousarray(np.asarray(pixels, dtype=np.float32))
    if array.ndim != 3 or array.shape[2] != 3 or array.shape[1] != 2 * array.shape[0]:
        raise ValueError(f"environment pixels must be (H, 2H, 3), got {array.shape}")
    array.setflags(write=False)
    digest = hashlib.sha256()
    digest.update(repr(array.shape).encode())
    digest.update(array.tobytes())
    return EnvironmentImage(array, digest.hexdigest(), label)


# --------------------------------------------------------------------------------------------
# Direction <-> equirectangular coordinates


def uv_to_direction(u: npt.ArrayLike, v: npt.ArrayLike) -> F64:
    """Unit directions (..., 3) for equirect coordinates u, v in [0, 1] (see module docstring)."""
    phi, theta = np.broadcast_arrays(
        2.0 * np.pi * np.asarray(u, dtype=np.float64), np.pi * np.asarray(v, dtype=np.float64)
    )
    sin_theta = np.sin(theta)
    return np.stack([sin_theta * np.sin(phi), np.cos(theta), -sin_theta * np.cos(phi)], axis=-1)


def direction_to_uv(directions: npt.ArrayLike) -> tuple[F64, F64]:
    d = np.asarray(directions, dtype=np.float64)
    u = np.mod(np.arctan2(d[..., 0], -d[..., 2]) / (2.0 * np.pi), 1.0)
    v = np.arccos(np.clip(d[..., 1], -1.0, 1.0)) / np.pi
    return u, v


def pixel_directions(height: int, width: int) -> F64:
    """Direction through each pixel centre, (H, W, 3)."""
    u = (np.arange(width) + 0.5) / width
    v = (np.arange(height) + 0.5) / height
    return uv_to_direction(u[None, :], v[:, None])


def pixel_solid_angles(height: int, width: int) -> F64:
    """Exact solid angle of each pixel row, (H, 1): dphi (cos theta0 - cos theta1). Sums to 4 pi."""
    edges = np.cos(np.pi * np.arange(height + 1) / height)
    return ((2.0 * np.pi / width) * (edges[:-1] - edges[1:]))[:, None]


def sample_bilinear(pixels: F32 | F64, directions: npt.ArrayLike) -> F64:
    """Bilinear lookup of an equirect image (wrapping in u, clamped in v), like the GL sampler."""
    h, w = pixels.shape[:2]
    u, v = direction_to_uv(directions)
    x = u * w - 0.5
    y = np.clip(v * h - 0.5, 0.0, h - 1.0)
    x0 = np.floor(x).astype(np.int64)
    y0 = np.minimum(np.floor(y).astype(np.int64), h - 2) if h > 1 else np.zeros_like(x0)
    fx = (x - x0)[..., None]
    fy = (y - y0)[..., None]
    x1 = x0 + 1
    x0 %= w
    x1 %= w
    y1 = np.minimum(y0 + 1, h - 1)
    p = pixels.astype(np.float64, copy=False)
    top = p[y0, x0] * (1 - fx) + p[y0, x1] * fx
    bottom = p[y1, x0] * (1 - fx) + p[y1, x1] * fx
    result: F64 = top * (1 - fy) + bottom * fy
    return result


# --------------------------------------------------------------------------------------------
# Procedural presets


def _smoothstep(edge0: float, edge1: float, x: F64) -> F64:
    t = np.clip((x - edge0) / (edge1 - edge0), 0.0, 1.0)
    result: F64 = t * t * (3.0 - 2.0 * t)
    return result


def _box(x: F64, lo: float, hi: float, soft: float) -> F64:
    """1 inside [lo, hi], 0 outside, with smooth edges `soft` wide (anti-aliased features)."""
    return _smoothstep(lo - soft, lo + soft, x) * (1.0 - _smoothstep(hi - soft, hi + soft, x))


def _value_noise(x: F64, y: F64, seed: int) -> F64:
    """Cheap smooth 2-D value noise in [0, 1] (hash of integer lattice, smooth interpolation)."""

    # Integer hash mod 2**32: uint32 arithmetic wraps exactly like the int64 products masked
    # with 0xFFFFFFFF, at half the memory traffic.
    seed_term = np.uint32((seed * 2147483647) & 0xFFFFFFFF)

    def hashed(ix: npt.NDArray[np.uint32], iy: npt.NDArray[np.uint32]) -> F64:
        h = ix * np.uint32(374761393) + iy * np.uint32(668265263) + seed_term
        h = (h ^ (h >> np.uint32(13))) * np.uint32(1274126177)
        result: F64 = (h & np.uint32(0xFFFF)) / 65535.0
        return result

    fx_floor = np.floor(x)
    fy_floor = np.floor(y)
    ix = fx_floor.astype(np.int64).astype(np.uint32)  # two's complement wrap, as the mask did
    iy = fy_floor.astype(np.int64).astype(np.uint32)
    fx = x - fx_floor
    fy = y - fy_floor
    sx = fx * fx * (3 - 2 * fx)
    sy = fy * fy * (3 - 2 * fy)
    a = hashed(ix, iy)
    one = np.uint32(1)
    b = hashed(ix + one, iy)
    c = hashed(ix, iy + one)
    d = hashed(ix + one, iy + one)
    result: F64 = (a * (1 - sx) + b * sx) * (1 - sy) + (c * (1 - sx) + d * sx) * sy
    return result


def _workshop(width: int, height: int) -> F64:
    """A dim industrial hall seen from its middle: concrete floor, grey walls with shelving,
    rows of fluorescent tubes on the ceiling, and one large bright window (sky) in the -z wall.

    Built as a box room: each pixel's ray from the room centre is intersected with the box, and
    features are placed on the walls in metres, so they have believable shapes in reflections."""
    d = pixel_directions(height, width)
    half = np.array([9.0, 1.6, 9.0])  # room half sizes around the eye (floor 1.6 m below)
    ceiling = 5.0
    # Distance to each wall along the ray; the nearest positive one is the hit.
    with np.errstate(divide="ignore", invalid="ignore"):
        tx = np.where(d[..., 0] != 0, np.abs(half[0] / d[..., 0]), np.inf)
        tz = np.where(d[..., 2] != 0, np.abs(half[2] / d[..., 2]), np.inf)
        ty = np.where(
            d[..., 1] > 0, ceiling / d[..., 1], np.where(d[..., 1] < 0, -1.6 / d[..., 1], np.inf)
        )
    t = np.minimum(np.minimum(tx, tz), ty)
    p = d * t[..., None]
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    on_floor = (ty <= np.minimum(tx, tz)) & (d[..., 1] < 0)
    on_ceiling = (ty <= np.minimum(tx, tz)) & (d[..., 1] > 0)
    on_wall = ~(on_floor | on_ceiling)

    rgb = np.zeros((height, width, 3))
    # Walls: painted grey-beige, darker lower band, shelving as dark horizontal bands with boxes.
    wall = np.array([0.130, 0.122, 0.105]) * (0.85 + 0.3 * _value_noise(x + z, y * 2, 3))[..., None]
    lower = _box(y, -1.7, -0.6, 0.02)[..., None]
    wall = wall * (1 - 0.45 * lower)
    shelf_rows = sum(_box(y, h, h + 0.05, 0.01) for h in (-0.9, -0.1, 0.7))
    along = np.where(np.abs(tx) < np.abs(tz), z, x)
    boxes = (_value_noise(along * 1.5, np.floor((y + 1.6) / 0.8), 11) > 0.55) & (y < 1.3)
    wall = np.where(boxes[..., None], wall * np.array([1.3, 1.0, 0.7]), wall)
    wall = wall * (1 - 0.7 * np.clip(shelf_rows, 0, 1))[..., None]
    # The window: -z wall, 7 m wide, from 0.3 m to 3.6 m above eye height, 4 x 3 panes.
    window_wall = on_wall & (tz < tx) & (d[..., 2] < 0)
    pane_x = _box(x, -3.5, 3.5, 0.02)
    pane_y = _box(y, 0.3, 3.6, 0.02)
    mullion_x = sum(_box(x, m - 0.04, m + 0.04, 0.01) for m in (-1.75, 0.0, 1.75))
    mullion_y = sum(_box(y, m - 0.04, m + 0.04, 0.01) for m in (1.4, 2.5))
    glass = pane_x * pane_y * (1 - np.clip(mullion_x + mullion_y, 0, 1))
    sky = np.array([4.4, 5.8, 8.4]) * (0.8 + 0.4 * ((y - 0.3) / 3.3))[..., None]
    sky_window = glass[..., None] * sky
    rgb = np.where(on_wall[..., None], wall, rgb)
    rgb = np.where(window_wall[..., None], rgb * (1 - glass[..., None]) + sky_window, rgb)
    # Floor: concrete with mottling and a yellow safety line; lit more under the window.
    concrete = 0.05 * (0.75 + 0.5 * _value_noise(x * 0.7, z * 0.7, 5))
    floor = np.stack([concrete * 1.02, concrete, concrete * 0.95], axis=-1)
    line = _box(x, 2.4, 2.55, 0.01)[..., None] * np.array([0.05, 0.04, 0.0])
    pool = 1.0 + 1.5 * np.exp(-((x / 4.0) ** 2 + ((z + 8.0) / 4.0) ** 2))
    floor = (floor + line) * pool[..., None]
    rgb = np.where(on_floor[..., None], floor, rgb)
    # Ceiling: dark, with three rows of fluorescent tube fittings along z.
    tubes = sum(_box(x, c - 0.12, c + 0.12, 0.015) for c in (-4.5, 0.0, 4.5))
    segments = _box(np.mod(z + 9.0, 3.0), 0.3, 2.7, 0.02)
    lamp = np.clip(tubes, 0, 1) * segments
    ceil = np.array([0.03, 0.03, 0.032]) + lamp[..., None] * np.array([8.0, 8.3, 8.6])
    rgb = np.where(on_ceiling[..., None], ceil, rgb)
    return rgb


def _overcast(width: int, height: int) -> F64:
    """CIE standard overcast sky, L(theta) = Lz (1 + 2 cos theta) / 3 with zenith Lz = 3
    (3000 cd/m^2), above grey ground that reflects it (albedo 0.2: L = 0.2 * (7/9) Lz) and a low
    band of distant buildings along the horizon for structure in reflections."""
    d = pixel_directions(height, width)
    up = d[..., 1]
    lz = 3.0
    sky = lz * (1.0 + 2.0 * np.clip(up, 0.0, 1.0)) / 3.0
    sky_rgb = sky[..., None] * np.array([0.97, 1.0, 1.04])
    u = (np.arange(width) + 0.5) / width
    skyline = 0.02 + 0.05 * _value_noise(np.floor(u * 60.0)[None, :] * 1.0, np.zeros((1, 1)), 9)
    elevation = np.arcsin(np.clip(up, -1, 1))
    buildings = (elevation > 0) & (elevation < skyline)
    ground = 0.2 * (7.0 / 9.0) * lz
    ground_rgb = (
        np.array([0.95, 0.9, 0.8])
        * ground
        * (0.8 + 0.4 * _value_noise(d[..., 0] * 8 / (np.abs(up) + 0.05), d[..., 2] * 8, 2))[
            ..., None
        ]
    )
    rgb = np.where((up > 0)[..., None], sky_rgb, ground_rgb)
    rgb = np.where(buildings[..., None], np.array([0.18, 0.18, 0.2]), rgb)
    return rgb


def _studio(width: int, height: int) -> F64:
    """Photo studio: dark grey cyclorama, a large key soft box front-left-above, a fill box to
    the right, and a thin strip light behind (rim)."""
    d = pixel_directions(height, width)
    rgb = np.zeros((height, width, 3)) + 0.008 + 0.01 * np.clip(d[..., 1], 0, 1)[..., None]

    def softbox(center: tuple[float, float, float], size: float, radiance: float) -> F64:
        c = np.asarray(center) / np.linalg.norm(center)
        cos = np.einsum("hwk,k->hw", d, c)
        angle = np.arccos(np.clip(cos, -1, 1))
        result: F64 = radiance * (1.0 - _smoothstep(size * 0.85, size, angle))
        return result

    rgb += softbox((-1.0, 1.2, 1.0), 0.35, 8.0)[..., None] * np.array([1.0, 0.98, 0.95])
    rgb += softbox((1.5, 0.3, 0.6), 0.3, 2.0)[..., None] * np.array([0.95, 0.98, 1.0])
    strip = _box(d[..., 0], -0.04, 0.04, 0.01) * _box(d[..., 1], 0.1, 0.8, 0.02) * (d[..., 2] < 0)
    rgb += strip[..., None] * 6.0
    return rgb


_PRESETS = {"workshop": _workshop, "overcast": _overcast, "studio": _studio}


@functools.lru_cache(maxsize=8)
def preset_image(name: str) -> EnvironmentImage:
    """The named built-in environment (generated once per process)."""
    width, height = PRESET_SIZE
    try:
        generate = _PRESETS[name]
    except KeyError:
        raise InputError("environment.preset", f"unknown preset {show(name)}") from None
    return make_image(generate(width, height), f"preset:{name}")


@functools.lru_cache(maxsize=32)
def uniform_image(radiance: tuple[float, float, float]) -> EnvironmentImage:
    width, height = UNIFORM_SIZE
    pixels = np.broadcast_to(np.asarray(radiance, np.float32), (height, width, 3))
    return make_image(pixels, f"uniform:{radiance}")


# --------------------------------------------------------------------------------------------
# Files


def _downsample(pixels: F32, factor: int) -> F32:
    h, w = pixels.shape[:2]
    h2, w2 = h // factor, w // factor
    trimmed = pixels[: h2 * factor, : w2 * factor]
    result: F32 = trimmed.reshape(h2, factor, w2, factor, 3).mean(axis=(1, 3), dtype=np.float64)
    return result.astype(np.float32)


def read_environment_file(path: Path, key: str = "environment.file") -> F32:
    """Read an equirect image with OpenImageIO as (H, W, 3) float32; errors name `key`."""
    import OpenImageIO as oiio

    image = oiio.ImageInput.open(os.fspath(path))
    if image is None:
        raise InputError(key, f"cannot read {path.name}: {oiio.geterror() or 'unknown format'}")
    try:
        spec = image.spec()
        width, height, channels = spec.width, spec.height, spec.nchannels
        if abs(width - 2 * height) > 1:
            raise InputError(key, f"{path.name} is {width}x{height}; equirect images are 2:1")
        if width > 32768:
            raise InputError(key, f"{path.name} is {width} px wide; at most 32768")
        data = image.read_image(0, 0, 0, min(channels, 3), "float")
    finally:
        image.close()
    if data is None:
        raise InputError(key, f"cannot read pixels of {path.name}")
    pixels = np.asarray(data, dtype=np.float32).reshape(height, width, -1)
    if pixels.shape[2] == 1:
        pixels = np.repeat(pixels, 3, axis=2)
    elif pixels.shape[2] == 2:
        raise InputError(key, f"{path.name} has 2 channels; need 1 (grey) or 3+ (RGB)")
    if not np.isfinite(pixels).all():
        raise InputError(key, f"{path.name} contains NaN or infinite pixels")
    pixels = np.maximum(pixels, 0.0)  # negative radiance (processing ringing) is not light
    if width != 2 * height:
        pixels = pixels[:, : 2 * height] if width > 2 * height else pixels[: width // 2]
    factor = 1
    while pixels.shape[1] // factor > MAX_SOURCE_WIDTH:
        factor *= 2
    if factor > 1:
        pixels = _downsample(pixels, factor)
    return np.ascontiguousarray(pixels)


def find_asset(directories: Sequence[Path], name: str, key: str, suffixes: Sequence[str]) -> Path:
    """The file `name` names in one of the (resolved) environment `directories`; errors name
    `key`. Absolute names, ``..``, ``~`` and symlinks leading outside are refused (the scene may
    come from a network client), and the server's directories never appear in a message."""
    if not directories:
        raise InputError(
            key, "no environment directories are configured (sphrender render --env-dir DIR)"
        )
    relative = Path(name)
    if relative.is_absolute() or ".." in relative.parts or name.startswith("~"):
        raise InputError(
            key, f"must be a path relative to an environment directory, got {show(name)}"
        )
    if relative.suffix.lower() not in suffixes:
        raise InputError(key, f"must end in one of {', '.join(suffixes)}, got {show(name)}")
    for directory in directories:
        candidate = (directory / relative).resolve()
        if not candidate.is_relative_to(directory):
            raise InputError(key, f"{show(name)} leads outside the environment directories")
        if candidate.is_file():
            return candidate
    raise InputError(key, f"{show(name)} not found in the environment directories")


Loaded = TypeVar("Loaded")


class FileCache(Generic[Loaded]):
    """What was loaded from the latest `size` files, keyed by (resolved path, size, mtime): an
    unchanged file is loaded once, a changed one again; `evict` is called on what the least
    recently used entries drop (e.g. to release a texture)."""

    def __init__(self, size: int, evict: Callable[[Loaded], None] | None = None) -> None:
        self._size, self._evict = size, evict
        self._entries: OrderedDict[tuple[str, int, int], Loaded] = OrderedDict()

    def get(self, path: Path, load: Callable[[Path], Loaded]) -> Loaded:
        stat = path.stat()
        key = (str(path), stat.st_size, stat.st_mtime_ns)
        cached = self._entries.get(key)
        if cached is not None:
            self._entries.move_to_end(key)
            return cached
        entry = self._entries[key] = load(path)
        while len(self._entries) > self._size:
            dropped = self._entries.popitem(last=False)[1]
            if self._evict is not None:
                self._evict(dropped)
        return entry

    def __iter__(self) -> Iterator[Loaded]:
        return iter(list(self._entries.values()))

    def clear(self) -> None:
        self._entries.clear()


class EnvironmentLibrary:
    """Resolves `[environment]` to an `EnvironmentImage`; files only from `directories`.

    A file name is relative to one of the configured directories; absolute names, ``..`` and
    symlinks leading outside are refused (the scene may come from a network client). Loaded
    files are cached by (resolved path, size, mtime), so an unchanged file is read once."""

    def __init__(self, directories: Sequence[str | Path] = (), cache_size: int = 4) -> None:
        self.directories = tuple(Path(d).resolve() for d in directories)
        self._files: FileCache[EnvironmentImage] = FileCache(cache_size)

    def resolve(self, config: EnvironmentConfig) -> EnvironmentImage:
        if config.uniform is not None:
            return uniform_image(config.uniform)
        if config.file is not None:
            return self._load_file(config.file)
        return preset_image(config.preset or DEFAULT_PRESET)

    def find_file(self, name: str) -> Path:
        return find_asset(self.directories, name, "environment.file", FILE_SUFFIXES)

    def _load_file(self, name: str) -> EnvironmentImage:
        def load(path: Path) -> EnvironmentImage:
            return make_image(read_environment_file(path), f"file:{name}")

        return self._files.get(self.find_file(name), load)


def rotation_about_y(degrees: float) -> F64:
    """World -> environment rotation for `environment.rotation_deg` (turning the environment by
    +angle about +y means looking it up at directions turned by -angle)."""
    a = math.radians(degrees)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])
