"""Camera maths in float64: view basis, projection, frustum culling, projected radius.

Everything here runs on the CPU in float64 so that a scene at coordinates ~1e5 loses nothing:
particle positions are made relative to the eye and rotated into view space *before* they are
converted to float32 for the GPU. View space is right-handed, the camera looks down -z; "eye
depth" is the positive distance along the view axis (``-z_view``).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from sphrender.server.scene import CameraConfig


@dataclass(frozen=True)
class Camera:
    eye: npt.NDArray[np.float64]  # (3,)
    #: rows are the view-space axes (right, up, back) in world coordinates: v_view = R @ (p - eye)
    rotation: npt.NDArray[np.float64]  # (3, 3)
    fov_y_deg: float
    aspect: float
    near: float
    width: int
    height: int

    @classmethod
    def from_config(cls, config: CameraConfig, width: int, height: int) -> Camera:
        """The camera of `config` at `width` x `height` (cached: a stream of frames with one
        camera builds its basis once)."""
        return _camera(config, width, height)

    @classmethod
    def build(cls, config: CameraConfig, width: int, height: int) -> Camera:
        eye = np.asarray(config.eye, dtype=np.float64)
        forward = np.asarray(config.target, dtype=np.float64) - eye
        forward /= np.linalg.norm(forward)
        right = np.cross(forward, np.asarray(config.up, dtype=np.float64))
        right /= np.linalg.norm(right)
        true_up = np.cross(right, forward)
        rotation = np.stack([right, true_up, -forward])
        return cls(eye, rotation, config.fov_y, width / height, config.near, width, height)

    @functools.cached_property
    def tan_half_fov_y(self) -> float:
        return math.tan(math.radians(self.fov_y_deg) / 2.0)

    @functools.cached_property
    def pixels_per_unit_at_unit_depth(self) -> float:
        """Pixels spanned by one scene unit at eye depth 1: ``(H / 2) / tan(fov_y / 2)``."""
        return (self.height / 2.0) / self.tan_half_fov_y

    def projected_radius_px(self, radius: float, eye_depth: float) -> float:
        return radius * self.pixels_per_unit_at_unit_depth / eye_depth

    def to_view(self, positions: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """World positions (N, 3) float64 -> view-space positions (N, 3) float64.

        Written as three broadcast products, not `@`: numpy hands a (N, 3) @ (3, 3) product to
        OpenBLAS, whose worker threads then spin on every core after it returns (on the main
        thread) and take them from llvmpipe's rasteriser, more than doubling the frame time."""
        offset = positions - self.eye
        r = self.rotation
        view = offset[:, :1] * r[:, 0]
        view += offset[:, 1:2] * r[:, 1]
        view += offset[:, 2:3] * r[:, 2]
        return view

    def projection_matrix(self, far: float) -> npt.NDArray[np.float32]:
        """OpenGL perspective matrix (column-major when transposed for GL upload)."""
        f = 1.0 / self.tan_half_fov_y
        n = self.near
        m = np.zeros((4, 4), dtype=np.float64)
        m[0, 0] = f / self.aspect
        m[1, 1] = f
        m[2, 2] = (far + n) / (n - far)
        m[2, 3] = 2.0 * far * n / (n - far)
        m[3, 2] = -1.0
        return m.astype(np.float32)

    def visible_mask(
        self,
        view_positions: npt.NDArray[np.float64],
        radii: npt.NDArray[np.floating],
        far: float | None,
    ) -> npt.NDArray[np.bool_]:
        """Spheres that can touch the image: in front of the near plane, inside the four side
        planes, before `far`, and not containing the eye (a sphere around the camera would cover
        the whole image with its inside, which a screen-space surface cannot represent)."""
        depth = -view_positions[:, 2]
        r = np.asarray(radii, dtype=np.float64)
        keep = depth + r > self.near
        if far is not None:
            keep &= depth - r < far
        keep &= np.einsum("ij,ij->i", view_positions, view_positions) > (r * 1.000001) ** 2
        # Side planes through the eye; inward unit normals in view space.
        ty = self.tan_half_fov_y
        tx = ty * self.aspect
        for axis, t in ((0, tx), (1, ty)):
            norm = math.sqrt(1.0 + t * t)
            for sign in (1.0, -1.0):
                # plane: sign * coord <= t * depth  ->  distance = (t*depth - sign*coord)/norm
                dist = (t * depth - sign * view_positions[:, axis]) / norm
                keep &= dist > -r
        return keep


@functools.lru_cache(maxsize=64)
def _camera(config: CameraConfig, width: int, height: int) -> Camera:
    camera = Camera.build(config, width, height)
    camera.eye.flags.writeable = False  # shared by every frame with this camera
    camera.rotation.flags.writeable = False
    return camera
