"""Anisotropic particles (issue 12, Yu & Turk 2013) on OpenCL (real PoCL) against float64 numpy.

Tolerances, derived (u = 2^-24, float32's unit roundoff):
* Eigen-solver (`eigen_sym3_test` runs the kernel's own `eigen_sym3`): cyclic Jacobi with 6
  sweeps applies 18 rotations, each an orthogonal similarity computed with O(u) ||A|| backward
  error (Golub & Van Loan 8.5.4), so the result is the exact decomposition of A + E with ||E||
  <~ 18 u ||A||; by Weyl the eigenvalues err by at most ||E||, the residual ||A v - lambda v||
  by about as much, and V^T V - I by O(18 u). The bound used is 32 u (||A|| = the largest
  |eigenvalue|); measured worst: 6 u (values), 12 u (orthonormality), 7 u (residual) over random,
  rank-1, rank-2, zero and repeated-eigenvalue matrices at scales 1e-30 .. 1e20. Eigenvectors
  of repeated eigenvalues are not unique, so vectors are checked through residual and
  orthonormality, not against numpy's.
* Shapes: compared as A A^T (the ellipsoid's invariant: independent of axis signs and, for
  repeated lengths, of the basis), relative to r^2. The device sums K ~ 30-120 float32 terms of
  magnitude <= 1 (offsets in units of R) per covariance entry, so C errs by ~sqrt(K) u ~ 7e-7
  R^2 (random-walk rounding; K u ~ 7e-6 if every rounding aligned). An axis length (s_k /
  g)^t r moves by ~2 dC / s_min of itself, s_min >= s_max / k_r ~ 0.03 R^2, and the longest
  axis^2 is <= k_r^(4/3) r^2 = 6.3 r^2 (k_r = 4), so A A^T errs by ~2 * 6.3 * 7e-7 / 0.03 ~
  3e-4 r^2 at most in the typical case. SHAPE_BOUND = 2e-4 r^2; measured worst 3.8e-6 r^2
  (random cloud, jittered ball, either at 1e5). Centres: the shift lambda t m R has the error
  of m (~sqrt(K) u R): CENTER_BOUND = 1e-6 R, measured 7e-8 R. Volume: |det A| / r^3 - 1 has
  three logs, an exp and a product of rounding (~10 u): VOLUME_BOUND = 1e-5, measured 1.1e-6.
* Neighbour counts (and so the sphere flags and the ramp t) must match the cKDTree exactly,
  except for particles with a pair within TIE_BAND = 1e-5 R of R (see test_sph.py: the device
  distance errs by < 5e-7 R), which are left out of every comparison.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest
from anisotropy_reference import ReferenceAnisotropy, reference_anisotropy, shape_tensor
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from sphrender.core.errors import InputError
from sphrender.core.frame import make_frame
from sphrender.server.content.lattice import jittered_lattice_ball
from sphrender.server.engine.gpu.cl_context import kernel_source
from sphrender.server.engine.sph.anisotropy import AnisotropyParameters, AnisotropyResult
from sphrender.server.engine.sph.engine import SphEngine
from sphrender.server.engine.sph.frame import (
    apply_sph,
    apply_to_frame,
    frame_adaptive_radii,
    needs_sph,
)
from sphrender.server.scene import Scene, scene_from_dict

U = 2.0**-24
EIGEN_BOUND = 32 * U
SHAPE_BOUND = 2e-4
CENTER_BOUND = 1e-6
VOLUME_BOUND = 1e-5
TIE_BAND = 1e-5
R = 0.01  # particle radius
H = 4 * R


def rotated(diagonal: tuple[float, float, float], count: int, seed: int) -> npt.NDArray[np.float64]:
    """`count` matrices R diag(d) R^T with random rotations R."""
    rotations = Rotation.random(count, random_state=seed).as_matrix()
    return np.einsum("nij,j,nkj->nik", rotations, np.asarray(diagonal), rotations)


def symmetric_cases(seed: int = 1) -> dict[str, npt.NDArray[np.float64]]:
    rng = np.random.default_rng(seed)
    random = rng.normal(size=(500, 3, 3))
    return {
        "random": random + random.transpose(0, 2, 1),
        "repeated 1,1,2": rotated((1.0, 1.0, 2.0), 200, seed),
        "repeated 2,1,1": rotated((2.0, 1.0, 1.0), 200, seed + 1),
        "nearly repeated": rotated((1.0, 1.0 + 1e-6, 2.0), 200, seed + 2),
        "isotropic": rotated((1.5, 1.5, 1.5), 50, seed + 3),
        "rank 1": rotated((0.0, 0.0, 1.0), 200, seed + 4),
        "rank 2": rotated((0.0, 1.0, 3.0), 200, seed + 5),
        "rank 2 repeated": rotated((0.0, 1.0, 1.0), 200, seed + 6),
        "indefinite": rotated((1.0, -1.0, 0.0), 200, seed + 7),
        "zero": np.zeros((4, 3, 3)),
        "diagonal": np.diag([3.0, 1.0, 2.0])[None],
    }


@pytest.mark.parametrize("scale", [1.0, 1e-30, 1e-20, 1e20])
@pytest.mark.parametrize("case", list(symmetric_cases()))
def test_eigen_solver_matches_numpy(sph_engine: SphEngine, case: str, scale: float) -> None:
    # the float32 matrix the device sees is the one numpy decomposes (input rounding is not
    # the solver's error)
    a32 = (symmetric_cases()[case] * scale).astype(np.float32)
    a = a32.astype(np.float64)
    values, vectors = sph_engine.anisotropy_kernels().eigen_sym3(a32)
    assert np.isfinite(values).all() and np.isfinite(vectors).all()
    expected = np.linalg.eigh(a)[0][:, ::-1]  # descending, as the kernel
    norm = np.abs(expected).max(axis=1)
    norm = np.where(norm > 0.0, norm, 1.0)  # the zero matrix: absolute errors (all are 0)
    assert (np.abs(values - expected).max(axis=1) <= EIGEN_BOUND * norm).all()
    assert (np.diff(values, axis=1) <= 0.0).all(), "eigenvalues must come sorted descending"
    v = vectors.astype(np.float64)
    gram = np.einsum("nji,njk->nik", v, v)
    assert np.abs(gram - np.eye(3)).max() <= EIGEN_BOUND
    assert np.linalg.det(v).min() > 0.0, "eigenvectors must form a proper rotation"
    residual = np.einsum("nij,njk->nik", a, v) - v * values[:, None, :].astype(np.float64)
    assert (np.linalg.norm(residual, axis=1).max(axis=1) <= EIGEN_BOUND * norm).all()


def test_eigen_solver_zero_matrix_gives_identity(sph_engine: SphEngine) -> None:
    values, vectors = sph_engine.anisotropy_kernels().eigen_sym3(np.zeros((1, 3, 3)))
    assert (values == 0.0).all()
    assert (vectors[0] == np.eye(3, dtype=np.float32)).all()


def test_eigen_solver_no_matrices(sph_engine: SphEngine) -> None:
    values, vectors = sph_engine.anisotropy_kernels().eigen_sym3(np.zeros((0, 3, 3)))
    assert values.shape == (0, 3) and vectors.shape == (0, 3, 3)


# -- anisotropy against the float64 reference ----------------------------------------------


def params(
    radius: float = 1.5 * H,
    *,
    max_ratio: float = 4.0,
    min_neighbours: int = 25,
    smoothing: float = 0.5,
) -> AnisotropyParameters:
    return AnisotropyParameters(radius, max_ratio, min_neighbours, smoothing)


def run_both(
    engine: SphEngine,
    positions: np.ndarray,
    p: AnisotropyParameters,
    radii: float | np.ndarray = R,
    shift: float = 0.0,
) -> tuple[AnisotropyResult, ReferenceAnisotropy, npt.NDArray[np.bool_]]:
    """Engine (optionally on positions + shift) and reference; the mask of non-tie particles."""
    result = engine.anisotropy(positions + shift, p, radii)
    ref = reference_anisotropy(
        positions,
        p.radius,
        max_ratio=p.max_ratio,
        min_neighbours=p.min_neighbours,
        smoothing=p.smoothing,
        particle_radius=radii,
    )
    tree = cKDTree(positions)
    outer = tree.query_ball_point(positions, p.radius * (1 + TIE_BAND), return_length=True)
    inner = tree.query_ball_point(positions, p.radius * (1 - TIE_BAND), return_length=True)
    return result, ref, outer == inner


def assert_matches_reference(
    result: AnisotropyResult,
    ref: ReferenceAnisotropy,
    ok: npt.NDArray[np.bool_],
    radius: float,
    r: float = R,
    shift: float = 0.0,
) -> None:
    assert result.centers.dtype == np.float64 and result.centers.shape == ref.centers.shape
    assert result.axes.dtype == np.float32 and result.axes.shape == ref.axes.shape
    assert np.isfinite(result.axes).all() and np.isfinite(result.centers).all()
    assert (result.neighbour_count[ok] == ref.neighbour_count[ok]).all()
    assert (result.is_sphere[ok] == ref.is_sphere[ok]).all()
    shape_error = np.abs(shape_tensor(result.axes) - shape_tensor(ref.axes)).max(axis=(1, 2))
    assert shape_error[ok].max(initial=0.0) <= SHAPE_BOUND * r**2
    center_error = np.abs(result.centers - shift - ref.centers).max(axis=1)
    assert center_error[ok].max(initial=0.0) <= CENTER_BOUND * radius
    volume = np.abs(np.linalg.det(result.axes.astype(np.float64)))
    assert np.abs(volume / r**3 - 1.0).max(initial=0.0) <= VOLUME_BOUND


def assert_spheres_exact(
    result: AnisotropyResult, positions: np.ndarray, radii: float | np.ndarray = R
) -> None:
    """The sphere contract: A = r I bit-exact (float32 r), centre = position bit-exact."""
    s = result.is_sphere
    r32 = np.broadcast_to(np.asarray(radii, dtype=np.float32), s.shape)
    expected = np.eye(3, dtype=np.float32)[None] * r32[:, None, None]
    assert (result.axes[s] == expected[s]).all()
    assert (result.centers[s] == np.asarray(positions, np.float64)[s]).all()


def test_random_cloud_matches_reference(sph_engine: SphEngine) -> None:
    # ~36 neighbours on average: spheres (< 25), ramping (25..37) and full shapes all occur
    positions = np.random.default_rng(5).uniform(0.0, 1.0, (3000, 3))
    p = params(0.15)
    result, ref, ok = run_both(sph_engine, positions, p, 0.02)
    assert 0.05 < result.is_sphere.mean() < 0.5
    assert ((ref.ramp > 0) & (ref.ramp < 1)).any() and (ref.ramp == 1).any()
    assert_matches_reference(result, ref, ok, p.radius, 0.02)
    assert_spheres_exact(result, positions, 0.02)


def test_hashed_grid_matches_reference(sph_engine: SphEngine) -> None:
    """A far droplet makes the domain sparse, so the grid is hashed (sph.cl's second mode)."""
    cloud = np.random.default_rng(6).uniform(0.0, 1.0, (2000, 3))
    positions = np.concatenate([cloud, [[1e3, 1e3, 1e3]]])
    p = params(0.15)
    result, ref, ok = run_both(sph_engine, positions, p, 0.02)
    assert_matches_reference(result, ref, ok, p.radius, 0.02)
    assert result.is_sphere[-1] and result.neighbour_count[-1] == 0


def test_kernel_file_includes_the_grid_walk_once() -> None:
    source = kernel_source("sph/anisotropy.cl")
    assert source.count("__kernel void density") == 1  # sph.cl, included
    assert "__kernel void anisotropy" in source and "#include" not in source


@pytest.mark.parametrize("shift", [0.0, 1e5])
def test_jittered_lattice_ball(sph_engine: SphEngine, shift: float) -> None:
    """Interior: (nearly) isotropic neighbourhoods stay spheres of ~r (cubic lattice second
    moments are isotropic; jitter 0.1 r perturbs them by a few %). Surface: flattened, the
    shortest axis along the ball's normal. Same result at 1e5 as at the origin."""
    ball = 0.2
    positions = jittered_lattice_ball(ball, R, seed=1)
    p = params()
    result, ref, ok = run_both(sph_engine, positions, p, shift=shift)
    assert_matches_reference(result, ref, ok, p.radius, shift=shift)
    assert not result.is_sphere.any()
    lengths = np.linalg.norm(result.axes.astype(np.float64), axis=1)  # column norms
    distance = np.linalg.norm(positions, axis=1)
    interior = distance < ball - p.radius - 2 * R
    assert interior.sum() > 500
    assert np.abs(lengths[interior] / R - 1.0).max() < 0.1
    outer = distance > ball - 2 * R
    shortest = np.argmin(lengths, axis=1)
    normal_axis = result.axes[np.arange(len(positions)), :, shortest].astype(np.float64)
    cos = np.abs(np.einsum("ij,ij->i", normal_axis, positions)) / (
        np.linalg.norm(normal_axis, axis=1) * distance
    )
    assert np.median(cos[outer]) > 0.95
    assert lengths[outer].min(axis=1).mean() < 0.7 * R  # flattened along the normal
    # the smoothed centres of the surface move inwards (toward the weighted neighbourhood mean)
    inward = np.einsum(
        "ij,ij->i", result.centers[outer] - shift - positions[outer], positions[outer]
    )
    assert (inward < 0).mean() > 0.95


def lattice_sheet(side: int, spacing: float) -> np.ndarray:
    axis = (np.arange(side) - side / 2) * spacing
    xs, ys = np.meshgrid(axis, axis, indexing="ij")
    return np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], 1)


