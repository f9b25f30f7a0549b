"""Which particles' eq 2 density is below a limit, on OpenCL (`SphEngine.density_below`,
shaders/sph/density_below.cl), against the float64 cKDTree density.

Tolerance, derived: the device sums float32 spline weights of float32 offsets from the frame's
minimum. For these frames (extent <= ~30 h) an offset is rounded by at most 30 h 2^-24 < 2e-6 h
per axis, so a distance by at most ~8e-6 h (two roundings, three axes), which moves a weight by
at most |dW/dq| (<= 2) x 8e-6 = 1.6e-5 W(0); the float32 sum adds K 2^-24 of itself. Below
0.5 rest (1.57 W(0)) a particle has at most a few neighbours with a sizeable weight, so its sum
errs by < 1e-4 of the limit even with every rounding the same way; at the fluid limits (0.9,
1.2 rest: ~30 terms) independent roundings grow as sqrt(K): ~1e-4. So a particle whose float64
density lies farther than TIE = 1e-4 of the limit from it must get the reference's answer
(measured: no particle differs on any frame here or in benchmarks/bench_sph.py --below).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
from sph_reference import reference_sph
from test_sph import MASS, H, R, params

from sphrender.core.readers import read_particles
from sphrender.server.content.lattice import jittered_lattice_ball
from sphrender.server.engine.sph import density_below as below_module
from sphrender.server.engine.sph.engine import SphEngine, column_bounds

TIE = 1e-4
#: Limits as fractions of rest density: a lone particle reads 1/pi = 0.318, a pair 3 r apart
#: 0.328, a touching pair 0.398, a fluid ~1 (0.36: the lone rule; 0.45: the droplet split).
FRACTIONS = (0.30, 0.33, 0.36, 0.45, 0.5, 0.9, 1.2)


def reference_density(positions: npt.NDArray[np.float64], h: float = H) -> npt.NDArray[np.float64]:
    return reference_sph(positions, h, MASS).density


def assert_matches_reference(
    engine: SphEngine, positions: npt.NDArray[np.float64], fractions: tuple[float, ...] = FRACTIONS
) -> None:
    """At every limit, every particle outside the tie band gets the reference's answer."""
    density = reference_density(positions)
    for fraction in fractions:
        below = fraction * 1000.0
        got = engine.density_below(positions, params(), below)
        expected = density < below
        decided = np.abs(density - below) > TIE * below
        wrong = np.flatnonzero((got != expected) & decided)
        assert wrong.size == 0, f"limit {fraction}: {wrong.size} wrong, first {wrong[:5]}"


def splashy_frame(seed: int) -> npt.NDArray[np.float64]:
    """A pool, spray over it, pairs at 2 r and 3 r, coincident, collinear and coplanar
    particles: the neighbourhoods a splash frame holds."""
    rng = np.random.default_rng(seed)
    pool = jittered_lattice_ball(0.25, R, jitter=0.3, seed=seed)
    spray = rng.uniform(-0.6, 0.6, (600, 3)) + np.array([0.0, 0.6, 0.0])
    pairs = np.concatenate(
        [[[0.7, 0.0, 0.0], [0.7 + 2 * R, 0.0, 0.0]], [[0.9, 0.1, 0.0], [0.9 + 3 * R, 0.1, 0.0]]]
    )
    coincident = np.repeat([[-0.7, 0.2, 0.3]], 3, axis=0)
    line = np.array([-0.8, -0.5, 0.0]) + np.arange(6)[:, None] * [2.5 * R, 0.0, 0.0]
    grid = np.stack(np.meshgrid(np.arange(5), np.arange(5), indexing="ij"), -1).reshape(-1, 2)
    sheet = np.column_stack([grid * 2.2 * R, np.zeros(len(grid))]) + np.array([0.5, -0.7, 0.4])
    return np.concatenate([pool, spray, pairs, coincident, line, sheet]).astype(np.float64)


