"""Temperature pass: the splatted kelvin image, blurred so the glow of hot metal is smooth.

The splat writes the front sphere's temperature per pixel (unsmoothed); this pass blurs it in
screen space, separably on packed images (four pixels per texel, as the depth filters), guided by
the smoothed depth: samples more than TEMPERATURE_DEPTH_RANGE_RADII particle radii away in depth
belong to another surface and are skipped. Sigma = TEMPERATURE_SIGMA_RADII projected radii.
Within TEMPERATURE_MAX_REACH_PX of the image's ends a variant (IMAGE_BORDER) fits a line where
taps fell past the end, so a gradient running out of the image keeps its value at the edge.

Shader: `shaders/temperature/smooth_temperature.frag.glsl` (+ `common/image_pack`, `image_unpack`).
Owns: the packed depth guide, two packed kelvin images (ping-pong) and the unpacked result.
"""

from __future__ import annotations

import moderngl

from sphrender.server.engine.geometry.screen_box import ScreenBox, packed_border_split
from sphrender.server.engine.gpu.draw import PerSize, Target, set_scissor
from sphrender.server.engine.gpu.uniforms import set_group, set_if_used
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
    def __init__(self, context: PassContext, channel: int = 0) -> None:
        """`channel`: which channel of the kelvin image this instance blurs (1: the peak kelvin
        of an RG32F image; a second instance, so each owns its result)."""
        self._context = context
        self._pack_defines = {"CHANNEL": channel} if channel else None
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
        channel = programs.get(FULLSCREEN_VERT, PACK_SHADER, self._pack_defines, {"u_image": 0})
        for source, target, program in (
            (depth, blur.packed_depth, pack),
            (temperature, blur.packed[0], channel),
        ):
            source.use(0)
            target.fbo.use()
            draw(program)
        blur.packed_depth.texture.use(1)
        for axis in (0, 1):
            blur.packed[axis].texture.use(0)
            fbo = blur.packed[1 - axis].fbo
            for border, box in self._parts(temperature.size, axis):
                program = self._program(
                    axis, border, temperature.size, particle_radius, px_per_unit
                )
                set_scissor(fbo, box)
                fbo.use()
                draw(program)
            set_scissor(fbo, None)
        unpack = programs.get(FULLSCREEN_VERT, UNPACK_SHADER, samplers={"u_packed": 0})
        blur.packed[0].texture.use(0)
        blur.result.fbo.use()
        draw(unpack)
        return blur.result.texture

    @staticmethod
    def _parts(size: tuple[int, int], axis: int) -> list[tuple[int, ScreenBox]]:
        """The packed texels of one pass: (0, the inside) and (1, each strip within the
        kernel cap of the image's ends along `axis`), where taps may fall past the image."""
        inside, strips = packed_border_split(size, axis, TEMPERATURE_MAX_REACH_PX)
        return ([(0, inside)] if inside is not None else []) + [(1, strip) for strip in strips]

    def _program(
        self, axis: int, border: int, size: tuple[int, int], radius: float, px_per_unit: float
    ) -> moderngl.Program:
        defines = {**_AXIS_DEFINES[axis], "IMAGE_BORDER": border}
        program = self._context.programs.get(FULLSCREEN_VERT, SHADER, defines, _BLUR_UNITS)
        set_group(
            program,
            "frame",
            (radius, px_per_unit),
            lambda: {
                "u_radius_px_at_unit_depth": radius * px_per_unit,
                "u_sigma_radii": TEMPERATURE_SIGMA_RADII,
                "u_max_reach_px": TEMPERATURE_MAX_REACH_PX,
                "u_depth_range": TEMPERATURE_DEPTH_RANGE_RADII * radius,
            },
        )
        set_if_used(program, "u_image_size_px", size)
        return program

    def release(self) -> None:
        self._targets.release()
