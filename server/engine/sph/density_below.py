"""Which particles' kernel density is below a limit, on OpenCL, without the SPH engine's
counting sort (``shaders/sph/density_below.cl`` documents the table and why it is exact).

The droplet split asks it of every frame whose densities it computes (a particle is a droplet
below `quality.droplet_density`), and `quality.droplet_lone_density` of every frame that
carries densities (SPlisHSPlasH's count walls the frame does not hold, so a lone particle by a
wall reads 0.45-1.0 rest density and would be smoothed into a lens). `SphEngine.density`
answers both too, but pays the sort and a whole neighbourhood per particle: 37 ms for the
100k-particle bench ball on this 2-core VM's PoCL against 4-6 ms here, 13-22 ms for a dam-break
frame's 32k against 2-4 ms, each particle's walk stopping once its sum passes the limit
(benchmarks/bench_sph.py --below; inside a rendered frame, beside llvmpipe, the ball's took
7-10 ms). `SphEngine.density_below` is the entry point; it keeps frames this module cannot
place in float32 (`fits`), and frames whose overflow list passed its cap, on the exact path.

Owns nothing: the buffers come from the engine's pool (`BufferPool`), released with it.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from sphrender.server.engine.gpu.cl_context import CLContext
from sphrender.server.engine.sph.buffers import WORK_GROUP, BufferPool, round_up

F64 = npt.NDArray[np.float64]
Bools = npt.NDArray[np.bool_]

#: Kernel file (package data in `sphrender.shaders`); includes ``sph/sph.cl``.
BELOW_KERNELS = "sph/density_below.cl"
#: Particle indices a bucket lists (BELOW_SLOTS of density_below.cl); a fluid's cell of side
#: h = 4 r holds ~8, so only a bucket shared by several full cells, or a support far above
#: 4 r, overflows.
SLOTS = 32
#: Largest frame extent, in support radii, kept in float32 offsets from the frame's minimum:
#: their rounding stays below 2^-8 h (2^16 h x 2^-24). Wider frames take the exact path.
BELOW_MAX_CELLS = 2**16
#: Buckets: the power of two >= N / 2, at least MIN_BUCKETS. A fluid fills ~N / 8 cells of side
#: h = 4 r, spray up to N: a bucket holds ~0.25-2 cells' particles, far from SLOTS, in a table
#: of 64 bytes a particle. The table's size is the insert's cost (scattered writes, not the
#: atomics): for the 100k ball 16 MB (N buckets) took it 1.5 ms, 8 MB 0.5-0.7 ms.
MIN_BUCKETS = 1024
#: Entries of the overflow list (particles past their bucket's SLOTS). A particle next to a
#: full bucket scans the whole list, so it stays short: at the default h = 4 r the 500k-ball
#: with 3 % spray overflows 11 particles, the 1M one 62; a support of 6 r overflows 2k of 100k
#: (cells of ~27), 8 r 46k (unbounded, that frame took 5.7 s at 500k against 0.2 s for the
#: density pass). Past the cap the particles that need the list are undecided and the frame
#: goes to `density`.
OVERFLOW_CAP = 1024
#: density_below.cl's answers.
NOT_BELOW, BELOW, UNDECIDED = 0, 1, 2
#: sph.cl's SIGMA_3D: the spline's 3-D normalisation, 8 / pi.
SIGMA_3D = 8.0 / np.pi


def fits(low: F64, high: F64, support_radius: float) -> bool:
    """Whether a frame between corners `low` and `high` spans at most `BELOW_MAX_CELLS` support
    radii along every axis (its float32 offsets from `low` stay within 2^-8 h)."""
    return float((high - low).max()) <= BELOW_MAX_CELLS * support_radius


def spline_limit(below: float, mass: float, support_radius: float) -> float:
    """The density `below` as a limit on sph.cl's unnormalised spline sum: rho = m sigma / h^3
    x sum, so rho < below <=> sum < below h^3 / (m sigma)."""
    return float(below * support_radius**3 / (mass * SIGMA_3D))


class DensityBelowKernels:
    """The program's kernels on one `CLContext` (built on first use, cached by it)."""

    def __init__(self, cl: CLContext) -> None:
        import pyopencl

        self._cl = cl
        self._pyopencl: Any = pyopencl
        program = cl.program(BELOW_KERNELS, {"BELOW_SLOTS": SLOTS})
        self._insert = pyopencl.Kernel(program, "below_insert")
        self._classify = pyopencl.Kernel(program, "below_classify")

    def run(
        self,
        points: F64,
        low: F64,
        support_radius: float,
        limit: float,
        buffer: BufferPool,
        overflow_cap: int = OVERFLOW_CAP,
    ) -> Bools | None:
        """Which of `points` ((N, 3) float64, N > 0, minimum `low`, `fits`) have a spline sum
        below `limit` (`spline_limit`); None when the overflow list (`overflow_cap` entries)
        was too short to answer a particle (the caller then asks the exact density pass)."""
        n = points.shape[0]
        relative = np.ascontiguousarray(points - low, dtype=np.float32)
        buckets = max(MIN_BUCKETS, 1 << max(0, (n - 1) // 2).bit_length())
        cl, queue = self._pyopencl, self._cl.queue
        positions = buffer("below_positions", relative.nbytes)
        cl.enqueue_copy(queue, positions, relative)
        counts = buffer("below_counts", 4 * buckets)
        cl.enqueue_fill_buffer(queue, counts, np.uint32(0), 0, 4 * buckets)
        overflow_count = buffer("below_overflow_count", 4)
        cl.enqueue_fill_buffer(queue, overflow_count, np.uint32(0), 0, 4)
        slots = buffer("below_slots", 4 * SLOTS * buckets)
        overflow = buffer("below_overflow", 4 * max(1, overflow_cap))
        answers = buffer("below_flags", n)
        h, mask, cap = np.float32(support_radius), np.uint32(buckets - 1), np.uint32(overflow_cap)
        inv_h = np.float32(1.0 / support_radius)
        size, group = (round_up(n),), (WORK_GROUP,)
        count = np.uint32(n)
        self._insert(
            queue, size, group, positions, count, inv_h, mask, counts, slots, cap,
            overflow_count, overflow,
        )  # fmt: skip
        self._classify(
            queue, size, group, positions, count, h, inv_h, mask, np.float32(limit), counts,
            slots, cap, overflow_count, overflow, answers,
        )  # fmt: skip
        flags = np.empty(n, np.uint8)
        cl.enqueue_copy(queue, flags, answers)
        if (flags == UNDECIDED).any():
            return None
        return flags == BELOW
