"""Exact occlusion culling for the sphere splat, so hidden particles are never rasterised.

A particle cloud is mostly interior: of the 90k particles of a ball only the outer layer or two
can own a pixel, yet every one of them costs llvmpipe a quad (two triangles, their set-up and
their fragments). The splat therefore runs in two draws:

1. `front_layer`: per screen tile, the particles whose nearest point is within a band of the
   tile's front-most particle (the visible layer, chosen on the CPU from the centres alone).
2. The rest is tested against the depth image of draw 1 (`DepthMaxTable`): a particle whose
   nearest eye depth lies behind the largest depth in every pixel its silhouette can touch
   would fail the depth test on every fragment, so it is dropped; the survivors are drawn.

The test is conservative, so the depth image is the one a single draw of every particle gives
(equal up to ties in the 24-bit depth buffer, far / 2**24); the front-layer choice only decides
how much is culled, never what is drawn. All screen coordinates here are GL window pixels
(origin bottom-left), as the splat's render target.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from sphrender.server.engine.geometry.camera import Camera

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
Mask = npt.NDArray[np.bool_]

# Below this many particles one draw is about as cheap as two plus the read-back (llvmpipe,
# balls at 1280x720, splat ms culled / single draw: 3k 9.3 / 11.3, 10k 9.3 / 23.6, 30k 18.5 /
# 44.1); scattered particles, where little is hidden, gain less.
MIN_PARTICLES = 2048
# The front layer keeps particles whose nearest point is within this many radii of the tile's
# front-most nearest point: the first two layers of a lattice (spacing 2 r) and a tilted surface.
FRONT_BAND_RADII = 4.0
# A screen tile holding more particles than this is searched for repeats (`repeats`), merged
# when within radius / REPEAT_FRACTION of each other: the same image for coincident ones.
CROWDED_TILE = 64
REPEAT_FRACTION = 64.0
# Tiles are this many projected radii (of the median particle) wide: about one particle apiece.
TILE_RADII = 2.0


@dataclass(frozen=True)
class SphereBounds:
    """Per particle: the inclusive pixel rectangle holding every pixel whose centre ray can hit
    the sphere (GL window coordinates), its nearest eye depth, and whether the bound is valid
    (False for spheres reaching the eye plane: those are always drawn)."""

    x0: I64
    x1: I64
    y0: I64
    y1: I64
    near_depth: F64
    valid: Mask

    def grown(self, pixels: int) -> SphereBounds:
        """The rectangles grown by `pixels` on every side (for passes that reach past the
        silhouettes, such as the anti-aliasing coverage)."""
        return SphereBounds(
            self.x0 - pixels,
            self.x1 + pixels,
            self.y0 - pixels,
            self.y1 + pixels,
            self.near_depth,
            self.valid,
        )

    def subset(self, rows: Mask) -> SphereBounds:
        """The bounds of the particles where `rows` is true."""
        return SphereBounds(
            self.x0[rows],
            self.x1[rows],
            self.y0[rows],
            self.y1[rows],
            self.near_depth[rows],
            self.valid[rows],
        )


def _tangent_extent(
    lateral: F64, depth: F64, radius: F64, tan_half_fov: float, size: int
) -> tuple[F64, F64]:
    """Pixel interval (window coordinates, continuous) of a sphere's silhouette along one axis.

    In the plane of this axis and the view axis the sphere is a circle at (a, d) = (lateral,
    depth) of radius r; a line through the eye with slope m (lateral = m depth) touches it when
    (a - m d)^2 = r^2 (1 + m^2), i.e. m = (a d +- r sqrt(a^2 + d^2 - r^2)) / (d^2 - r^2).
    Requires d > r (the circle lies in front of the eye)."""
    d2_r2 = (depth - radius) * (depth + radius)
    spread = radius * np.sqrt(lateral * lateral + d2_r2)
    ad = lateral * depth
    scale = 0.5 * size / tan_half_fov
    center = 0.5 * size
    return (ad - spread) / d2_r2 * scale + center, (ad + spread) / d2_r2 * scale + center


def sphere_bounds(center_radius: npt.NDArray[np.float32], camera: Camera) -> SphereBounds:
    """Conservative pixel rectangles of the spheres' silhouettes (see `SphereBounds`).

    A fragment is produced at pixel i when its centre i + 0.5 lies inside the silhouette, so the
    continuous interval [lo, hi] maps to pixels ceil(lo - 0.5) .. floor(hi - 0.5); one pixel of
    margin on each side covers float32 rounding in the shader."""
    view = center_radius[:, :3].astype(np.float64)
    radius = center_radius[:, 3].astype(np.float64)
    depth = -view[:, 2]
    # Both tangent lines are finite and on the image side of the eye only when the sphere lies
    # in front of the eye plane, with some room (depth - r > 1e-6 depth) for rounding.
    valid = (depth - radius) > 1e-6 * np.maximum(depth, 1e-300)
    safe_depth = np.where(valid, depth, 1.0)
    safe_radius = np.where(valid, radius, 0.0)
    tan_y = camera.tan_half_fov_y
    x_lo, x_hi = _tangent_extent(
        view[:, 0], safe_depth, safe_radius, tan_y * camera.aspect, camera.width
    )
    y_lo, y_hi = _tangent_extent(view[:, 1], safe_depth, safe_radius, tan_y, camera.height)
    finite = np.isfinite(x_lo) & np.isfinite(x_hi) & np.isfinite(y_lo) & np.isfinite(y_hi)
    valid &= finite
    limit = 4.0 * max(camera.width, camera.height)  # keeps the integer casts in range
    x0 = np.ceil(np.clip(np.where(valid, x_lo, 0.0), -limit, limit) - 0.5) - 1
    x1 = np.floor(np.clip(np.where(valid, x_hi, 0.0), -limit, limit) - 0.5) + 1
    y0 = np.ceil(np.clip(np.where(valid, y_lo, 0.0), -limit, limit) - 0.5) - 1
    y1 = np.floor(np.clip(np.where(valid, y_hi, 0.0), -limit, limit) - 0.5) + 1
    return SphereBounds(
        x0.astype(np.int64),
        x1.astype(np.int64),
        y0.astype(np.int64),
        y1.astype(np.int64),
        depth - radius,
        valid,
    )


def front_layer(bounds: SphereBounds, radius: F64, image_size: tuple[int, int]) -> Mask:
    """Particles to draw first: those within `FRONT_BAND_RADII` radii (in eye depth) of the
    front-most particle of their screen tile, plus every particle without a valid bound.

    Tiles are keyed by the centre of each particle's rectangle and are `TILE_RADII` median
    projected radii wide, so a tile holds about one column of particles."""
    valid = bounds.valid
    front = ~valid
    if not valid.any():
        return front
    index = np.flatnonzero(valid)
    key = _tile_keys(bounds, index, image_size)
    near = bounds.near_depth[index]
    tile_front = np.full(int(key.max()) + 1, np.inf)
    np.minimum.at(tile_front, key, near)
    in_band = near <= tile_front[key] + FRONT_BAND_RADII * radius[index]
    front[index[in_band]] = True
    return front


def _tile_keys(bounds: SphereBounds, index: I64, image_size: tuple[int, int]) -> I64:
    """The screen tile of each particle in `index` (valid bounds): keyed by its rectangle's
    centre, `TILE_RADII` median projected radii wide."""
    x0, x1 = bounds.x0[index], bounds.x1[index]
    y0, y1 = bounds.y0[index], bounds.y1[index]
    radius_px = float(np.median(x1 - x0 - 1)) * 0.5  # the rectangles carry a pixel of margin
    tile = max(TILE_RADII * radius_px, 1.0)
    # Centres off the image share the border tiles, which keeps the tile grid image-sized.
    width, height = image_size
    tx = np.floor(np.clip((x0 + x1) * 0.5, 0, width) / tile).astype(np.int64)
    ty = np.floor(np.clip((y0 + y1) * 0.5, 0, height) / tile).astype(np.int64)
    return np.asarray(ty * (int(width // tile) + 2) + tx, np.int64)


def repeats(
    bounds: SphereBounds,
    center_radius: npt.NDArray[np.float32],
    drawn: Mask,
    image_size: tuple[int, int],
) -> Mask:
    """Particles of `drawn` that repeat a lower-index one of the same radius within
    radius / REPEAT_FRACTION, in screen tiles holding more than CROWDED_TILE of `drawn`: they
    can be left out (coincident spheres add no fragment that passes the depth test, and the
    coverage blends MAX). Empty unless a tile is crowded, so ordinary frames skip the search."""
    out = np.zeros(drawn.shape, np.bool_)
    index = np.flatnonzero(drawn & bounds.valid)
    if index.size <= CROWDED_TILE:
        return out
    key = _tile_keys(bounds, index, image_size)
    counts = np.bincount(key)
    crowded = index[counts[key] > CROWDED_TILE]
    if crowded.size == 0:
        return out
    rows = center_radius[crowded].astype(np.float64)
    step = np.maximum(rows[:, 3], 1e-30) / REPEAT_FRACTION
    cells = np.floor(np.clip(rows[:, :3] / step[:, None], -(2.0**62), 2.0**62)).astype(np.int64)
    radius_bits = center_radius[crowded, 3].view(np.int32).astype(np.int64)
    table = np.column_stack([cells, radius_bits])
    _, first = np.unique(table, axis=0, return_index=True)  # the lowest index of each group
    out[crowded] = True
    out[crowded[first]] = False
    return out


class DepthMaxTable:
    """Range-maximum queries over an eye-depth image (0 = background, read as +inf).

    Level k holds, at [y, x], the largest depth in the 2**k x 2**k block whose lower-left pixel
    is (x, y) (a sparse table, not an aligned pyramid), so a rectangle whose sides lie between
    2**k and 2**(k+1) - 1 is covered exactly by four overlapping blocks: the maximum is exact,
    not rounded up to a coarser tile. Only the levels the queries need are kept (each is as
    large as the image), up to blocks of `max_side`; larger rectangles are simply not culled."""

    def __init__(
        self,
        depth: npt.NDArray[np.float32],
        origin: tuple[int, int],
        sides: npt.NDArray[np.integer] | None = None,
        max_side: int = 64,
    ) -> None:
        """`depth`: (H, W) rows bottom first, covering window pixels from `origin` (x, y);
        `sides`: the shorter sides of the rectangles that will be asked about (None: keep every
        level)."""
        image = np.where(depth > 0.0, depth, np.float32(np.inf)).astype(np.float32)
        self.origin = origin
        self.shape = image.shape
        top = int(np.log2(max(1, min(max_side, *image.shape))))
        if sides is None:
            wanted = set(range(top + 1))
        else:
            levels = np.floor(np.log2(np.clip(sides, 1, 1 << (top + 1)))).astype(np.int64)
            present = np.bincount(levels, minlength=top + 2)[: top + 1]
            wanted = {int(k) for k in np.flatnonzero(present)}
        self.levels: dict[int, npt.NDArray[np.float32]] = {}
        current = image
        for k in range(max(wanted, default=-1) + 1):
            if k:
                step = 1 << (k - 1)
                rows = np.maximum(current[:-step], current[step:])
                current = np.maximum(rows[:, :-step], rows[:, step:])
            if k in wanted:
                self.levels[k] = current

    def occluded(self, bounds: SphereBounds, candidates: I64) -> Mask:
        """For each candidate particle (indices into `bounds`): True when its nearest eye depth
        is larger than every depth inside its rectangle, i.e. no fragment of it can pass the
        depth test. Rectangles leaving the table count as visible (`largest`)."""
        return bounds.near_depth[candidates] > self.largest(bounds, candidates)

    def largest(self, bounds: SphereBounds, candidates: I64) -> npt.NDArray[np.float64]:
        """For each candidate particle (indices into `bounds`): the largest depth inside its
        rectangle (+inf where it holds background), or +inf where the table cannot tell:
        rectangles leaving the table, and those it has no level for.

        The level k = floor(log2(shorter side)) has blocks of side s = 2**k <= side < 2 s, so
        two blocks per axis (at the low and the high end) cover the rectangle exactly when its
        longer side is below 2 s too; longer rectangles (elongated silhouettes near the image
        border, or sides without a level) get +inf."""
        result = np.full(candidates.size, np.inf)
        if candidates.size == 0:
            return result
        ox, oy = self.origin
        height, width = self.shape
        x0 = bounds.x0[candidates] - ox
        x1 = bounds.x1[candidates] - ox
        y0 = bounds.y0[candidates] - oy
        y1 = bounds.y1[candidates] - oy
        inside = bounds.valid[candidates] & (x0 >= 0) & (y0 >= 0) & (x1 < width) & (y1 < height)
        inside &= (x1 >= x0) & (y1 >= y0)
        w = x1 - x0 + 1
        h = y1 - y0 + 1
        level = np.floor(np.log2(np.maximum(np.minimum(w, h), 1))).astype(np.int64)
        inside &= np.isin(level, list(self.levels))
        block = np.left_shift(1, np.clip(level, 0, 62))
        inside &= (w < 2 * block) & (h < 2 * block)
        for k, table in self.levels.items():
            rows = np.flatnonzero(inside & (level == k))
            if rows.size == 0:
                continue
            flat = table.ravel()
            size = 1 << k
            stride = table.shape[1]
            low_x, high_x = x0[rows], x1[rows] - size + 1
            low_y, high_y = y0[rows] * stride, (y1[rows] - size + 1) * stride
            largest = np.maximum(flat[low_y + low_x], flat[low_y + high_x])
            np.maximum(largest, flat[high_y + low_x], out=largest)
            np.maximum(largest, flat[high_y + high_x], out=largest)
            result[rows] = largest
        return result
