"""Read-back: the colour target always, the normal + depth target only when Z or N is asked for,
as the float arrays of a `RenderedFrame` (rows top first). Only the part of a target that can
be non-zero (the screen box) is read; the rest is known to be zero."""

from __future__ import annotations

import moderngl
import numpy as np
import numpy.typing as npt

from sphrender.server.engine.frame_output import RenderedFrame
from sphrender.server.engine.geometry.screen_box import ScreenBox
from sphrender.server.engine.gpu.draw import Target
from sphrender.server.engine.gpu.gl_clock import GLClock


def read_region(
    fbo: moderngl.Framebuffer, size: tuple[int, int], box: ScreenBox | None, clock: GLClock
) -> npt.NDArray[np.float32]:
    """The RGBA float target of `fbo` as (H, W, 4), rows top first. With a `box` only its rows
    are read and the others zeroed (the target is known to be zero there); None reads all.

    The driver writes straight into the returned array (GL rows are bottom first; the rows of a
    box are contiguous there) and the array handed back is its flipped view: the render thread
    copies nothing per pixel (an encoder that needs C order copies on its own thread). The
    zeroing is a memset of the rows outside the box only: `np.zeros` of the whole image is a
    1.6 ms memset at 1280x720 whenever glibc serves it from its heap rather than fresh pages."""
    width, height = size
    bottom_first = np.empty((height, width, 4), dtype=np.float32)
    if box is None:
        with clock:
            fbo.read_into(bottom_first, components=4, dtype="f4")
        return bottom_first[::-1]
    _, y, _, h = box
    bottom_first[:y] = 0.0
    bottom_first[y + h :] = 0.0
    with clock:
        fbo.read_into(bottom_first[y : y + h], viewport=(0, y, width, h), components=4, dtype="f4")
    return bottom_first[::-1]


def read_frame(
    color: Target,
    normal_depth: Target,
    *,
    want_depth: bool,
    want_normals: bool,
    color_box: ScreenBox | None,
    surface_box: ScreenBox | None,
    clock: GLClock,
) -> RenderedFrame:
    """Colour, and depth / normals when asked. `color_box` / `surface_box`: where those targets
    can be non-zero (None: anywhere)."""
    size = color.texture.size
    rgba = read_region(color.fbo, size, color_box, clock)
    depth_out = normals_out = None
    if want_depth or want_normals:
        nd = read_region(normal_depth.fbo, size, surface_box, clock)
        if want_depth:
            z = nd[:, :, 3]
            depth_out = np.where(z > 0.0, z, np.float32(np.inf)).astype(np.float32)
        if want_normals:
            normals_out = np.ascontiguousarray(nd[:, :, :3])
    return RenderedFrame(rgba=rgba, depth=depth_out, normals=normals_out)
