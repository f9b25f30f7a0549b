"""Motion blur's geometry (numpy, host): when a frame's particles carry velocities and the
camera's shutter is open, the renderer draws sub-frames at positions + v t over the shutter
[-shutter/2, +shutter/2] and averages them (passes/accumulate.py).

* Sub-frame times: the midpoints of N equal slices of the shutter, N = the longest streak over
  `SUBFRAME_SPACING_PX` (rounded up; at least 1, at most `MAX_SUBFRAMES`), so consecutive
  sub-frames of the fastest particle lie about a pixel apart.
* A streak (a particle's screen motion over the shutter, to first order at its depth) longer than
  `MAX_STREAK_FRACTION` of the image's larger side is shortened to it by scaling that particle's
  velocity; particles not in front of the camera at the frame's time are not moved.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from sphrender.core.frame import ParticleFrame
from sphrender.server.engine.geometry.camera import Camera

#: Most sub-frames one frame is drawn with.
MAX_SUBFRAMES = 64
#: Screen distance between consecutive sub-frames of the fastest particle (px).
SUBFRAME_SPACING_PX = 1.0
#: Longest streak, as a fraction of the image's larger side.
MAX_STREAK_FRACTION = 0.25


@dataclass(frozen=True)
class MotionPlan:
    """The sub-frames of one blurred frame: their times (seconds from the frame's time, the one
    nearest 0 last) and the velocities after clamping (scene units per second, float64)."""

    times: tuple[float, ...]
    velocities: npt.NDArray[np.float64]
    longest_streak_px: float

    def subframe(self, frame: ParticleFrame, time: float) -> ParticleFrame:
        return replace(frame, positions=frame.positions + self.velocities * time)


def streak_lengths_px(
    frame: ParticleFrame, camera: Camera, shutter: float
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_]]:
    """Each particle's screen motion over the shutter (px, first order at its depth) and whether
    it is in front of the camera (others get length 0)."""
    assert frame.velocities is not None
    view = camera.to_view(frame.positions)
    velocity = camera.to_view(np.asarray(frame.velocities, np.float64) + camera.eye).T
    depth = -view[:, 2]
    ahead = depth > camera.near
    d = np.where(ahead, depth, 1.0)
    vd = -velocity[2]
    sx = (velocity[0] * d - view[:, 0] * vd) / (d * d)
    sy = (velocity[1] * d - view[:, 1] * vd) / (d * d)
    length = np.hypot(sx, sy) * camera.pixels_per_unit_at_unit_depth * shutter
    return np.where(ahead & np.isfinite(length), length, 0.0), ahead


def plan_motion(frame: ParticleFrame, camera: Camera, shutter: float) -> MotionPlan | None:
    """The sub-frames of `frame`, or None when it is a still (no shutter, no velocities)."""
    if shutter <= 0.0 or frame.velocities is None or frame.count == 0:
        return None
    lengths, ahead = streak_lengths_px(frame, camera, shutter)
    limit = MAX_STREAK_FRACTION * max(camera.width, camera.height)
    scale = np.where(lengths > limit, limit / np.maximum(lengths, 1e-300), 1.0)
    scale = np.where(ahead, scale, 0.0)
    velocities = np.asarray(frame.velocities, np.float64) * scale[:, None]
    longest = float(np.minimum(lengths, limit).max())
    count = min(max(math.ceil(longest / SUBFRAME_SPACING_PX), 1), MAX_SUBFRAMES)
    times = [((i + 0.5) / count - 0.5) * shutter for i in range(count)]
    times.sort(key=lambda t: -abs(t))
    return MotionPlan(tuple(times), velocities, longest)
