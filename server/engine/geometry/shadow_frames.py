"""Light-space frames of the shadow maps (passes/shadow.py), numpy in float64 on the host.

Particles are made relative to the frame's centre (the middle of their bounds) before they become
float32, as the camera makes them relative to the eye, so shadows at 1e5 coordinates keep their
millimetres. A point or sphere light gets a cube map around it; a directional light an
orthographic map fitted to the particles' bounds across its direction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]

#: Cube faces: rows (right, up, back) of each face's view, looking along -back = +x, -x, +y,
#: -y, +z, -z (the same table as shaders/shadow/shadow_lookup.glsl).
CUBE_FACES: tuple[F64, ...] = tuple(
    np.array(rows, dtype=np.float64)
    for rows in (
        ((0, 0, 1), (0, 1, 0), (-1, 0, 0)),
        ((0, 0, -1), (0, 1, 0), (1, 0, 0)),
        ((-1, 0, 0), (0, 0, -1), (0, -1, 0)),
        ((-1, 0, 0), (0, 0, 1), (0, 1, 0)),
        ((-1, 0, 0), (0, 1, 0), (0, 0, -1)),
        ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
    )
)


@dataclass(frozen=True)
class ShadowSpheres:
    """Every particle as (centre - `centre`, radius), float32, and the float64 `centre`."""

    centre: F64
    spheres: npt.NDArray[np.float32]
    max_radius: float

    @classmethod
    def of(cls, positions: F64, radii: npt.NDArray[np.floating]) -> ShadowSpheres:
        centre = 0.5 * (positions.min(axis=0) + positions.max(axis=0))
        spheres = np.empty((positions.shape[0], 4), dtype=np.float32)
        spheres[:, :3] = positions - centre
        spheres[:, 3] = radii
        return cls(centre, spheres, float(np.max(radii)))


@dataclass(frozen=True)
class CubeFrame:
    """A cube map around a light: the light relative to the spheres' centre, the clip planes."""

    light: F64
    near: float
    far: float


@dataclass(frozen=True)
class OrthoFrame:
    """An orthographic map: rows of `axes` = (x, y across, z along the travel) in world axes;
    `origin` the near plane's centre relative to the spheres' centre; half extents in x, y."""

    axes: F64
    origin: F64
    half_extent: tuple[float, float]


def cube_frame(light_position: F64, spheres: ShadowSpheres) -> CubeFrame:
    light = np.asarray(light_position, dtype=np.float64) - spheres.centre
    reach = np.linalg.norm(spheres.spheres[:, :3] - light, axis=1)
    far = float(np.max(reach)) + spheres.max_radius
    far = max(far * 1.01, 1e-6)
    return CubeFrame(light, far * 1e-6, far)


def light_axes(direction: F64) -> F64:
    """Rows: two unit vectors across `direction`, then `direction` normalised."""
    z = np.asarray(direction, dtype=np.float64)
    z = z / np.linalg.norm(z)
    helper = np.array([0.0, 1.0, 0.0]) if abs(z[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z])


def ortho_frame(direction: F64, spheres: ShadowSpheres) -> OrthoFrame:
    axes = light_axes(direction)
    local = spheres.spheres[:, :3].astype(np.float64) @ axes.T
    radii = spheres.spheres[:, 3].astype(np.float64)
    low = (local - radii[:, None]).min(axis=0)
    high = (local + radii[:, None]).max(axis=0)
    middle = 0.5 * (low + high)
    # A margin of a few per cent keeps the outermost spheres' texels inside the map.
    half = np.maximum(0.5 * (high - low) * 1.02, 1e-6)
    near = low[2] - 0.01 * (high[2] - low[2]) - 1e-6
    origin = axes.T @ np.array([middle[0], middle[1], near])
    return OrthoFrame(axes, origin, (float(half[0]), float(half[1])))
