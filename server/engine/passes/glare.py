"""Glare pass: the light of very bright pixels spread through the eye's point-spread function,
on the shaded colour before the read-back (so the display codes, PNG, JPEG and, when the scene
asks, EXR colour carry it; Z and N never do).

Each pixel's premultiplied radiance above the exposed threshold (`[glare] threshold` /
2^exposure, by luminance) is the light spread; what is below stays. The spread light goes
through a pyramid (`glare_psf.py`: 2x2 means, a 7-tap Gaussian per level, weighted bilinear
sum) whose weights are fitted to Spencer et al.'s 1995 photopic PSF at the camera's degrees per
pixel; the weights sum to 1, so the light is conserved but for what the halo carries past the
frame's edge. NaN becomes 0 and radiance past 1e30 is clipped there, so no sum overflows.

Owns: its programs (through the ProgramCache) and the pyramid's targets per image size.
"""

from __future__ import annotations

import moderngl
import numpy as np

from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.gpu.draw import PerSize, Target
from sphrender.server.engine.gpu.uniforms import set_if_used, write_array
from sphrender.server.engine.passes.context import FULLSCREEN_VERT, PassContext
from sphrender.server.engine.passes.glare_psf import (
    MAX_LEVELS,
    blur_weights,
    degrees_per_pixel,
    fit_pyramid,
    level_count,
)
from sphrender.server.scene.schema_post import GlareConfig

EXCESS_SHADER = "glare/glare_excess.frag.glsl"
DOWN_SHADER = "glare/glare_down.frag.glsl"
BLUR_SHADER = "glare/glare_blur.frag.glsl"
COMPOSE_SHADER = "glare/glare_compose.frag.glsl"


class _Pyramid:
    """Per image size: each level's mean and blurred targets, a blur scratch per level, the
    glared colour."""

    def __init__(self, ctx: moderngl.Context, size: tuple[int, int]) -> None:
        width, height = size
        self.means: list[Target] = []
        self.scratch: list[Target] = []
        self.blurred: list[Target] = []
        for level in range(MAX_LEVELS):
            step = 2**level
            level_size = (max(-(-width // step), 1), max(-(-height // step), 1))
            self.means.append(Target.float(ctx, level_size, 4))
            self.scratch.append(Target.float(ctx, level_size, 4))
            self.blurred.append(Target.float(ctx, level_size, 4))
        self.color = Target.float(ctx, size, 4)

    def release(self) -> None:
        for target in (*self.means, *self.scratch, *self.blurred, self.color):
            target.release()


class GlarePass:
    def __init__(self, context: PassContext) -> None:
        self._context = context
        self._pyramids = PerSize(lambda size: _Pyramid(context.gl.ctx, size))

    def run(self, color: Target, camera: Camera, glare: GlareConfig, exposure: float) -> Target:
        """The glared straight RGBA of `color` (its own target, valid until the next run)."""
        width, height = color.texture.size
        pyramid = self._pyramids.get((width, height))
        deg_per_px = degrees_per_pixel(camera.fov_y_deg, height)
        levels = level_count(deg_per_px, width, height)
        fit = fit_pyramid(round(deg_per_px, 9), levels)
        scale = float(np.exp2(np.float64(exposure)))
        threshold = float(np.float32(glare.threshold / scale)) if np.isfinite(scale) else 0.0
        programs = self._context.programs
        excess = programs.get(FULLSCREEN_VERT, EXCESS_SHADER, samplers={"u_color": 0})
        set_if_used(excess, "u_threshold", threshold)
        color.texture.use(0)
        self._draw(excess, pyramid.means[0])
        down = programs.get(FULLSCREEN_VERT, DOWN_SHADER, samplers={"u_source": 0})
        for level in range(1, levels):
            pyramid.means[level - 1].texture.use(0)
            self._draw(down, pyramid.means[level])
        blur = programs.get(FULLSCREEN_VERT, BLUR_SHADER, samplers={"u_source": 0})
        write_array(blur, "u_taps", tuple(blur_weights()), np.float32)
        for level in range(levels):
            for source, target, direction in (
                (pyramid.means[level], pyramid.scratch[level], (1, 0)),
                (pyramid.scratch[level], pyramid.blurred[level], (0, 1)),
            ):
                set_if_used(blur, "u_direction", direction)
                source.texture.use(0)
                self._draw(blur, target)
        samplers = {"u_color": 0, **{f"u_level{i}": i + 1 for i in range(MAX_LEVELS)}}
        compose = programs.get(FULLSCREEN_VERT, COMPOSE_SHADER, {"LEVELS": levels}, samplers)
        set_if_used(compose, "u_threshold", threshold)
        set_if_used(compose, "u_centre", fit.centre)
        set_if_used(compose, "u_scale", float(np.float32(min(scale, 3e38))))
        write_array(compose, "u_weights", fit.weights, np.float32)
        color.texture.use(0)
        for level in range(levels):
            pyramid.blurred[level].texture.use(level + 1)
        self._draw(compose, pyramid.color)
        return pyramid.color

    def _draw(self, program: moderngl.Program, target: Target) -> None:
        target.fbo.use()
        self._context.fullscreen.draw(program)

    def release(self) -> None:
        self._pyramids.release()