def test_thin_sheet_is_squashed_across_and_stretched_along(sph_engine: SphEngine) -> None:
    """One lattice layer: the normal variance is 0, clamped to s_max / k_r; the two in-plane
    ones are equal, so axes are r k_r^(1/3) in the plane and r k_r^(-2/3) across (product r^3)."""
    positions = lattice_sheet(40, 2 * R)
    p = params(min_neighbours=10)  # 28 in-plane neighbours within 6 r: full ramp (t = 1)
    result, ref, ok = run_both(sph_engine, positions, p)
    assert_matches_reference(result, ref, ok, p.radius)
    inner = np.abs(positions[:, :2]).max(axis=1) < 40 * R - p.radius - 2 * R
    assert inner.sum() > 100 and (ref.ramp[inner] == 1.0).all()
    a = result.axes[inner].astype(np.float64)
    lengths = np.sort(np.linalg.norm(a, axis=1), axis=1)
    np.testing.assert_allclose(lengths[:, 0], R * 4.0 ** (-2 / 3), rtol=1e-5)
    np.testing.assert_allclose(lengths[:, 1:], R * 4.0 ** (1 / 3), rtol=1e-5)
    across = a[np.arange(len(a)), :, np.argmin(np.linalg.norm(a, axis=1), axis=1)]
    np.testing.assert_allclose(
        np.abs(across[:, 2]) / np.linalg.norm(across, axis=1), 1.0, atol=1e-6
    )
    np.testing.assert_allclose(result.centers[inner][:, 2], 0.0, atol=1e-12)  # stays in the plane


