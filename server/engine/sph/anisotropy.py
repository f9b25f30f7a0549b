"""Anisotropic particles on OpenCL (Yu & Turk 2013): per particle an ellipsoid of the
particle's volume stretched along its neighbourhood's principal axes, and a smoothed centre.

The kernels (``shaders/sph/anisotropy.cl``, which includes ``sph.cl`` for the grid walk) run on
the grid `SphEngine` builds, with cell side R = the anisotropy radius; `SphEngine.anisotropy` is
the entry point, this module holds the parameters, the result and the kernel launches (its
buffers come from the engine's pool, `buffers.py`; it imports nothing of `engine.py`).

Output contract (the ellipsoid splat consumes it):

* ``centers``  float64 (N, 3): smoothed centres, world units: x_i + lambda t_i (x^w_i - x_i),
  the shift computed in float32 on the device from cell-split offsets and added here in
  float64, so a scene at 1e5 gets the same shifts as one at the origin. Spheres: exactly x_i.
* ``axes``     float32 (N, 3, 3): ``axes[i]`` is the matrix A whose COLUMNS are the ellipsoid's
  principal semi-axes in world units; the ellipsoid is { c + A u : |u| <= 1 }, |det A| = r^3.
  Spheres: exactly ``r * I`` (bit-exact: the device writes the identity, the host multiplies
  by the float32 radius).
* ``is_sphere`` bool (N,): fewer than N_eps neighbours, or a degenerate neighbourhood.
* ``neighbour_count`` int32 (N,): neighbours j != i within R (diagnostics, tests).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from sphrender.core.errors import InputError, show
from sphrender.server.engine.gpu.cl_context import CLContext
from sphrender.server.engine.sph.buffers import WORK_GROUP, BufferPool, round_up

if TYPE_CHECKING:
    from sphrender.server.scene import Scene

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
Bools = npt.NDArray[np.bool_]
I32 = npt.NDArray[np.int32]

#: Kernel file (package data in `sphrender.shaders`); includes ``sph/sph.cl``.
ANISOTROPY_KERNELS = "sph/anisotropy.cl"
#: Anisotropy ramps in over this many neighbours, as a fraction of N_eps: t = min(1, (n - N_eps
#: + 1) / ramp) for n >= N_eps, so crossing N_eps between frames changes a shape continuously.
RAMP_FRACTION = 0.5


@dataclass(frozen=True)
class AnisotropyParameters:
    """Absolute anisotropy settings for one frame (see `SphConfig.anisotropy_*`)."""

    #: R: neighbourhood radius (length); also the grid's cell side for this pass.
    radius: float
    #: k_r: largest ratio between the largest and the smallest covariance eigenvalue (>= 1).
    max_ratio: float
    #: N_eps: particles with fewer neighbours (j != i within R) stay spheres.
    min_neighbours: int
    #: lambda in [0, 1]: how far centres move toward their neighbourhood's weighted mean.
    smoothing: float

    @property
    def ramp(self) -> float:
        """Neighbours over which anisotropy ramps in above N_eps (>= 1)."""
        return max(1.0, RAMP_FRACTION * self.min_neighbours)

    @classmethod
    def from_scene(cls, scene: Scene, support_radius: float) -> AnisotropyParameters:
        sph = scene.sph
        return cls(
            radius=sph.anisotropy_radius * support_radius,
            max_ratio=sph.anisotropy_max_ratio,
            min_neighbours=sph.anisotropy_min_neighbours,
            smoothing=sph.anisotropy_smoothing,
        )


@dataclass(frozen=True)
class AnisotropyResult:
    """Per-particle ellipsoids, in the frame's particle order (layout: module docstring)."""

    centers: F64
    axes: F32
    is_sphere: Bools
    neighbour_count: I32

    @classmethod
    def empty(cls) -> AnisotropyResult:
        return cls(
            np.zeros((0, 3), np.float64),
            np.zeros((0, 3, 3), np.float32),
            np.zeros(0, bool),
            np.zeros(0, np.int32),
        )

    @property
    def count(self) -> int:
        return int(self.is_sphere.shape[0])

    def subset(self, keep: Bools) -> AnisotropyResult:
        """The particles where `keep` is true (e.g. the surface-only splat mask)."""
        return AnisotropyResult(
            self.centers[keep], self.axes[keep], self.is_sphere[keep], self.neighbour_count[keep]
        )


