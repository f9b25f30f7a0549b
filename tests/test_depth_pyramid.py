"""The device culling's max-depth pyramid (`shaders/splat/depth_pyramid.comp.glsl`, one dispatch
for every level) against a numpy reference.

Level 0 is the depth inside the box with the background (0) as +inf; level k + 1 is the largest
of each 2 x 2 block of level k, the blocks at an odd edge taking what exists. Only copies and
maxima of float32 values are involved, so the comparison is exact. The sizes cross the 64 x 64
block of one work group (partial groups at both edges, odd sides at every level), reach the
7-level cap, and stop early for boxes smaller than 64 pixels.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import numpy.typing as npt
import pytest

from sphrender.server.engine.gpu.draw import FullscreenTriangle, float_texture
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.gpu.programs import ProgramCache
from sphrender.server.engine.passes.context import PassContext
from sphrender.server.engine.passes.device_culling import LEVELS, DeviceCulling, levels
from sphrender.server.engine.passes.splat_buffers import PYRAMID, SplatBuffers

F32 = npt.NDArray[np.float32]


@pytest.fixture(scope="module")
def culling(gl_context: GLContext) -> Iterator[tuple[DeviceCulling, SplatBuffers]]:
    context = PassContext(gl_context, ProgramCache(gl_context), FullscreenTriangle(gl_context))
    buffers = SplatBuffers(gl_context)
    yield DeviceCulling(context, buffers, 0), buffers
    buffers.release()
    context.programs.release()


def reference(depth: F32, origin: tuple[int, int], size: tuple[int, int]) -> list[F32]:
    """Each level as a (height, width) array; `depth` rows are GL rows (bottom first)."""
    (x, y), (w, h) = origin, size
    level = depth[y : y + h, x : x + w].copy()
    level[level <= 0.0] = np.inf
    out = [level]
    while len(out) < LEVELS and max(out[-1].shape) > 1:
        prev = out[-1]
        ph, pw = prev.shape
        padded = np.full((ph + ph % 2, pw + pw % 2), -np.inf, np.float32)
        padded[:ph, :pw] = prev
        out.append(padded.reshape(padded.shape[0] // 2, 2, padded.shape[1] // 2, 2).max((1, 3)))
    return out


@pytest.mark.parametrize(
    ("texture_size", "origin", "box"),
    [
        ((220, 150), (5, 7), (200, 130)),  # 4 x 3 groups, partial ones, odd sides
        ((300, 200), (0, 0), (300, 200)),  # whole image, all 7 levels
        ((64, 64), (0, 0), (64, 64)),  # exactly one group
        ((80, 40), (3, 2), (65, 1)),  # a single row across two groups
        ((16, 16), (4, 5), (3, 3)),  # stops after 3 levels
        ((8, 8), (2, 2), (1, 1)),  # one pixel, one level
    ],
)
def test_every_level_equals_the_numpy_reference(
    gl_context: GLContext,
    culling: tuple[DeviceCulling, SplatBuffers],
    texture_size: tuple[int, int],
    origin: tuple[int, int],
    box: tuple[int, int],
) -> None:
    cull, buffers = culling
    rng = np.random.default_rng(sum(texture_size) + box[0])
    width, height = texture_size
    depth = rng.uniform(0.5, 4.0, (height, width)).astype(np.float32)
    depth[rng.random((height, width)) < 0.3] = 0.0  # background holes
    depth[:, :2] = 0.0  # and whole background columns
    texture = float_texture(gl_context.ctx, texture_size, 1)
    try:
        texture.write(depth.tobytes())  # rows as given: GL row 0 first
        dims, offsets = levels(*box)
        total = offsets[-1] + dims[-1][0] * dims[-1][1]
        buffers.reserve(PYRAMID, total + 64)
        # Poison what the dispatch must overwrite, and one value past its end.
        buffers.buffer(PYRAMID).write(np.full(total + 1, -7.0, np.float32).tobytes())
        cull.build_pyramid(texture, origin, dims, offsets)
        data = np.frombuffer(buffers.buffer(PYRAMID).read(), np.float32)
    finally:
        texture.release()
    expected = reference(depth, origin, box)
    assert [(lv.shape[1], lv.shape[0]) for lv in expected] == list(dims)
    for k, (level, offset) in enumerate(zip(expected, offsets, strict=True)):
        got = data[offset : offset + level.size].reshape(level.shape)
        np.testing.assert_array_equal(got, level, err_msg=f"level {k}")
    assert data[total] == -7.0, "wrote past the last level"
