"""Temperature pass: the splatted kelvin image, blurred so the glow of hot metal is smooth.

The splat writes the front sphere's temperature per pixel (unsmoothed); this pass blurs it in
screen space, separably on packed images (four pixels per texel, as the depth filters), guided by
the smoothed depth: samples more than TEMPERATURE_DEPTH_RANGE_RADII particle radii away in depth
belong to another surface and are skipped. Sigma = TEMPERATURE_SIGMA_RADII projected radii.

Shader: `shaders/temperature/smooth_temperature.frag.glsl` (+ `common/image_pack`, `image_unpack`).
Owns: the packed depth guide, two packed kelvin images (ping-pong) and the unpacked result.
"""

from __future__ import annotations

import moderngl

from sphrender.server.engine.gpu.draw import PerSize, Target
from sphrender.server.engine.gpu.uniforms import set_group
from sphrender.server.engine.passes.context import FULLSCREEN_VERT, PassContext

SHADER = "temperature/smooth_temperature.frag.glsl"
_AXIS_DEFINES = ({"AXIS": 0}, {"AXIS": 1})
_BLUR_UNITS = {"u_packed_temperature": 0, "u_packed_depth": 1}  # the blur's texture units
PACK_SHADER = "common/image_pack.frag.glsl"
UNPACK_SHADER = "common/image_unpack.frag.glsl"
#: Temperature blur: sigma in projected particle radii, kernel cap, and the depth window (in
#: particle radii) outside which samples belong to another surface.
TEMPERATURE_SIGMA_RADII = 2.0
TEMPERATURE_MAX_REACH_PX = 24
TEMPERATURE_DEPTH_RANGE_RADII = 4.0


class _BlurTargets:
    def __init__(self, ctx: moderngl.Context, size: tuple[int, int]) -> None:
        self.size = size
        packed_size = ((size[0] + 3) // 4, size[1])
        self.packed_depth = Target.float(ctx, packed_size, 4, clamp=False)
        self.packed = [Target.float(ctx, packed_size, 4, clamp=False) for _ in range(2)]
        self.result = Target.float(ctx, size, 1, clamp=False)

    def release(self) -> None:
        for target in (self.packed_depth, *self.packed, self.result):
            target.release()


class TemperaturePass:
    def __init__(self, context: PassContext) -> None:
        self._context = context
        self._targets = PerSize(lambda size: _BlurTargets(context.gl.ctx, size))

    def run(
        self,
        temperature: moderngl.Texture,
        depth: moderngl.Texture,
        px_per_unit: float,
        particle_radius: float,
    ) -> moderngl.Texture:
        """Blur the kelvin image `temperature` guided by the eye depth `depth`: pack both, blur
        along x then y, unpack. `px_per_unit`: pixels per scene unit at eye depth 1
        (`Camera.pixels_per_unit_at_unit_depth`)."""
        blur = self._targets.get(temperature.size)
        programs, draw = self._context.programs, self._context.fullscreen.draw
        pack = programs.get(FULLSCREEN_VERT, PACK_SHADER, samplers={"u_image": 0})
        for source, target in ((depth, blur.packed_depth), (temperature, blur.packed[0])):
            source.use(0)
            target.fbo.use()
            draw(pack)
        blur.packed_depth.texture.use(1)
        for axis in (0, 1):
            program = programs.get(FULLSCREEN_VERT, SHADER, _AXIS_DEFINES[axis], _BLUR_UNITS)
            set_group(
                program,
                "frame",
                (particle_radius, px_per_unit),
                lambda: {
                    "u_radius_px_at_unit_depth": particle_radius * px_per_unit,
                    "u_sigma_radii": TEMPERATURE_SIGMA_RADII,
                    "u_max_reach_px": TEMPERATURE_MAX_REACH_PX,
                    "u_depth_range": TEMPERATURE_DEPTH_RANGE_RADII * particle_radius,
                },
            )
            blur.packed[axis].texture.use(0)
            blur.packed[1 - axis].fbo.use()
            draw(program)
        unpack = programs.get(FULLSCREEN_VERT, UNPACK_SHADER, samplers={"u_packed": 0})
        blur.packed[0].texture.use(0)
        blur.result.fbo.use()
        draw(unpack)
        return blur.result.texture

    def release(self) -> None:
        self._targets.release()
