"""SPH quantities on OpenCL: neighbour grid, density, colour field, surface flags.

Why the renderer needs SPH at all (thesis section 3.3.4): the adaptive particle radius shrinks
splash particles, which needs each particle's density and the average density of the surface
particles, which needs the colour field gradient (eq 26-28). Clients that send no densities get
them computed (eq 2). Surface-only splatting reuses the surface flags to skip the hidden interior.

Per frame (`SphEngine.compute`), everything below runs on the device except the first and last
steps, which are O(N) numpy:

1. host, float64: positions relative to the frame's minimum, split into an integer grid cell
   (cell size = support radius h) and a float32 offset inside the cell. Distances on the device
   are ``(cell_j - cell_i) h + (local_j - local_i)``, exact in the cell part, so coordinates of
   1e5 or a domain of 1e5 h lose nothing.
2. counting sort by cell (Green 2010): bucket per particle and its rank in the bucket by
   ``atomic_inc``, exclusive prefix sum of the bucket counts, the ranks made stable (by index
   within the bucket, not atomic order: the same frame sums its neighbours in the same order
   every run), scatter into cell order. Dense
   buckets (one per cell) when the domain's cell count is at most ~8 N, else a hash table of
   2 N..4 N buckets (sparse or unbounded domains: a lone droplet far away costs one bucket).
3. density (only when the client sent none), then colour field + gradient + surface flag, then
   (surface-only splatting) the dilated splat mask. The three read the same sorted arrays.
4. host: surface density (mean density of surface particles) and the eq 29 radii, vectorised
   (`radii.py`); `frame.py` applies the result to a frame for the renderer.

The kernel file is ``shaders/sph/sph.cl``; its header documents the kernel function and grid modes.
`SphEngine.anisotropy` (Yu & Turk ellipsoids) builds its own grid with cell side R and
runs ``shaders/sph/anisotropy.cl`` (launched by `anisotropy.py`, which documents the output).
`SphEngine` owns its device buffers (`buffers.py`'s pool, shared with the anisotropy and
density-below launches) and releases them in `release`; the program is cached by the `CLContext`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from sphrender.core.errors import InputError, show
from sphrender.server.engine.gpu.cl_context import CLContext
from sphrender.server.engine.sph.anisotropy import (
    AnisotropyKernels,
    AnisotropyParameters,
    AnisotropyResult,
    check_radii,
)
from sphrender.server.engine.sph.buffers import WORK_GROUP, BufferPool, round_up
from sphrender.server.engine.sph.crowd import find_crowds
from sphrender.server.engine.sph.density_below import DensityBelowKernels, spline_limit
from sphrender.server.engine.sph.density_below import fits as below_fits

if TYPE_CHECKING:
    from sphrender.server.scene import Scene

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
Bools = npt.NDArray[np.bool_]

#: Kernel file (package data in `sphrender.shaders`).
SPH_KERNELS = "sph/sph.cl"
#: Largest cell coordinate accepted (cells are int32 on the device, with room for +-1).
MAX_CELL_SPAN = 2**30
#: Dense buckets while the domain has at most this many cells per particle (+ a small floor).
DENSE_CELLS_PER_PARTICLE = 8
#: Target number of chunks in the three-pass prefix sum (the middle pass is serial).
SCAN_CHUNKS = 4096


@dataclass(frozen=True)
class SphParameters:
    """Absolute SPH settings for one frame, resolved from a scene and a particle radius."""

    support_radius: float
    mass: float
    rest_density: float
    #: eq 28's t in 1/length: surface where |n| > surface_threshold.
    surface_threshold: float
    #: Splat mask: kernel density below this (absolute) marks a sparse particle.
    sparse_density: float
    #: Splat mask: reach of the safety layer around flagged particles (length, <= h).
    safety_reach: float

    @classmethod
    def from_scene(cls, scene: Scene, particle_radius: float) -> SphParameters:
        sph = scene.sph
        h = sph.support_radius if sph.support_radius is not None else 4.0 * particle_radius
        mass = sph.mass if sph.mass is not None else sph.rest_density * (2.0 * particle_radius) ** 3
        return cls(
            support_radius=h,
            mass=mass,
            rest_density=sph.rest_density,
            surface_threshold=sph.surface_threshold / h,
            sparse_density=sph.sparse_density * sph.rest_density,
            safety_reach=sph.safety_layer * h,
        )


@dataclass(frozen=True)
class SphResult:
    """Per-particle SPH quantities, in the frame's particle order."""

    density: F32
    #: False when `density` are the client's densities, passed through.
    density_computed: bool
    color_field: F32
    #: (N, 3), eq 27; None when not asked for.
    color_gradient: F32 | None
    #: eq 28 (corrected): |n| > t.
    surface: Bools
    #: Surface-only splatting: which particles to splat; None when not asked for.
    splat_keep: Bools | None


