"""The splat's storage buffers: each particle uploaded once, pulled by the vertex stage.

The vertex shaders (`shaders/common/splat_particles.glsl`) read quad q's particle from these
buffers by `gl_VertexID`, so nothing is copied per quad corner on the CPU. Two ways fill them:

* host prepare (`geometry/prepare.py`): the CPU has culled the particles and rotated them to view
  space; `upload_prepared` writes the (N, 4) spheres, and the subsets the occlusion culling draws
  go in as id lists (`write_ids`);
* device prepare (`passes/device_prepare.py`): `upload_frame` writes the client's arrays as they
  are (float64 positions, float32 radii, temperatures, axes, the droplet mask's bytes) and a
  compute shader writes the spheres in place.

Binding points (the shaders' `binding = k`): 0 spheres, 1 ids, 2 temperatures, 3 axes,
4 positions, 5 radii, 6 droplet mask, 7 the device prepare's summary; the device occlusion
culling's 8 per-particle flags, 9 tile minima, 10 max-depth pyramid, 11 drawn counts; 25 peak
temperatures (12-24 are the field normals'). Buffers grow
geometrically (`orphan`, so the vertex arrays stay valid) and are never shrunk: a steady stream
of frames allocates nothing.

Owns: every buffer above and the quad index buffer; released by `SplatPass.release`.
"""

from __future__ import annotations

import moderngl
import numpy as np
import numpy.typing as npt

from sphrender.server.engine.gpu.gl_context import GLContext

SPHERES, IDS, TEMPERATURES, AXES, POSITIONS, RADII, DROPLETS, SUMMARY = range(8)
FLAGS, TILES, PYRAMID, COUNTS = range(8, 12)
PEAKS = 25
#: Bytes per particle of each per-particle buffer.
STRIDE = {
    SPHERES: 16, IDS: 4, TEMPERATURES: 4, AXES: 36, POSITIONS: 24, RADII: 4, DROPLETS: 1,
    FLAGS: 4, TILES: 4, PYRAMID: 4, PEAKS: 4,
}  # fmt: skip
SUMMARY_BYTES = 48
COUNTS_BYTES = 16


class SplatBuffers:
    def __init__(self, gl: GLContext) -> None:
        self._gl = gl
        ctx = gl.ctx
        self._clock = gl.clock
        self._buffers = {binding: ctx.buffer(reserve=64 * 1024) for binding in STRIDE}
        self._buffers[SUMMARY] = ctx.buffer(reserve=SUMMARY_BYTES)
        self._buffers[COUNTS] = ctx.buffer(reserve=COUNTS_BYTES)
        # Two triangles per quad: 4q + (0, 1, 2, 2, 1, 3); grows with the largest frame.
        self.index_buffer = ctx.buffer(reserve=4)
        self._quad_capacity = 0

    def buffer(self, binding: int) -> moderngl.Buffer:
        return self._buffers[binding]

    def bind(self) -> None:
        """Bind every buffer to its binding point, unless they still are: storage bindings are
        context state shared with other passes (GLContext.claim_storage_bindings), so the
        splat's draws and dispatches call this before they run."""
        if self._gl.claim_storage_bindings(self):
            for binding, buffer in self._buffers.items():
                buffer.bind_to_storage_buffer(binding)

    def ensure_quads(self, count: int) -> None:
        """An index buffer holding at least `count` quads."""
        if count <= self._quad_capacity:
            return
        capacity = max(count, 2 * self._quad_capacity, 1024)
        first = np.arange(capacity, dtype=np.uint32)[:, None] * 4
        indices = first + np.array([0, 1, 2, 2, 1, 3], dtype=np.uint32)
        self.index_buffer.orphan(indices.nbytes)
        self.index_buffer.write(indices)
        self._quad_capacity = capacity

    def write(self, binding: int, data: npt.NDArray[np.generic], offset_items: int = 0) -> None:
        """Write `data` (C-contiguous, its bytes as the shader reads them) at particle
        `offset_items` of buffer `binding`, growing it first when needed."""
        stride = STRIDE[binding]
        data = np.ascontiguousarray(data)
        self.reserve(binding, offset_items + data.nbytes // stride + 1)
        if data.nbytes:
            with self._clock:
                self._buffers[binding].write(data, offset=offset_items * stride)

    def reserve(self, binding: int, items: int) -> None:
        """Room for `items` particles in buffer `binding` (the contents are lost on growth)."""
        buffer = self._buffers[binding]
        nbytes = -(-items * STRIDE[binding] // 16) * 16  # whole vec4s: std430 reads past odd ends
        if nbytes > buffer.size:
            buffer.orphan(max(nbytes, buffer.size * 2))
            # A storage binding is a range of the size the buffer had when it was bound: a grown
            # buffer read through the old binding reads zeros past the old end.
            buffer.bind_to_storage_buffer(binding)
            self._gl.storage_bindings_disturbed(self)

    def release(self) -> None:
        self._gl.release_storage_claim(self)
        for buffer in self._buffers.values():
            buffer.release()
        self.index_buffer.release()