def test_line_of_particles(sph_engine: SphEngine) -> None:
    """Collinear: rank-1 covariance, both cross variances clamped: r k_r^(2/3) along, r
    k_r^(-1/3) across, finite. With the default N_eps (4 neighbours < 25) all stay spheres."""
    positions = np.zeros((60, 3))
    positions[:, 0] = np.arange(60) * 2 * R
    p = params(min_neighbours=2)
    result, ref, ok = run_both(sph_engine, positions, p)
    assert_matches_reference(result, ref, ok, p.radius)
    inner = slice(5, 55)
    lengths = np.sort(np.linalg.norm(result.axes[inner].astype(np.float64), axis=1), axis=1)
    np.testing.assert_allclose(lengths[:, 2], R * 4.0 ** (2 / 3), rtol=1e-5)
    np.testing.assert_allclose(lengths[:, :2], R * 4.0 ** (-1 / 3), rtol=1e-5)
    default = sph_engine.anisotropy(positions, params(), R)
    assert default.is_sphere.all()
    assert_spheres_exact(default, positions)


def test_coplanar_neighbourhoods(sph_engine: SphEngine) -> None:
    positions = np.random.default_rng(8).uniform(-0.1, 0.1, (1500, 3))
    positions[:, 1] = 0.25  # all in one plane (rank-2 covariances)
    p = params(0.02, min_neighbours=10)
    result, ref, ok = run_both(sph_engine, positions, p)
    assert (~result.is_sphere).sum() > 500
    assert_matches_reference(result, ref, ok, p.radius)


