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


def read_region(
    fbo: moderngl.Framebuffer, size: tuple[int, int], box: ScreenBox | None
) -> npt.NDArray[np.float32]:
    """The RGBA float target of `fbo` as (H, W, 4), rows top first, reading only `box` (the
    rest is known to be zero) or everything (None)."""
    width, height = size
    if box is None:
        data = np.frombuffer(fbo.read(components=4, dtype="f4"), dtype=np.float32)
        return np.ascontiguousarray(data.reshape(height, width, 4)[::-1])
    x, y, w, h = box
    part = np.frombuffer(fbo.read(viewport=box, components=4, dtype="f4"), dtype=np.float32)
    out = np.zeros((height, width, 4), dtype=np.float32)
    out[height - y - h : height - y, x : x + w] = part.reshape(h, w, 4)[::-1]
    return out


def read_frame(
    color: Target,
    normal_depth: Target,
    *,
    want_depth: bool,
    want_normals: bool,
    color_box: ScreenBox | None,
    surface_box: ScreenBox | None,
) -> RenderedFrame:
    """Colour, and depth / normals when asked. `color_box` / `surface_box`: where those targets
    can be non-zero (None: anywhere)."""
    size = color.texture.size
    rgba = read_region(color.fbo, size, color_box)
    depth_out = normals_out = None
    if want_depth or want_normals:
        nd = read_region(normal_depth.fbo, size, surface_box)
        if want_depth:
            z = nd[:, :, 3]
            depth_out = np.where(z > 0.0, z, np.float32(np.inf)).astype(np.float32)
        if want_normals:
            normals_out = np.ascontiguousarray(nd[:, :, :3])
    return RenderedFrame(rgba=rgba, depth=depth_out, normals=normals_out)