@dataclass(frozen=True)
class AnisotropyShapes:
    """Device output before radii: unit-volume shapes (identity for spheres) and shifts."""

    shift: F32  # (N, 3) world units
    shape: F32  # (N, 3, 3), det ~ 1
    is_sphere: Bools
    neighbour_count: I32

    def result(self, positions: F64, radii: float | npt.ArrayLike) -> AnisotropyResult:
        """Centres x + shift (float64) and axes r * shape (float32: r * I exactly for spheres)."""
        n = self.is_sphere.shape[0]
        radius = check_radii(radii, n)
        centers = np.asarray(positions, dtype=np.float64) + self.shift.astype(np.float64)
        axes = self.shape * radius[:, None, None]
        return AnisotropyResult(centers, axes, self.is_sphere, self.neighbour_count)


def check_radii(radii: float | npt.ArrayLike, count: int) -> F32:
    """Particle radii as float32 (N,): a scalar broadcasts; `InputError` for <= 0, NaN, Inf."""
    array = np.asarray(radii, dtype=np.float32)
    if array.ndim == 0:
        array = np.full(count, array, dtype=np.float32)
    if array.shape != (count,):
        raise InputError("radii", f"must have shape ({count},), got {tuple(array.shape)}")
    bad = ~np.isfinite(array) | (array <= 0.0)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InputError(f"radii[{i}]", f"must be finite and > 0, got {show(array[i])}")
    return np.ascontiguousarray(array)


class AnisotropyKernels:
    """The anisotropy program's kernels on one `CLContext` (built on first use, cached by it)."""

    def __init__(self, cl: CLContext) -> None:
        import pyopencl

        self._cl = cl
        self._pyopencl: Any = pyopencl
        program = cl.program(ANISOTROPY_KERNELS)
        self._anisotropy = pyopencl.Kernel(program, "anisotropy")
        self._eigen = pyopencl.Kernel(program, "eigen_sym3_test")

    def _download(self, buffer: Any, array: np.ndarray) -> np.ndarray:
        if array.nbytes:
            self._pyopencl.enqueue_copy(self._cl.queue, array, buffer)
        return array

    def run(
        self, grid_args: tuple[Any, ...], n: int, params: AnisotropyParameters, buffer: BufferPool
    ) -> AnisotropyShapes:
        """Launch on a grid of cell side `params.radius` (`grid_args` = sph.cl's GRID_ARGS,
        sorted_to_original, n) and read the shapes back."""
        if params.max_ratio < 1.0 or not 0.0 <= params.smoothing <= 1.0:
            raise ValueError(f"anisotropy parameters out of range: {params}")
        shift = buffer("aniso_shift", 16 * n)
        shape = buffer("aniso_shape", 36 * n)
        sphere = buffer("aniso_sphere", n)
        count = buffer("aniso_count", 4 * n)
        f32 = np.float32
        self._anisotropy(
            self._cl.queue,
            (round_up(n),),
            (WORK_GROUP,),
            *grid_args,
            f32(params.max_ratio),
            np.uint32(params.min_neighbours),
            f32(params.ramp),
            f32(params.smoothing),
            shift,
            shape,
            sphere,
            count,
        )
        shift4 = self._download(shift, np.empty((n, 4), np.float32))
        return AnisotropyShapes(
            np.ascontiguousarray(shift4[:, :3]),
            self._download(shape, np.empty((n, 3, 3), np.float32)),
            self._download(sphere, np.empty(n, np.uint8)).astype(bool),
            self._download(count, np.empty(n, np.uint32)).astype(np.int32),
        )

    def eigen_sym3(self, matrices: npt.ArrayLike) -> tuple[F32, F32]:
        """The device's symmetric 3x3 eigen-solver on (M, 3, 3) matrices (the upper triangle
        is used): eigenvalues (M, 3) descending, eigenvectors (M, 3, 3) as columns. For tests."""
        a = np.asarray(matrices, dtype=np.float32).reshape(-1, 3, 3)
        m = a.shape[0]
        packed = np.stack(
            [a[:, 0, 0], a[:, 1, 1], a[:, 2, 2], a[:, 0, 1], a[:, 0, 2], a[:, 1, 2]], axis=1
        )
        cl, mf = self._pyopencl, self._pyopencl.mem_flags
        context = self._cl.context
        padded = np.zeros((max(m, 1), 6), np.float32)  # a buffer cannot be empty
        padded[:m] = packed
        source = cl.Buffer(context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=padded)
        values_buf = cl.Buffer(context, mf.WRITE_ONLY, max(16, 12 * m))
        vectors_buf = cl.Buffer(context, mf.WRITE_ONLY, max(16, 36 * m))
        try:
            if m:
                self._eigen(
                    self._cl.queue,
                    (round_up(m),),
                    (WORK_GROUP,),
                    source,
                    np.uint32(m),
                    values_buf,
                    vectors_buf,
                )
            values = self._download(values_buf, np.empty((m, 3), np.float32))
            vectors = self._download(vectors_buf, np.empty((m, 3, 3), np.float32))
        finally:
            for buf in (source, values_buf, vectors_buf):
                buf.release()
        return values, vectors
