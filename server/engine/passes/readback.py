"""Read-back: the colour target always, the Z and N AOVs only when asked for, as the float arrays
of a `RenderedFrame` (rows top first). Only the part of a target that can be non-zero (the
screen box) is read; the rest is known and filled on the host.

The host does no per-pixel work on what it reads: the driver writes straight into the arrays
handed back (their flipped views, GL rows being bottom first), in the frame contract's formats.
N is read as the normal + depth target's first three channels (the driver drops the fourth); Z
needs +inf where there is no surface, where the target keeps 0, so a one-channel copy is drawn
first (`shaders/readback/depth_aov.frag.glsl`). Doing those conversions in numpy cost the render
thread 17 ms a frame at 1280x720 and 44 ms at 1920x1080 on this VM (a `where`, a cast and a
strided copy of 4-10 MB each): on a GPU server, ten times the rest of its host work.

Owns: the one-channel depth target per image size; released with the renderer.
"""

from __future__ import annotations

import moderngl
import numpy as np
import numpy.typing as npt

from sphrender.server.engine.frame_output import RenderedFrame
from sphrender.server.engine.geometry.screen_box import ScreenBox
from sphrender.server.engine.gpu.draw import PerSize, Target, set_scissor
from sphrender.server.engine.gpu.gl_clock import GLClock
from sphrender.server.engine.passes.context import FULLSCREEN_VERT, PassContext

DEPTH_SHADER = "readback/depth_aov.frag.glsl"


def read_region(
    fbo: moderngl.Framebuffer,
    size: tuple[int, int],
    box: ScreenBox | None,
    clock: GLClock,
    *,
    components: int = 4,
    fill: float = 0.0,
) -> npt.NDArray[np.float32]:
    """The first `components` float channels of `fbo`'s target as (H, W, components), or (H, W)
    for one, rows top first. With a `box` only its rows are read and the others set to `fill`
    (what the target holds there); None reads all.

    The driver writes straight into the returned array (GL rows are bottom first; the rows of a
    box are contiguous there) and the array handed back is its flipped view: the render thread
    copies nothing per pixel (an encoder that needs C order copies on its own thread). The
    filling is a memset of the rows outside the box only: `np.zeros` of the whole image is a
    1.6 ms memset at 1280x720 whenever glibc serves it from its heap rather than fresh pages."""
    width, height = size
    shape = (height, width) if components == 1 else (height, width, components)
    bottom_first = np.empty(shape, dtype=np.float32)
    if box is None:
        with clock:
            fbo.read_into(bottom_first, components=components, dtype="f4")
        return bottom_first[::-1]
    _, y, _, h = box
    bottom_first[:y] = fill
    bottom_first[y + h :] = fill
    with clock:
        fbo.read_into(
            bottom_first[y : y + h], viewport=(0, y, width, h), components=components, dtype="f4"
        )
    return bottom_first[::-1]


class ReadbackPass:
    def __init__(self, context: PassContext) -> None:
        self._context = context
        self._depth = PerSize(lambda size: Target.float(context.gl.ctx, size, 1))

    def run(
        self,
        color: Target,
        normal_depth: Target,
        *,
        want_depth: bool,
        want_normals: bool,
        color_box: ScreenBox | None,
        surface_box: ScreenBox | None,
    ) -> RenderedFrame:
        """Colour, and depth / normals when asked. `color_box` / `surface_box`: where those
        targets can be non-zero (None: anywhere)."""
        clock = self._context.gl.clock
        size = color.texture.size
        rgba = read_region(color.fbo, size, color_box, clock)
        depth = normals = None
        if want_depth:
            target = self._depth_aov(normal_depth.texture, surface_box)
            depth = read_region(target.fbo, size, surface_box, clock, components=1, fill=np.inf)
        if want_normals:
            normals = read_region(normal_depth.fbo, size, surface_box, clock, components=3)
        return RenderedFrame(rgba=rgba, depth=depth, normals=normals)

    def _depth_aov(self, normal_depth: moderngl.Texture, box: ScreenBox | None) -> Target:
        """The Z AOV (+inf where no surface) of `normal_depth` in the rows the read-back reads
        (all, or the box's full rows)."""
        width, height = normal_depth.size
        target = self._depth.get((width, height))
        program = self._context.programs.get(
            FULLSCREEN_VERT, DEPTH_SHADER, samplers={"u_normal_depth": 0}
        )
        normal_depth.use(0)
        target.fbo.use()
        set_scissor(target.fbo, None if box is None else (0, box[1], width, box[3]))
        self._context.fullscreen.draw(program)
        set_scissor(target.fbo, None)
        return target

    def release(self) -> None:
        self._depth.release()
