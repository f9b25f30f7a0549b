"""Field grid: the frame's particle centres, counting-sorted into a hashed uniform grid on the
device, so a shader finds the particles within the SPH support h of any point (the field
normals pass, `field_normals.py`).

With `RimCulling` (the field normals' use) the count phase leaves out every particle whose
support's screen rectangle holds no 16-px rim block with a listed pixel (common/rim_blocks.glsl;
phase 0 dilates the blocks by two, so a rectangle of up to five blocks takes one lookup): they
add nothing to any listed pixel's gradient. On the 100k ball at 1280x720, 24k of 102k stay.

Where the centres come from (`FieldParticles`): with the host prepare, the CPU's view-space
arrays of the bulk and of the exact droplets (the droplets' upload replaced the bulk's in the
splat's buffers, so the splat's buffer no longer holds both), uploaded here; with the device
prepare, the splat's own spheres buffer, which holds every particle (culled ones with radius 0,
left out). Only the centres are used: the field is phi(x) = sum_j W(|x - x_j|, h) with equal
weights (on the dam break, per-particle volumes m / rho_j scored no better: 10.9 vs 10.3 deg).
A bucket holds at most SLOTS sorted entries: a crowded one (coincident or clustered particles)
is merged into weighted slots, one per sub-cell (field_grid.comp.glsl's phase 8), so a reader's
work per pixel is bounded whatever the geometry; uncrowded centres weigh 1, the same sums.

The sort (`shaders/field/field_grid.comp.glsl`, layout in `shaders/common/field_grid.glsl`):
count each centre's rank in its bucket (atomics) and list the kept ones, prefix-sum the counts
(chunk sums, one serial scan of the chunks, chunk scans: the SPH engine's scheme), scatter the
kept ones' indices (an indirect dispatch over the list, whose size the serial scan turns into
its arguments: the CPU never reads it), then place each kept centre within its bucket by its
index, so that every run sums the same centres in the same order (bit-identical normals).
Cells have side h / 2 and the hash is linear in x, so a reader scans each row of cells along x
that its support sphere crosses as one contiguous run of sorted centres (half the volume of
the 27 cells of side h around a point).
Table size: the power of two >= N, at least MIN_BUCKETS (the hash's constants keep the rows of
one reader's window in distinct buckets for every such table; common/field_grid.glsl). A cell
holds ~2 centres inside a fluid (spacing 2 r, cell side 2.5 r by default); cells far apart
that share a bucket only cost time: a reader's distance test drops their centres. The table is
zeroed with a buffer clear (a dispatch over it cost ~3 ms at 262k buckets on llvmpipe).
Bindings 12-16, 20 and 23 (common/field_grid.glsl; the kept list's count, the scatter's order);
nothing else uses them, so they are bound per build.
Faster layouts tried on llvmpipe and not kept (ARCHITECTURE.md, "field normals' speed"): a
texture instead of the buffer, tiles in shared memory (benchmarks/bench_field_gradient.py).

Owns: the source (host prepare), kept-list, kept-count, order, bucket, raw-count, chunk-sum
and sorted-centre buffers; grown
geometrically, never shrunk; released by `release`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import moderngl
import numpy as np
import numpy.typing as npt

from sphrender.server.engine.gpu.dispatch import dispatch_1d
from sphrender.server.engine.gpu.uniforms import set_if_used
from sphrender.server.engine.passes.context import PassContext

SHADER = "field/field_grid.comp.glsl"
GROUP_SIZE = 256  # local_size_x of the shader
SOURCE, KEPT, BUCKETS, SUMS, SORTED = range(12, 17)
#: The kept particles' count + the scatter's indirect dispatch arguments; the scatter's source
#: indices per bucket (shaders/field/field_grid.comp.glsl's phases 5 and 6).
KEPT_COUNT, ORDER = 20, 23
#: The buckets' uncapped counts, then their starts in `order` (phases 7, 5 and 6).
RAW = 24
#: At most this many sorted entries per bucket (FIELD_SLOTS of common/field_grid.glsl).
SLOTS = 64
#: Work groups per row of the scatter's indirect dispatch (GL 4.3 promises 65535 per axis).
SCATTER_GROUPS_X = 4096
#: The rim blocks' binding and side in pixels (common/rim_blocks.glsl).
RIM_BLOCKS, RIM_BLOCK = 19, 16
#: Chunks of the prefix sum (the serial scan over them runs in one invocation).
SCAN_CHUNKS = 1024
#: The smallest table (FIELD_MIN_BUCKETS of common/field_grid.glsl; a power of two).
MIN_BUCKETS = 1024
DILATE_BLOCKS, COUNT, CHUNK_SUMS, SCAN_SUMS, CHUNK_SCAN, SCATTER, PLACE, CAP, CROWD = range(9)


@dataclass(frozen=True)
class FieldParticles:
    """The centres the grid sorts: host arrays ((N, 4) float32, view space, w = radius) or the
    first `count` entries of a device buffer of that layout."""

    arrays: tuple[npt.NDArray[np.float32], ...] = ()
    buffer: moderngl.Buffer | None = None
    count: int = 0

    @property
    def total(self) -> int:
        return self.count if self.buffer is not None else sum(len(a) for a in self.arrays)


@dataclass(frozen=True)
class RimCulling:
    """Sort only the particles whose support reaches a flagged rim block (the storage buffer
    at binding 19, common/rim_blocks.glsl) of an image of `size` seen through `tan_half_fov`."""

    blocks: moderngl.Buffer
    size: tuple[int, int]
    tan_half_fov: tuple[float, float]


@dataclass(frozen=True)
class BuiltGrid:
    """What a reader sets: the support and the table mask (common/field_grid.glsl)."""

    support: float
    bucket_mask: int


def rim_blocks(size: tuple[int, int]) -> tuple[int, int]:
    """Rim blocks per row and per column of an image of `size`."""
    return (-(-size[0] // RIM_BLOCK), -(-size[1] // RIM_BLOCK))


def table_size(count: int) -> int:
    return max(MIN_BUCKETS, 1 << math.ceil(math.log2(max(count, 1))))


class FieldGrid:
    def __init__(self, context: PassContext) -> None:
        self._context = context
        ctx = context.gl.ctx
        bindings = (*range(SOURCE, SORTED + 1), KEPT_COUNT, ORDER, RAW)
        self._buffers = {binding: ctx.buffer(reserve=64) for binding in bindings}

    def _reserve(self, binding: int, nbytes: int) -> moderngl.Buffer:
        buffer = self._buffers[binding]
        nbytes = max(-(-nbytes // 16) * 16, 16)
        if nbytes > buffer.size:
            buffer.orphan(max(nbytes, buffer.size * 2))
        return buffer

    def build(
        self, particles: FieldParticles, support: float, cull: RimCulling | None = None
    ) -> BuiltGrid:
        """Sort `particles` into the grid of SPH support `support` (view-space units; cells of
        half that side); with `cull`, only those that can reach a flagged rim block."""
        n = particles.total
        buckets = table_size(n)
        chunk = max(32, -(-buckets // SCAN_CHUNKS))
        chunks = -(-buckets // chunk)
        clock = self._context.gl.clock
        source = particles.buffer
        if source is None:
            source = self._reserve(SOURCE, 16 * n)
            offset = 0
            with clock:
                for array in particles.arrays:
                    if len(array):
                        source.write(np.ascontiguousarray(array), offset=offset)
                    offset += array.nbytes
        self._reserve(KEPT, 8 * n)
        table = self._reserve(BUCKETS, 4 * (buckets + 1))
        raw = self._reserve(RAW, 4 * (buckets + 1))
        self._reserve(SUMS, 4 * (chunks + 1))
        self._reserve(SORTED, 16 * n)
        self._reserve(ORDER, 4 * n)
        with clock:
            source.bind_to_storage_buffer(SOURCE)
            for binding in (*range(KEPT, SORTED + 1), KEPT_COUNT, ORDER, RAW):
                self._buffers[binding].bind_to_storage_buffer(binding)
        shader = self._context.programs.compute(SHADER)
        set_if_used(shader, "u_support", float(support))
        set_if_used(shader, "u_bucket_mask", buckets - 1)
        set_if_used(shader, "u_buckets", buckets)
        set_if_used(shader, "u_chunk", chunk)
        set_if_used(shader, "u_cull", cull is not None)
        set_if_used(shader, "u_groups_x", SCATTER_GROUPS_X)
        if cull is not None:
            width, height = cull.size
            set_if_used(shader, "u_image", (width, height))
            set_if_used(shader, "u_rim_blocks", rim_blocks(cull.size))
            set_if_used(shader, "u_tan_half_fov", cull.tan_half_fov)
            with clock:
                cull.blocks.bind_to_storage_buffer(RIM_BLOCKS)
            blocks_x, blocks_y = rim_blocks(cull.size)
            self._run(shader, DILATE_BLOCKS, blocks_x * blocks_y)
        with clock:
            table.clear(size=4 * (buckets + 1))
            self._buffers[KEPT_COUNT].clear()
        self._run(shader, COUNT, n)
        self._run(shader, CAP, buckets)
        for counts, other in ((raw, table), (table, raw)):  # the same scan over both
            with clock:
                counts.bind_to_storage_buffer(BUCKETS)
                other.bind_to_storage_buffer(RAW)
            self._run(shader, CHUNK_SUMS, chunks)
            self._run(shader, SCAN_SUMS, 1, count=chunks)  # one invocation scans `chunks` sums
            self._run(shader, CHUNK_SCAN, chunks)
        for phase in (SCATTER, PLACE):  # over the kept particles only
            set_if_used(shader, "u_phase", phase)
            with clock:
                shader.run_indirect(self._buffers[KEPT_COUNT], 4)  # past the count
                self._context.gl.ctx.memory_barrier(moderngl.ALL_BARRIER_BITS)
        self._run(shader, CROWD, buckets)
        return BuiltGrid(float(support), buckets - 1)

    def sorted_count(self, built: BuiltGrid) -> int:
        """How many entries the build that returned `built` sorted (crowded buckets merged into
        at most SLOTS each; reads 4 bytes back: for tests and benches)."""
        end = 4 * (built.bucket_mask + 1)  # starts[table size] = the total
        return int(np.frombuffer(self._buffers[BUCKETS].read(size=4, offset=end), np.uint32)[0])

    def bind_for_reading(self) -> None:
        """Bind the table and the sorted centres (a reader's bindings 14 and 16)."""
        with self._context.gl.clock:
            self._buffers[BUCKETS].bind_to_storage_buffer(BUCKETS)
            self._buffers[SORTED].bind_to_storage_buffer(SORTED)

    def _run(
        self, shader: moderngl.ComputeShader, phase: int, items: int, count: int | None = None
    ) -> None:
        """Phase `phase` over `items` invocations (`count`: its u_count, default `items`)."""
        set_if_used(shader, "u_phase", phase)
        set_if_used(shader, "u_count", items if count is None else count)
        with self._context.gl.clock:
            dispatch_1d(shader, items, GROUP_SIZE)
            self._context.gl.ctx.memory_barrier(moderngl.ALL_BARRIER_BITS)

    def release(self) -> None:
        for buffer in self._buffers.values():
            buffer.release()
        self._buffers.clear()
