"""The read-back pass (passes/readback.py): the Z and N AOVs the driver writes straight into
the frame's arrays are exactly what the frame contract (frame_output.py) asks of the normal +
depth target: depth where w > 0, +inf elsewhere; normals the first three channels; rows top
first; rows outside the screen box filled with what the target holds there (0 -> +inf / 0).

Exact equality: the pass copies float32 values (a texel fetch and a store, no arithmetic), so
any difference is a bug, not rounding. The target holds random normals, depths up to 1e5,
holes, and a tiny (1e-30) and a huge (3e38) depth: the copy is bit-faithful."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import numpy.typing as npt
import pytest

from sphrender.server.engine.gpu.draw import FullscreenTriangle, Target, image_bytes
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.gpu.programs import ProgramCache
from sphrender.server.engine.passes.context import PassContext
from sphrender.server.engine.passes.readback import ReadbackPass

WIDTH, HEIGHT = 37, 23  # odd sizes: no row padding or power-of-two luck


@pytest.fixture(scope="module")
def context(gl_context: GLContext) -> Iterator[PassContext]:
    context = PassContext(gl_context, ProgramCache(gl_context), FullscreenTriangle(gl_context))
    yield context
    context.fullscreen.release()
    context.programs.release()


def normal_depth_image(rng: np.random.Generator, box_rows: slice) -> npt.NDArray[np.float32]:
    """(H, W, 4) top-first image: random unit normals and depths inside `box_rows` (top-first
    rows), a background hole pattern inside, zeros outside (as the passes leave it)."""
    image = np.zeros((HEIGHT, WIDTH, 4), np.float32)
    rows = image[box_rows]
    normals = rng.normal(size=(*rows.shape[:2], 3))
    rows[..., :3] = normals / np.linalg.norm(normals, axis=-1, keepdims=True)
    rows[..., 3] = rng.uniform(0.1, 1e5, size=rows.shape[:2])
    rows[::3, ::2] = 0.0  # no surface
    # Tiny and huge depths survive the copy (denormals need not: shaders may flush them, and the
    # near plane keeps depths far above them).
    rows[-1, 1, 3] = 1e-30
    rows[-1, 2, 3] = 3e38
    return image


def reference(image: npt.NDArray[np.float32]) -> tuple[np.ndarray, np.ndarray]:
    """The conversion the host used to do: depth where w > 0 else +inf, normals = xyz."""
    depth = np.where(image[..., 3] > 0.0, image[..., 3], np.float32(np.inf))
    return depth.astype(np.float32), image[..., :3].copy()


@pytest.mark.parametrize("box", [None, (5, 4, 20, 11), (0, 0, WIDTH, 1), (3, HEIGHT - 2, 1, 2)])
def test_aovs_equal_the_contracts_conversion(
    gl_context: GLContext, context: PassContext, box: tuple[int, int, int, int] | None
) -> None:
    rng = np.random.default_rng(7)
    # A box is in GL rows (bottom first); its top-first rows are the mirror.
    rows = slice(None) if box is None else slice(HEIGHT - box[1] - box[3], HEIGHT - box[1])
    image = normal_depth_image(rng, rows)
    color = Target.float(gl_context.ctx, (WIDTH, HEIGHT), 4)
    surface = Target.float(gl_context.ctx, (WIDTH, HEIGHT), 4)
    readback = ReadbackPass(context)
    try:
        surface.texture.write(image_bytes(image))
        color.texture.write(image_bytes(image[..., ::-1]))
        frame = readback.run(
            color,
            surface,
            want_depth=True,
            want_normals=True,
            color_box=box,
            surface_box=box,
        )
    finally:
        readback.release()
        surface.release()
        color.release()
    depth, normals = reference(image)
    assert frame.depth is not None and frame.normals is not None
    np.testing.assert_array_equal(frame.depth, depth)
    np.testing.assert_array_equal(frame.normals, normals)
    np.testing.assert_array_equal(frame.rgba, image[..., ::-1])


def test_only_what_is_asked_is_read(gl_context: GLContext, context: PassContext) -> None:
    color = Target.float(gl_context.ctx, (WIDTH, HEIGHT), 4)
    readback = ReadbackPass(context)
    try:
        only_depth = readback.run(
            color, color, want_depth=True, want_normals=False, color_box=None, surface_box=None
        )
        only_normals = readback.run(
            color, color, want_depth=False, want_normals=True, color_box=None, surface_box=None
        )
    finally:
        readback.release()
        color.release()
    assert only_depth.normals is None and only_normals.depth is None
    assert only_depth.depth is not None and np.isposinf(only_depth.depth).all()