def test_coincident_neighbourhoods(sph_engine: SphEngine) -> None:
    """40 particles on one point: C = 0 exactly, a degenerate neighbourhood -> exact spheres;
    one particle R/2 from 30 coincident ones: a rank-1 covariance, a finite line shape."""
    cluster = np.full((40, 3), 0.5)
    result = sph_engine.anisotropy(cluster, params(), R)
    assert result.is_sphere.all() and (result.neighbour_count == 39).all()
    assert_spheres_exact(result, cluster)
    p = params(min_neighbours=5)
    pair = np.concatenate([np.zeros((1, 3)), np.tile([[0.5 * p.radius, 0.0, 0.0]], (30, 1))])
    result, ref, ok = run_both(sph_engine, pair, p)
    assert np.isfinite(result.axes).all() and not result.is_sphere[0]
    assert_matches_reference(result, ref, ok, p.radius)


@pytest.mark.parametrize("size", [1, 2, 3, 4])
def test_few_neighbours_stay_exact_spheres(sph_engine: SphEngine, size: int) -> None:
    """Clusters of 1-4 particles (0-3 neighbours), far apart: spheres of radius r exactly, at
    their own positions (a lone droplet neither shrinks nor moves)."""
    rng = np.random.default_rng(size)
    centres = np.arange(20)[:, None] * np.array([1.0, 0.0, 0.0])
    positions = (centres[:, None, :] + rng.uniform(0, 2 * R, (20, size, 3))).reshape(-1, 3)
    radii = rng.uniform(0.5 * R, R, len(positions))
    result = sph_engine.anisotropy(positions, params(), radii)
    assert result.is_sphere.all() and (result.neighbour_count == size - 1).all()
    assert_spheres_exact(result, positions, radii)


