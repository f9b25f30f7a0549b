"""Detail fixed to the workpiece: the same surface point's detail normal seen from two views."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.interpolate import griddata

Array = npt.NDArray[np.float64]


def two_view_angles(
    points_a: Array, slopes_a: Array, points_b: Array, slopes_b: Array, inside: float = 0.45
) -> tuple[Array, Array]:
    """(angle between the two views' detail normals, the detail's tilt), in degrees, at view
    A's top-face points within `inside` of the centre (away from the edges in both views),
    view B's slopes interpolated there. Slopes are (dy/dx, dy/dz) of a face facing +y."""
    near = np.all(np.abs(points_a) < inside, axis=-1)
    moved = griddata(points_b, slopes_b, points_a[near], method="linear")
    ok = np.all(np.isfinite(moved), axis=-1)
    assert ok.sum() > 1000
    own = slopes_a[near][ok]
    a = np.stack([-own[:, 0], np.ones(ok.sum()), -own[:, 1]], -1)
    b = np.stack([-moved[ok, 0], np.ones(ok.sum()), -moved[ok, 1]], -1)
    cos = np.sum(a * b, -1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1)
    angle = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    tilt = np.degrees(np.arctan(np.linalg.norm(own, axis=-1)))
    print(f"{ok.sum()} points: p99 {np.percentile(angle, 99):.3f}, max {angle.max():.3f} deg; "
          f"tilt {tilt.mean():.2f}")  # fmt: skip
    return angle, tilt