def check_densities(densities: object, count: int, name: str = "densities") -> F32:
    """Client densities as float32; `InputError` naming `name[i]` for <= 0, NaN or Inf."""
    array = np.asarray(densities)
    if array.dtype.kind not in "fiu":
        raise InputError(name, f"must be a numeric array, got dtype {array.dtype}")
    if array.shape != (count,):
        raise InputError(name, f"must have shape ({count},), got {tuple(array.shape)}")
    values = array.astype(np.float32)
    bad = ~np.isfinite(values) | (values <= 0.0)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InputError(f"{name}[{i}]", f"must be finite and > 0, got {show(array[i])}")
    return np.ascontiguousarray(values)


@dataclass
class _Grid:
    """The sorted particle grid of one frame, living in the engine's buffers."""

    count: int
    nx: int  # > 0: dense buckets; 0: hashed
    ny: int
    nz: int
    mask: int
    h: float


def checked_positions(positions: npt.ArrayLike) -> F64:
    """Positions as contiguous float64 (N, 3); `InputError` for another shape, NaN or Inf."""
    points = np.ascontiguousarray(positions, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise InputError("positions", f"must have shape (N, 3), got {points.shape}")
    if not np.isfinite(points).all():
        bad = int(np.flatnonzero(~np.isfinite(points).all(axis=1))[0])
        raise InputError(f"positions[{bad}]", "must be finite (found NaN or Inf)")
    return points


def column_bounds(points: npt.NDArray[np.floating[Any]]) -> tuple[F64, F64]:
    """Per-axis minimum and maximum of (N, 3) points (N > 0), column by column: numpy's
    ``min(axis=0)`` over a C-ordered (N, 3) array is ~20x slower (100k points: 2.8 ms against
    0.13 ms per call, numpy 2.4 on this 2-core VM); the grid build took four of them."""
    low = np.array([points[:, k].min() for k in range(points.shape[1])], np.float64)
    high = np.array([points[:, k].max() for k in range(points.shape[1])], np.float64)
    return low, high


class SphEngine:
    """Runs the SPH kernels on one `CLContext`; owns its device buffers (see module docstring)."""

    @property
    def cl(self) -> CLContext:
        return self._cl

    def __init__(self, cl: CLContext) -> None:
        import pyopencl

        self._cl = cl
        self._pyopencl: Any = pyopencl
        program = cl.program(SPH_KERNELS)
        self._kernels: dict[str, Any] = {
            name: pyopencl.Kernel(program, name)
            for name in (
                "count_buckets",
                "scatter_index",
                "stable_rank",
                "scatter_sorted",
                "chunk_sums",
                "scan_chunk_sums",
                "chunk_scan",
                "count_neighbours",
                "list_neighbours",
                "density",
                "gather_volumes",
                "color_field",
                "dilate_flags",
            )
        }
        self._pool = BufferPool(cl)
        self._anisotropy: AnisotropyKernels | None = None  # built on first use
        self._below: DensityBelowKernels | None = None  # built on first use

    def _run(self, name: str, global_size: int, *args: Any) -> None:
        kernel = self._kernels[name]
        kernel(self._cl.queue, (round_up(global_size),), (WORK_GROUP,), *args)

    def release(self) -> None:
        """Release every device buffer (owner thread); the engine is unusable afterwards."""
        self._cl.check_owner()
        self._pool.release()
        self._kernels.clear()
        self._anisotropy = None
        self._below = None

    # -- grid ------------------------------------------------------------------------------

    def _prefix_sum(self, counts: Any, m: int, starts: Any) -> None:
        """starts[0..m] = exclusive prefix sum of counts[0..m-1] (starts[m] = total)."""
        chunk = max(32, -(-m // SCAN_CHUNKS))
        chunks = -(-m // chunk)
        sums = self._pool("scan_sums", 4 * (chunks + 1))
        u32 = np.uint32
        self._run("chunk_sums", chunks, counts, u32(m), u32(chunk), sums)
        self._kernels["scan_chunk_sums"](self._cl.queue, (1,), (1,), sums, u32(chunks))
        self._run("chunk_scan", chunks, counts, u32(m), u32(chunk), u32(chunks), sums, starts)

    def _build_grid(self, positions: F64, h: float, weights: F32 | None = None) -> _Grid:
        """`weights`: how many particles each stands for (crowd.py; None: 1 each), in .w of
        the sorted offsets, which the kernels multiply each neighbour's term by."""
        n = positions.shape[0]
        lo, hi = column_bounds(positions)
        relative = positions - lo
        cell_f = np.floor(relative / h)
        span = column_bounds(cell_f)[1]
        if float(span.max()) >= MAX_CELL_SPAN:
            extent = float((hi - lo).max())
            raise InputError(
                "positions",
                f"the particles span {extent:g} units, more than {MAX_CELL_SPAN} support radii "
                f"({h:g}); split the frame or raise sph.support_radius",
            )
        cell = np.zeros((n, 4), dtype=np.int32)
        cell[:, :3] = cell_f
        local = np.zeros((n, 4), dtype=np.float32)
        local[:, :3] = relative - cell_f * h
        local[:, 3] = 1.0 if weights is None else weights
        dims = [int(s) + 1 for s in span]
        cells = dims[0] * dims[1] * dims[2]
        if cells <= DENSE_CELLS_PER_PARTICLE * n + 4096:
            nx, ny, nz, mask, buckets = dims[0], dims[1], dims[2], 0, cells
        else:
            buckets = 1 << max(10, math.ceil(math.log2(2 * n)))
            nx, ny, nz, mask = 0, 0, 0, buckets - 1

        queue = self._cl.queue
        cell_buf = self._pool.upload("cell", cell)
        local_buf = self._pool.upload("local", local)
        counts = self._pool("bucket_counts", 4 * buckets)
        self._pyopencl.enqueue_fill_buffer(queue, counts, np.uint32(0), 0, 4 * buckets)
        bucket = self._pool("bucket", 4 * n)
        rank = self._pool("rank", 4 * n)
        i32, u32 = np.int32, np.uint32
        self._run(
            "count_buckets", n, cell_buf, u32(n), i32(nx), i32(ny), u32(mask), bucket, rank, counts
        )
        starts = self._pool("bucket_starts", 4 * (buckets + 1))
        self._prefix_sum(counts, buckets, starts)
        # The same order every run: ranks by index within each bucket, not atomic order.
        slots = self._pool("bucket_slots", 4 * n)
        self._run("scatter_index", n, bucket, rank, starts, u32(n), slots)
        self._run("stable_rank", n, bucket, starts, slots, u32(n), rank)
        self._run(
            "scatter_sorted",
            n,
            cell_buf,
            local_buf,
            bucket,
            rank,
            starts,
            u32(n),
            self._pool("sorted_cell", 16 * n),
            self._pool("sorted_local", 16 * n),
            self._pool("sorted_to_original", 4 * n),
        )
        return _Grid(n, nx, ny, nz, mask, h)

    def _grid_args(self, grid: _Grid) -> tuple[Any, ...]:
        """The GRID_ARGS of sph.cl followed by sorted_to_original and n."""
        return (
            self._pool["sorted_cell"],
            self._pool["sorted_local"],
            self._pool["bucket_starts"],
            np.int32(grid.nx),
            np.int32(grid.ny),
            np.int32(grid.nz),
            np.uint32(grid.mask),
            np.float32(grid.h),
            self._pool["sorted_to_original"],
            np.uint32(grid.count),
        )

    # -- public ----------------------------------------------------------------------------

    def neighbour_lists(
        self, positions: npt.ArrayLike, support_radius: float
    ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
        """CSR neighbour lists: for particle i, ``indices[offsets[i]:offsets[i+1]]`` are the j != i
        with |x_i - x_j| < support_radius, in no particular order."""
        self._cl.check_owner()
        points = np.ascontiguousarray(positions, dtype=np.float64)
        n = points.shape[0]
        if n == 0:
            return np.zeros(1, np.int64), np.zeros(0, np.int64)
        grid = self._build_grid(points, support_radius)
        args = self._grid_args(grid)
        counts = self._pool("neighbour_counts", 4 * n)
        self._run("count_neighbours", n, *args, counts)
        offsets_buf = self._pool("neighbour_offsets", 4 * (n + 1))
        self._prefix_sum(counts, n, offsets_buf)
        offsets = self._pool.download(offsets_buf, np.empty(n + 1, np.uint32))
        total = int(offsets[-1])
        neighbours = self._pool("neighbour_list", 4 * total)
        self._run("list_neighbours", n, *args, offsets_buf, neighbours)
        indices = self._pool.download(neighbours, np.empty(total, np.uint32))
        return offsets.astype(np.int64), indices.astype(np.int64)

    def compute(
        self,
        positions: npt.ArrayLike,
        params: SphParameters,
        densities: npt.ArrayLike | None = None,
        *,
        gradient: bool = True,
        splat_mask: bool = False,
    ) -> SphResult:
        """Density (unless `densities` are given), colour field, surface flags; the gradient and
        the surface-only splat mask only when asked for (their read-back costs time)."""
        self._cl.check_owner()
        points = checked_positions(positions)
        n = points.shape[0]
        client_densities = None if densities is None else check_densities(densities, n)
        crowd = find_crowds(points, params.support_radius)
        if crowd is not None:  # each representative takes its own client density
            rows = crowd.representatives
            chosen = None if client_densities is None else client_densities[rows]
            merged = crowd.expand(
                self._compute(points[rows], params, chosen, gradient, splat_mask, crowd.weights)
            )
            if client_densities is None:
                return merged
            return replace(merged, density=client_densities)
        return self._compute(points, params, client_densities, gradient, splat_mask)

    def _compute(
        self,
        points: F64,
        params: SphParameters,
        client_densities: F32 | None,
        gradient: bool,
        splat_mask: bool,
        weights: F32 | None = None,
    ) -> SphResult:
        n = points.shape[0]
        if n == 0:
            empty = np.zeros(0, np.float32)
            return SphResult(
                empty,
                client_densities is None,
                empty,
                np.zeros((0, 3), np.float32) if gradient else None,
                np.zeros(0, bool),
                np.zeros(0, bool) if splat_mask else None,
            )
        args = self._grid_args(self._build_grid(points, params.support_radius, weights))
        sorted_volume, density_out = self._volumes(args, n, params, client_densities)
        sorted_flag = self._colour_field(args, n, params, sorted_volume)
        if splat_mask:
            keep_out = self._pool("splat_keep", n)
            reach = np.float32(params.safety_reach)
            self._run("dilate_flags", n, *args, sorted_flag, reach, keep_out)
        density = client_densities
        if density is None:
            density = self._pool.download(density_out, np.empty(n, np.float32))
        return self._read_result(n, density, client_densities is None, gradient, splat_mask)

    def _volumes(
        self,
        args: tuple[Any, ...],
        n: int,
        params: SphParameters,
        client_densities: F32 | None,
    ) -> tuple[Any, Any]:
        """Each particle's volume m / rho in grid order and the density buffer (eq 2's, or the
        client's uploaded)."""
        f32 = np.float32
        sorted_volume = self._pool("sorted_volume", 4 * n)
        density_out = self._pool("density", 4 * n)
        if client_densities is None:
            self._run("density", n, *args, f32(params.mass), sorted_volume, density_out)
        else:
            self._pool.upload("density", client_densities)
            self._run(
                "gather_volumes",
                n,
                density_out,
                self._pool["sorted_to_original"],
                np.uint32(n),
                f32(params.mass),
                sorted_volume,
            )
        return sorted_volume, density_out

    def _colour_field(
        self, args: tuple[Any, ...], n: int, params: SphParameters, sorted_volume: Any
    ) -> Any:
        """The colour field, its gradient and the surface flags (in input order), and the flags
        in grid order, which the splat mask's dilation reads."""
        f32 = np.float32
        sorted_flag = self._pool("sorted_flag", n)
        self._run(
            "color_field",
            n,
            *args,
            f32(params.mass),
            sorted_volume,
            f32(params.surface_threshold),
            f32(params.sparse_density),
            self._pool("color", 4 * n),
            self._pool("gradient", 16 * n),
            self._pool("surface", n),
            sorted_flag,
        )
        return sorted_flag

    def _read_result(
        self, n: int, density: F32, computed: bool, gradient: bool, splat_mask: bool
    ) -> SphResult:
        """The colour field, the surface flags and what else was asked for, read back."""
        color = self._pool.download(self._pool["color"], np.empty(n, np.float32))
        surface = self._pool.download(self._pool["surface"], np.empty(n, np.uint8)).astype(bool)
        gradient_xyz = None
        if gradient:
            gradient4 = self._pool.download(self._pool["gradient"], np.empty((n, 4), np.float32))
            gradient_xyz = np.ascontiguousarray(gradient4[:, :3])
        keep = None
        if splat_mask:
            keep = self._pool.download(self._pool["splat_keep"], np.empty(n, np.uint8)).astype(bool)
        return SphResult(density, computed, color, gradient_xyz, surface, keep)

    def density(self, positions: npt.ArrayLike, params: SphParameters) -> F32:
        """Eq 2 only (no colour field): the kernel density of every particle, in input order."""
        self._cl.check_owner()
        points = np.ascontiguousarray(positions, dtype=np.float64)
        n = points.shape[0]
        if n == 0:
            return np.zeros(0, np.float32)
        crowd = find_crowds(points, params.support_radius)
        weights = None
        if crowd is not None:
            points, weights = points[crowd.representatives], crowd.weights
        grid = self._build_grid(points, params.support_radius, weights)
        n = grid.count
        sorted_volume = self._pool("sorted_volume", 4 * n)
        density_out = self._pool("density", 4 * n)
        self._run(
            "density",
            n,
            *self._grid_args(grid),
            np.float32(params.mass),
            sorted_volume,
            density_out,
        )
        density = self._pool.download(density_out, np.empty(n, np.float32))
        return density if crowd is None else density[crowd.members]

    def density_below(self, positions: npt.ArrayLike, params: SphParameters, below: float) -> Bools:
        """Which particles' eq 2 density is below `below` (absolute): `density(...) < below`
        at a fraction of its cost, each particle's sum stopping once it passes the limit
        (`density_below.py`). Frames wider than `BELOW_MAX_CELLS` support radii, and those
        where a full bucket of its table left a particle undecided (crowded cells: a support
        far above 4 r), take `density` itself."""
        self._cl.check_owner()
        points = checked_positions(positions)
        if points.shape[0] == 0:
            return np.zeros(0, bool)
        low, high = column_bounds(points)
        h = params.support_radius
        if below_fits(low, high, h):
            limit = spline_limit(below, params.mass, h)
            answer = self.density_below_kernels().run(points, low, h, limit, self._pool)
            if answer is not None:
                return answer
        return self.density(points, params) < below

    def density_below_kernels(self) -> DensityBelowKernels:
        """The density_below program (built on first use: `SphStage.warm` asks for it before
        the first frame that needs it, so that frame's SPH stage is not LLVM's)."""
        self._cl.check_owner()
        if self._below is None:
            self._below = DensityBelowKernels(self._cl)
        return self._below

    def anisotropy_kernels(self) -> AnisotropyKernels:
        """The anisotropy program (built on first use; `eigen_sym3` is the tests' way in)."""
        self._cl.check_owner()
        if self._anisotropy is None:
            self._anisotropy = AnisotropyKernels(self._cl)
        return self._anisotropy

    def anisotropy(
        self,
        positions: npt.ArrayLike,
        params: AnisotropyParameters,
        radii: float | npt.ArrayLike,
    ) -> AnisotropyResult:
        """Yu & Turk ellipsoids (see `anisotropy.py` for the layout): smoothed centres (float64)
        and semi-axis matrices scaled by `radii` (a scalar or one per particle, e.g. eq 29's);
        spheres get exactly ``r * I`` and their own position. The grid is built with cell side
        `params.radius`, so this is its own neighbour walk, not `compute`'s."""
        kernels = self.anisotropy_kernels()
        points = checked_positions(positions)
        n = points.shape[0]
        radius = check_radii(radii, n)
        if n == 0:
            return AnisotropyResult.empty()
        crowd = find_crowds(points, params.radius)
        if crowd is None:
            grid = self._build_grid(points, params.radius)
            shapes = kernels.run(self._grid_args(grid), n, params, self._pool)
        else:
            rows = crowd.representatives
            grid = self._build_grid(points[rows], params.radius, crowd.weights)
            shapes = crowd.expand(kernels.run(self._grid_args(grid), rows.size, params, self._pool))
        return shapes.result(points, radius)


# -- renderer glue ---------------------------------------------------------------------------
