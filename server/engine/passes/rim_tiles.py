"""Rim tiles: the farthest and the nearest eye depth within +-8 pixels, per 4 x 4 pixels.

The silhouette pass (`silhouette.py`) and the field normals pass (`field_normals.py`) look for a
rim (background or a depth step) within a few pixels of each surface pixel; most pixels have
none, and these tiles let them skip the search. Built once per frame by `NormalsPass` when
either pass runs, from the eye-depth image the normals are differenced from (neither pass
changes the depth).

Shader: `shaders/silhouette/rim_tiles.frag.glsl` (the extremes per tile, then dilated along x
and along y). Owns: three RG32F tile targets per image size (a quarter of the image per side).
"""

from __future__ import annotations

import moderngl

from sphrender.server.engine.gpu.draw import PerSize, Target
from sphrender.server.engine.passes.context import FULLSCREEN_VERT, PassContext

SHADER = "silhouette/rim_tiles.frag.glsl"
#: The steps' defines: extremes per tile, then their dilation along x and along y.
_STEPS = tuple({"RIM_DILATE": int(step > 0), "AXIS": max(step - 1, 0)} for step in range(3))


class _Tiles:
    def __init__(self, ctx: moderngl.Context, size: tuple[int, int]) -> None:
        tiles = ((size[0] + 3) // 4, (size[1] + 3) // 4)
        self.steps = [Target.float(ctx, tiles, 2) for _ in range(3)]

    def release(self) -> None:
        for target in self.steps:
            target.release()


class RimTiles:
    def __init__(self, context: PassContext) -> None:
        self._context = context
        self._targets = PerSize(lambda size: _Tiles(context.gl.ctx, size))

    def build(self, depth: moderngl.Texture) -> moderngl.Texture:
        """The tiles of the eye-depth image `depth` (R32F, 0 = no surface): R = the farthest
        depth within +-8 pixels of the tile (background 3e38), G = the nearest (3e38 without
        surface). The same extremes of each tile's own 4 x 4 pixels: `extremes` after it."""
        steps = self._targets.get(depth.size).steps
        programs, draw = self._context.programs, self._context.fullscreen.draw
        sources = (depth, steps[0].texture, steps[1].texture)
        for step, source in enumerate(sources):
            program = programs.get(FULLSCREEN_VERT, SHADER, _STEPS[step], {"u_depth": 0})
            source.use(0)
            steps[step].fbo.use()
            draw(program)
        return steps[2].texture

    def extremes(self, size: tuple[int, int]) -> moderngl.Texture:
        """The farthest and the nearest depth of each tile's own 4 x 4 pixels (same encoding),
        as the last `build` of an image of `size` left them."""
        return self._targets.get(size).steps[0].texture

    def release(self) -> None:
        self._targets.release()