def test_no_and_one_particle(sph_engine: SphEngine) -> None:
    empty = sph_engine.anisotropy(np.zeros((0, 3)), params(), R)
    assert empty.centers.shape == (0, 3) and empty.axes.shape == (0, 3, 3)
    assert empty.is_sphere.shape == (0,) and empty.count == 0
    one = np.array([[1e5, -3.0, 2.5]])
    result = sph_engine.anisotropy(one, params(min_neighbours=1), R)
    assert result.is_sphere.all() and result.neighbour_count[0] == 0
    assert_spheres_exact(result, one)


def test_axes_scale_with_per_particle_radii(sph_engine: SphEngine) -> None:
    """axes = float32 shape * float32 r: bit-identical to scaling the unit-radius result."""
    positions = jittered_lattice_ball(0.1, R, seed=2)
    radii = np.random.default_rng(0).uniform(0.5 * R, R, len(positions)).astype(np.float32)
    unit = sph_engine.anisotropy(positions, params(), 1.0)
    scaled = sph_engine.anisotropy(positions, params(), radii)
    assert (scaled.axes == unit.axes * radii[:, None, None]).all()
    assert (scaled.centers == unit.centers).all()


def test_bad_input_names_the_array(sph_engine: SphEngine) -> None:
    with pytest.raises(InputError, match=r"radii\[1\]"):
        sph_engine.anisotropy(np.zeros((3, 3)), params(), np.array([R, 0.0, R]))
    with pytest.raises(InputError, match="radii"):
        sph_engine.anisotropy(np.zeros((3, 3)), params(), np.array([R, R]))
    bad = np.zeros((3, 3))
    bad[2, 1] = np.nan
    with pytest.raises(InputError, match=r"positions\[2\]"):
        sph_engine.anisotropy(bad, params(), R)