def kernel_answer(
    engine: SphEngine,
    positions: npt.NDArray[np.float64],
    fraction: float,
    overflow_cap: int = below_module.OVERFLOW_CAP,
) -> npt.NDArray[np.bool_] | None:
    """density_below.cl's own answer (None: undecided), without the engine's density pass."""
    kernels = below_module.DensityBelowKernels(engine._cl)
    low, _ = column_bounds(positions)
    limit = below_module.spline_limit(fraction * 1000.0, MASS, H)
    return kernels.run(positions, low, H, limit, engine._pool, overflow_cap)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_splashy_frames_match_the_reference(sph_engine: SphEngine, seed: int) -> None:
    assert_matches_reference(sph_engine, splashy_frame(seed))


def test_the_fast_path_answers_ordinary_frames(sph_engine: SphEngine) -> None:
    """No bucket overflows on a fluid and its spray at the default h: the kernel answers the frame
    itself (the density pass would hide a kernel that left everything undecided)."""
    positions = splashy_frame(0)
    got = kernel_answer(sph_engine, positions, 0.36)
    assert got is not None
    expected = reference_density(positions) < 360.0
    assert np.array_equal(got, expected)
    assert 500 < got.sum() < len(positions) - 1000  # spray is lone, the pool is not


def test_real_frame_matches_the_reference(sph_engine: SphEngine, dambreak: Path) -> None:
    frame = read_particles(dambreak / "vtk" / "ParticleData_Fluid_11.vtk")
    assert_matches_reference(sph_engine, frame.positions.astype(np.float64))


def test_huge_coordinates_give_the_same_answer(sph_engine: SphEngine) -> None:
    positions = splashy_frame(3)
    near = sph_engine.density_below(positions, params(), 360.0)
    far = sph_engine.density_below(positions + np.array([2e5, -1e5, 1e5]), params(), 360.0)
    assert np.array_equal(near, far)
    assert near.any() and not near.all()


def test_small_frames(sph_engine: SphEngine) -> None:
    """No particle, one (lone: W(0) alone), two coincident (not: 2 W(0) = 0.64 rest)."""
    assert sph_engine.density_below(np.zeros((0, 3)), params(), 360.0).shape == (0,)
    assert sph_engine.density_below(np.zeros((1, 3)), params(), 360.0).tolist() == [True]
    assert sph_engine.density_below(np.zeros((2, 3)), params(), 360.0).tolist() == [False, False]
    # A limit below W(0): nothing is lone, whatever its neighbours.
    assert not sph_engine.density_below(np.eye(3), params(), 100.0).any()


def test_a_full_bucket_is_answered_exactly(sph_engine: SphEngine) -> None:
    """70 coincident particles 0.9 h from a particle: each adds W(0.9 h) = 0.002 W(0), 0.14 in
    all, which takes it past 0.36 rest (1.131 W(0)). All 71 share one cell (0 and 0.9 h lie
    in the same cell of side h), so its bucket lists 32 and the other 39 go to the overflow
    list: the listed ones alone (<= 0.064) would leave it below; with the list, not below.
    With 40 of them (0.08) it is below, and answered so. A list two entries too short leaves
    the particle undecided (None: the engine then runs the density pass)."""
    one = np.array([[0.0, 0.0, 0.0]])
    for crowd, lone in ((70, False), (40, True)):
        positions = np.concatenate([one, np.repeat([[0.9 * H, 0.0, 0.0]], crowd, axis=0)])
        assert (reference_density(positions)[0] < 360.0) == lone
        got = kernel_answer(sph_engine, positions, 0.36)
        assert got is not None and got[0] == lone and not got[1:].any()
        assert np.array_equal(sph_engine.density_below(positions, params(), 360.0), got)
        assert kernel_answer(sph_engine, positions, 0.36, overflow_cap=crowd - 33) is None


def test_crowded_buckets_are_read_from_the_overflow_list(sph_engine: SphEngine) -> None:
    """A support of 8 r: a fluid's cell holds ~64 particles, every bucket of the ball
    overflows (~600 particles on the list, under its cap), and the spray beside the ball reads
    its crowded neighbours from the list."""
    rng = np.random.default_rng(6)
    pool = jittered_lattice_ball(0.2, R, jitter=0.3, seed=6)
    spray = rng.uniform(-0.35, 0.35, (300, 3))
    positions = np.concatenate([pool, spray])
    h = 2 * H
    density = reference_sph(positions, h, MASS).density
    for fraction in (0.05, 0.36):
        below = fraction * 1000.0
        kernels = below_module.DensityBelowKernels(sph_engine._cl)
        low, _ = column_bounds(positions)
        limit = below_module.spline_limit(below, MASS, h)
        got = kernels.run(positions, low, h, limit, sph_engine._pool)
        assert got is not None
        decided = np.abs(density - below) > TIE * below
        assert np.array_equal(got[decided], (density < below)[decided])
        assert 0 < got.sum() < len(pool)


