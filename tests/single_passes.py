"""Single passes of the renderer on given images: the same pass objects and code paths as a
frame's, for tests that compare one pass with a numpy reference (exact normals into the shade
pass, synthetic depth into the smoothing, a kelvin image into the temperature blur).

`SinglePasses(renderer)` owns nothing (the passes are the renderer's, `image_passes`) and runs
on the GL context's owner thread.
"""

from __future__ import annotations

import moderngl
import numpy as np
import numpy.typing as npt

from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.gpu.draw import image_bytes, read_image
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import QualityConfig, Scene


class SinglePasses:
    def __init__(self, renderer: SurfaceRenderer) -> None:
        self._gl = renderer.gl
        splat, smooth, normals, temperature, shade = renderer.image_passes
        self._splat = splat
        self._smooth = smooth
        self._normals = normals
        self._temperature = temperature
        self._shade = shade

    def shade_normal_depth(
        self,
        normal_depth: npt.NDArray[np.float32],
        scene: Scene,
        temperatures: npt.NDArray[np.float32] | None = None,
    ) -> npt.NDArray[np.float32]:
        """Run only the shade pass on given world normals + eye depth (H, W, 4), rows top first
        (depth 0 = no surface), and optional per-pixel kelvin (H, W); returns straight RGBA.
        Shading can so be compared with references on exact normals."""
        self._gl.check_owner()
        height, width = normal_depth.shape[:2]
        if (width, height) != (scene.image.width, scene.image.height):
            raise ValueError("normal_depth must have the scene's image size")
        target = self._normals.target((width, height))
        target.texture.write(image_bytes(normal_depth))
        temperature = None
        if temperatures is not None:
            temperature, _ = self._splat.targets((width, height)).temperature_targets()
            temperature.write(image_bytes(temperatures))
        camera = Camera.from_config(scene.camera, width, height)
        color = self._shade.run(scene, camera, target.texture, temperature)
        rgba = np.frombuffer(color.texture.read(), dtype=np.float32).reshape(height, width, 4)
        return np.ascontiguousarray(rgba[::-1])

    def detail_normal_depth(
        self, normal_depth: npt.NDArray[np.float32], scene: Scene
    ) -> npt.NDArray[np.float32]:
        """Run only the surface-detail pass on given world normals + eye depth (H, W, 4), rows
        top first; returns its normals + depth, so the detail can be compared on exact shapes."""
        self._gl.check_owner()
        height, width = normal_depth.shape[:2]
        target = self._normals.target((width, height))
        target.texture.write(image_bytes(normal_depth))
        camera = Camera.from_config(scene.camera, width, height)
        out = self._shade.detail.run(scene.finish, camera, target, None)
        rgba = np.frombuffer(out.texture.read(), dtype=np.float32).reshape(height, width, 4)
        return np.ascontiguousarray(rgba[::-1])

    def filter_depth_image(
        self,
        depth: npt.NDArray[np.float32],
        *,
        particle_radius: float,
        px_per_unit: float,
        quality: QualityConfig,
    ) -> npt.NDArray[np.float32]:
        """Run only the smoothing pass on an eye-depth image (rows top first, 0 = background),
        to compare the filters with a numpy reference on synthetic images."""
        self._gl.check_owner()
        height, width = depth.shape
        source = self._splat.targets((width, height)).depth
        source.write(image_bytes(depth))
        result = self._smooth.run(
            source, px_per_unit=px_per_unit, particle_radius=particle_radius, quality=quality
        )
        return read_image(result.read(), width, height)

    def blur_temperature_image(
        self,
        temperature: npt.NDArray[np.float32],
        depth: npt.NDArray[np.float32],
        *,
        particle_radius: float,
        px_per_unit: float,
    ) -> npt.NDArray[np.float32]:
        """Run only the temperature blur on a kelvin image guided by an eye-depth image (both
        rows top first, depth 0 = background), to compare it with a numpy reference."""
        self._gl.check_owner()
        height, width = depth.shape
        targets = self._splat.targets((width, height))
        kelvin, _ = targets.temperature_targets()
        kelvin.write(image_bytes(temperature))
        targets.depth.write(image_bytes(depth))
        result = self._temperature.run(kelvin, targets.depth, px_per_unit, particle_radius)
        return read_image(result.read(), width, height)

    def guide_crease_runs(
        self, codes: npt.NDArray[np.float32]
    ) -> dict[int, npt.NDArray[np.float32]]:
        """Run only the normal guide's crease-run pass (`SmoothPass.crease_runs`) on one image
        of limit codes (the guide's reduced size, guide_limits.frag.glsl's coding, rows as
        stored) given to both axes; returns each axis's kept codes, rows as stored."""
        self._gl.check_owner()
        height, width = codes.shape
        packed = np.zeros((height, (width + 3) // 4 * 4), np.float32)
        packed[:, :width] = codes
        textures = {
            axis: self._gl.ctx.texture((packed.shape[1] // 4, height), 4, dtype="f4")
            for axis in (0, 1)
        }
        try:
            for texture in textures.values():
                texture.filter = (moderngl.NEAREST, moderngl.NEAREST)
                texture.write(packed.tobytes())
            kept = self._smooth.crease_runs(textures, (width, height))
            return {
                axis: np.frombuffer(texture.read(), np.float32).reshape(height, -1)[:, :width]
                for axis, texture in kept.items()
            }
        finally:
            for texture in textures.values():
                texture.release()