# -- scene keys ------------------------------------------------------------------------------


def test_parameters_from_scene() -> None:
    scene = scene_from_dict({"sph": {"anisotropy": True, "anisotropy_radius": 2.0}})
    p = AnisotropyParameters.from_scene(scene, support_radius=0.04)
    assert p == AnisotropyParameters(0.08, 4.0, 25, 0.5)
    assert not Scene().sph.anisotropy  # off by default (the presets decide)


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("anisotropy_radius", 0.0),
        ("anisotropy_max_ratio", 0.5),
        ("anisotropy_min_neighbours", 0),
        ("anisotropy_min_neighbours", 2.5),
        ("anisotropy_smoothing", 1.5),
        ("anisotropy", "yes"),
    ],
)
def test_scene_errors_name_the_key(key: str, value: object) -> None:
    with pytest.raises(InputError, match=f"sph.{key}"):
        scene_from_dict({"sph": {key: value}})


# -- the frame glue --------------------------------------------------------------------------


def aniso_scene(**sph: object) -> Scene:
    return scene_from_dict({"particles": {"radius": R}, "sph": {"anisotropy": True, **sph}})


def test_needs_sph_includes_anisotropy() -> None:
    assert needs_sph(aniso_scene())
    assert not needs_sph(Scene())


def test_apply_sph_anisotropy_only(sph_engine: SphEngine) -> None:
    """Only anisotropy: no density pass, the frame unchanged, ellipsoids for every particle at
    the scene's radius with R = anisotropy_radius * h (h = 4 r)."""
    positions = jittered_lattice_ball(0.1, R, seed=3)
    frame = make_frame(positions)
    scene = aniso_scene()
    out = apply_sph(sph_engine, frame, scene)
    assert out.sph is None and out.frame.radii is None
    assert out.frame.positions is frame.positions
    assert out.anisotropy is not None and out.anisotropy.count == frame.count
    direct = sph_engine.anisotropy(positions, params(1.5 * H), R)
    assert (out.anisotropy.axes == direct.axes).all()
    assert (out.anisotropy.centers == direct.centers).all()
    # the sphere path never computes anisotropy (nor, here, anything else)
    drawn, result = apply_to_frame(sph_engine, frame, scene)
    assert result is None and drawn.positions is frame.positions


def test_apply_sph_scales_axes_by_frame_adaptive_radii_and_follows_the_splat_subset(
    sph_engine: SphEngine,
) -> None:
    ball = jittered_lattice_ball(0.1, R, seed=4)
    droplets = np.array([[0.5, 0.0, 0.0], [0.0, 0.6, 0.0], [0.02, 0.0, 0.15]])
    positions = np.concatenate([ball, droplets])
    frame = make_frame(positions, temperatures=np.full(len(positions), 1800.0))
    scene = aniso_scene(adaptive_radius=True, surface_only=True)
    out = apply_sph(sph_engine, frame, scene)
    assert out.sph is not None and out.sph.splat_keep is not None and out.anisotropy is not None
    keep = out.sph.splat_keep
    assert 0 < keep.sum() < len(positions) and keep[-3:].all()
    assert out.anisotropy.count == out.frame.count == keep.sum()
    radii = frame_adaptive_radii(out.sph, frame, scene)
    full = sph_engine.anisotropy(positions, params(1.5 * H), radii)
    assert (out.anisotropy.axes == full.axes[keep]).all()
    assert out.frame.radii is not None
    np.testing.assert_array_equal(out.frame.radii, radii[keep])
    # droplets: exact spheres of their (shrunk) eq 29 radius, at their own position
    drop = out.anisotropy.subset(np.arange(out.frame.count) >= out.frame.count - 3)
    assert drop.is_sphere.all()
    assert (drop.axes == np.eye(3, dtype=np.float32) * radii[-3:, None, None]).all()
    assert (drop.centers == droplets).all()
    assert (radii[-3:] < R).all()  # eq 29 shrank them: the axes follow