def test_an_overflow_list_past_its_cap_leaves_the_frame_to_the_density_pass(
    sph_engine: SphEngine,
) -> None:
    """2000 coincident particles 0.9 h from one: 1968 past their bucket's slots, over the
    list's cap. They add 2000 W(0.9) = 4 W(0): the one is not below 0.36 rest, which only the
    density pass can tell; the kernel leaves it undecided."""
    positions = np.concatenate([np.zeros((1, 3)), np.repeat([[0.9 * H, 0.0, 0.0]], 2000, axis=0)])
    assert 2000 - below_module.SLOTS > below_module.OVERFLOW_CAP
    assert kernel_answer(sph_engine, positions, 0.36) is None
    assert not sph_engine.density_below(positions, params(), 360.0).any()
    assert reference_density(positions)[0] > 360.0


def test_a_frame_too_wide_for_float32_offsets_takes_the_density_pass(
    sph_engine: SphEngine,
) -> None:
    """Two clusters 2^17 h apart: outside `fits`, answered by `density` all the same."""
    cluster = splashy_frame(4)[:400]
    positions = np.concatenate([cluster, cluster + np.array([2**17 * H, 0.0, 0.0])])
    low, high = column_bounds(positions)
    assert not below_module.fits(low, high, H)
    got = sph_engine.density_below(positions, params(), 360.0)
    assert np.array_equal(got[:400], got[400:])
    assert np.array_equal(got[:400], reference_density(cluster) < 360.0)


def test_column_bounds_are_numpys() -> None:
    points = np.random.default_rng(5).normal(size=(1000, 3)) * [1.0, 1e5, 1e-5]
    low, high = column_bounds(points)
    assert np.array_equal(low, points.min(axis=0)) and np.array_equal(high, points.max(axis=0))


def bucket(cell: tuple[int, int, int], mask: int) -> int:
    """density_below.cl's bucket of a cell (sph.cl's hashed_bucket; cells >= 0 here)."""
    x, y, z = cell
    return ((x * 73856093) ^ (y * 19349663) ^ (z * 83492791)) & mask


def colliding_face_neighbour(mask: int) -> tuple[tuple[int, int, int], tuple[int, int, int]]:
    """A cell c >= 1 and a face neighbour offset d whose bucket is also the bucket of c or of
    another of c's 26 neighbours (a bucket the walk reaches twice)."""
    offsets = [(x, y, z) for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1)]
    faces = [d for d in offsets if sum(map(abs, d)) == 1]
    for x in range(2, 40):
        for y in range(2, 40):
            c = (x, y, 5)
            buckets = {d: bucket((x + d[0], y + d[1], 5 + d[2]), mask) for d in offsets}
            for d in faces:
                if sum(b == buckets[d] for b in buckets.values()) > 1:
                    return c, d
    raise AssertionError("no colliding neighbourhood found")


def test_a_bucket_two_cells_share_is_counted_once(sph_engine: SphEngine) -> None:
    """Particle A at a cell's centre, B 0.7 h away in a face neighbour whose bucket another
    cell of A's walk shares: B adds W(0.7) = 0.054 W(0) once (A: 1.054 W(0), lone under a
    limit of 1.08 W(0)), not twice (1.108: not lone). An anchor at the origin fixes the
    frame's minimum, and so the cells, far from both."""
    mask = below_module.MIN_BUCKETS - 1
    cell, face = colliding_face_neighbour(mask)
    a = (np.array(cell) + 0.5) * H
    positions = np.array([[0.0, 0.0, 0.0], a, a + 0.7 * H * np.array(face)])
    unit = MASS * below_module.SIGMA_3D / H**3  # W(0)'s density
    density = reference_density(positions) / unit
    assert np.allclose(density, [1.0, 1.054, 1.054], atol=1e-6)
    below = 1.08 * unit
    got = kernel_answer(sph_engine, positions, below / 1000.0)
    assert got is not None and got.tolist() == [True, True, True]
