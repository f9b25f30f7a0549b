"""SPH on OpenCL (real PoCL) against brute force and a float64 cKDTree reference.

Tolerances, derived:
* Neighbour sets: the device sees positions as float32 offsets inside cells of side h, each
  rounded by at most h 2^-24, so a pair's distance is off by at most ~4 sqrt(3) h 2^-24 < 5e-7 h
  (two roundings per axis plus the float32 subtraction and dot product). Pairs whose float64
  distance lies within TIE_BAND = 1e-5 h of h may therefore go either way; every other pair must
  match brute force exactly. On a lattice with h off the lattice distances the band is empty,
  so there the sets must be identical.
* Quantities: float32 sums of K ~ 30-60 terms carry a rounding error of at most ~K 2^-24 of the
  sum of the terms' magnitudes (< 4e-6), plus the position rounding above, which moves a term
  by ~5e-7 h / |x_i - x_j| of itself (largest for close pairs; measured up to 1.4e-5 of the
  magnitude sum for the gradient on the dam-break frame, 5e-7 for density and colour).
  Density and colour field are sums of positive terms, so that is a relative error; the
  gradient cancels to ~0 inside the fluid, so its error is measured relative to
  sum_j |V_j grad W_ij| (the scale the rounding is relative to), and additionally as a plain
  relative error on surface particles, where |n| is a sizeable part of that sum. The issue's
  bounds (median 1e-4, max 1e-3) are 25x above the derived sum rounding and 70x above the
  measured worst case, so a failure means a wrong formula, not rounding.
"""

from __future__ import annotations

import math
import threading
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
from sph_reference import ReferenceSph, cubic_spline, reference_pairs, reference_sph

from sphrender.core.errors import InputError
from sphrender.core.frame import make_frame
from sphrender.core.readers import read_particles
from sphrender.server.content.lattice import jittered_lattice_ball
from sphrender.server.engine.gpu.cl_context import (
    CLContext,
    CLUnavailableError,
    kernel_source,
    list_devices,
    probe_device,
)
from sphrender.server.engine.sph.engine import (
    SphEngine,
    SphParameters,
    SphResult,
    check_densities,
)
from sphrender.server.engine.sph.radii import adaptive_radii, surface_density
from sphrender.server.scene import Scene, scene_from_dict

TIE_BAND = 1e-5
MEDIAN_BOUND = 1e-4
MAX_BOUND = 1e-3
R = 0.015  # particle radius of the SPlisHSPlasH frames
H = 4 * R
MASS = 1000.0 * (2 * R) ** 3


def params(h: float = H, mass: float = MASS) -> SphParameters:
    return SphParameters(
        support_radius=h,
        mass=mass,
        rest_density=1000.0,
        surface_threshold=0.5 / h,
        sparse_density=750.0,
        safety_reach=0.5 * h,
    )


def pair_keys(offsets: npt.NDArray[np.int64], indices: npt.NDArray[np.int64]) -> np.ndarray:
    n = len(offsets) - 1
    rows = np.repeat(np.arange(n, dtype=np.int64), np.diff(offsets))
    return np.sort(rows * n + indices)


def assert_neighbours_match_brute_force(engine: SphEngine, positions: np.ndarray, h: float) -> int:
    """Every pair outside the tie band matches brute force; returns how many pairs were ties."""
    offsets, indices = engine.neighbour_lists(positions, h)
    n = len(positions)
    assert offsets.shape == (n + 1,) and offsets[0] == 0 and np.all(np.diff(offsets) >= 0)
    device = pair_keys(offsets, indices)
    assert len(np.unique(device)) == len(device), "a neighbour is listed twice"
    loose = reference_pairs(positions, h * (1 + TIE_BAND))
    not_self = loose.i != loose.j
    keys = loose.i[not_self] * n + loose.j[not_self]
    distance = loose.distance[not_self]
    strict = np.sort(keys[distance < h * (1 - TIE_BAND)])
    ties = keys[distance >= h * (1 - TIE_BAND)]
    assert np.all(np.isin(strict, device)), "a pair closer than h is missing"
    assert np.all(np.isin(device, np.sort(keys))), "a pair farther than h is listed"
    return len(ties)


def relative_errors(
    engine_result: SphResult, positions: np.ndarray, densities: np.ndarray | None = None
) -> tuple[ReferenceSph, np.ndarray, np.ndarray, np.ndarray]:
    ref = reference_sph(positions, H, MASS, densities)
    expected_density = ref.density if densities is None else np.asarray(densities, np.float64)
    density = np.abs(engine_result.density / expected_density - 1)
    color = np.abs(engine_result.color_field / ref.color_field - 1)
    assert engine_result.color_gradient is not None
    delta = np.linalg.norm(engine_result.color_gradient - ref.color_gradient, axis=1)
    gradient = delta / np.maximum(ref.gradient_abs_sum, 1e-300)
    return ref, density, color, gradient


def lattice_block(n: int, spacing: float) -> np.ndarray:
    axis = np.arange(n) * spacing
    return np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)


# -- neighbour search -----------------------------------------------------------------------


def test_neighbours_random(sph_engine: SphEngine) -> None:
    rng = np.random.default_rng(3)
    positions = rng.uniform(0.0, 1.0, (4000, 3))
    assert_neighbours_match_brute_force(sph_engine, positions, 0.1)


def test_neighbours_lattice(sph_engine: SphEngine) -> None:
    positions = lattice_block(14, 2 * R)
    # h = 4 r = 2 spacings: many pairs at exactly h (the tie band); h = 5 r: none, so there the
    # sets must be identical.
    assert assert_neighbours_match_brute_force(sph_engine, positions, H) > 0
    assert assert_neighbours_match_brute_force(sph_engine, positions, 5 * R) == 0


def test_neighbours_real_frame(sph_engine: SphEngine, dambreak: Path) -> None:
    frame = read_particles(dambreak / "vtk" / "ParticleData_Fluid_11.vtk")
    assert_neighbours_match_brute_force(sph_engine, frame.positions, H)


def test_neighbours_sparse_domain_uses_hashing(sph_engine: SphEngine) -> None:
    # Two clusters 1e4 h apart: a dense grid would need ~1e12 cells, so buckets are hashed.
    rng = np.random.default_rng(4)
    a = rng.uniform(0.0, 0.3, (1500, 3))
    b = rng.uniform(0.0, 0.3, (1500, 3)) + np.array([1e4 * H, -3e3 * H, 5e3 * H])
    positions = np.concatenate([a, b])
    assert_neighbours_match_brute_force(sph_engine, positions, H)
    check_against_reference(sph_engine.compute(positions, params()), positions)


def test_neighbours_huge_coordinates_match_origin(sph_engine: SphEngine) -> None:
    rng = np.random.default_rng(5)
    positions = rng.uniform(0.0, 0.5, (3000, 3))
    far = positions + np.array([1e5, -1e5, 3e5])
    near_keys = pair_keys(*sph_engine.neighbour_lists(positions, H))
    far_keys = pair_keys(*sph_engine.neighbour_lists(far, H))
    # float64 can represent the shifted positions to ~1e-11, far below the tie band.
    assert_neighbours_match_brute_force(sph_engine, far, H)
    assert np.array_equal(near_keys, far_keys)


def test_the_same_frame_gives_the_same_bits(sph_engine: SphEngine) -> None:
    """The counting sort's atomic ranks follow the order PoCL's threads ran the work-groups in;
    neighbour sums in that order differed in their last bits from run to run (before the
    ranks were made stable: 6 of 10 runs of this frame, ~60 particles a cell from many
    work-groups; a flaky bitwise test under the full suite's load). Ten runs, one result."""
    rng = np.random.default_rng(6)
    positions = rng.uniform(0.0, 0.4, (20000, 3))
    first = sph_engine.compute(positions, params())
    for _ in range(10):
        again = sph_engine.compute(positions, params())
        assert np.array_equal(again.density, first.density)
        assert again.color_gradient is not None and first.color_gradient is not None
        assert np.array_equal(again.color_gradient, first.color_gradient)


def test_all_particles_in_one_cell(sph_engine: SphEngine) -> None:
    rng = np.random.default_rng(6)
    positions = rng.uniform(0.0, 0.4 * H, (600, 3))  # one cell, everyone neighbours everyone
    offsets, _ = sph_engine.neighbour_lists(positions, H)
    assert np.all(np.diff(offsets) == 599)
    result = sph_engine.compute(positions, params())
    _, density, color, gradient = relative_errors(result, positions)
    assert np.max(density) <= MAX_BOUND and np.max(color) <= MAX_BOUND
    assert np.max(gradient) <= MAX_BOUND


# -- quantities against the reference -------------------------------------------------------


def check_against_reference(
    result: SphResult, positions: np.ndarray, densities: np.ndarray | None = None
) -> None:
    ref, density, color, gradient = relative_errors(result, positions, densities)
    for name, err in (("density", density), ("color_field", color), ("gradient", gradient)):
        assert np.median(err) <= MEDIAN_BOUND, (name, np.median(err))
        assert np.max(err) <= MAX_BOUND, (name, np.max(err))
    assert result.color_gradient is not None
    on_surface = np.linalg.norm(ref.color_gradient, axis=1) > 0.5 / H
    if on_surface.any():
        delta = result.color_gradient[on_surface] - ref.color_gradient[on_surface]
        plain = np.linalg.norm(delta, axis=1) / np.linalg.norm(
            ref.color_gradient[on_surface], axis=1
        )
        assert np.median(plain) <= MEDIAN_BOUND
        assert np.max(plain) <= MAX_BOUND
    assert np.array_equal(result.surface, np.linalg.norm(ref.color_gradient, axis=1) > 0.5 / H)


def test_quantities_random(sph_engine: SphEngine) -> None:
    rng = np.random.default_rng(7)
    positions = rng.uniform(0.0, 0.6, (8000, 3))
    check_against_reference(sph_engine.compute(positions, params()), positions)


def test_quantities_lattice_ball(sph_engine: SphEngine) -> None:
    positions = jittered_lattice_ball(0.3, R, jitter=0.2, seed=2)
    check_against_reference(sph_engine.compute(positions, params()), positions)


def test_quantities_real_frame_with_client_densities(sph_engine: SphEngine, dambreak: Path) -> None:
    frame = read_particles(dambreak / "vtk" / "ParticleData_Fluid_11.vtk")
    assert frame.densities is not None
    result = sph_engine.compute(frame.positions, params(), frame.densities)
    assert not result.density_computed
    assert np.array_equal(result.density, frame.densities)
    check_against_reference(result, frame.positions, frame.densities)


def test_quantities_real_frame_computed(sph_engine: SphEngine, dambreak: Path) -> None:
    frame = read_particles(dambreak / "vtk" / "ParticleData_Fluid_11.vtk")
    result = sph_engine.compute(frame.positions, params())
    assert result.density_computed
    check_against_reference(result, frame.positions)


def test_huge_coordinates_same_quantities(sph_engine: SphEngine) -> None:
    positions = jittered_lattice_ball(0.2, R, jitter=0.3, seed=9)
    near = sph_engine.compute(positions, params())
    far = sph_engine.compute(positions + np.array([2e5, 1e5, -1e5]), params())
    # Cell-relative float32 offsets: the shift changes only float64 rounding (~1e-11), so the
    # same float32 inputs reach the device, up to one ulp where the offsets round differently.
    np.testing.assert_allclose(far.density, near.density, rtol=1e-5)
    np.testing.assert_allclose(far.color_field, near.color_field, rtol=1e-5)
    assert np.array_equal(far.surface, near.surface)


# -- hard cases ------------------------------------------------------------------------------


def test_one_particle(sph_engine: SphEngine) -> None:
    result = sph_engine.compute(np.array([[1.0, 2.0, 3.0]]), params())
    w0 = 8.0 / (math.pi * H**3)
    assert result.density[0] == pytest.approx(MASS * w0, rel=1e-6)
    assert result.color_field[0] == pytest.approx(1.0, rel=1e-6)
    assert result.color_gradient is not None
    assert np.all(result.color_gradient == 0.0)
    assert not result.surface[0]


def test_no_particles(sph_engine: SphEngine) -> None:
    result = sph_engine.compute(np.zeros((0, 3)), params(), splat_mask=True)
    assert result.density.shape == (0,) and result.surface.shape == (0,)
    assert result.color_gradient is not None and result.color_gradient.shape == (0, 3)


def test_coincident_particles_give_zero_gradient_not_nan(sph_engine: SphEngine) -> None:
    # Two coincident pairs, far apart, plus a triple stacked on a lattice.
    lattice = lattice_block(6, 2 * R)
    positions = np.concatenate(
        [
            np.array([[5.0, 5.0, 5.0], [5.0, 5.0, 5.0], [9.0, 9.0, 9.0], [9.0, 9.0, 9.0]]),
            lattice,
            lattice[[40, 40, 40]],
        ]
    )
    result = sph_engine.compute(positions, params())
    assert result.color_gradient is not None
    for array in (result.density, result.color_field, result.color_gradient):
        assert np.all(np.isfinite(array))
    w0 = MASS * 8.0 / (math.pi * H**3)
    np.testing.assert_allclose(result.density[:4], 2 * w0, rtol=1e-6)
    assert np.all(result.color_gradient[:4] == 0.0)
    check_against_reference(result, positions)


def test_isolated_particles(sph_engine: SphEngine) -> None:
    positions = np.arange(50, dtype=np.float64)[:, None] * np.array([[1.5 * H, 0.0, 0.0]])
    result = sph_engine.compute(positions, params(), splat_mask=True)
    w0 = MASS * 8.0 / (math.pi * H**3)
    np.testing.assert_allclose(result.density, w0, rtol=1e-6)
    assert result.color_gradient is not None and np.all(result.color_gradient == 0.0)
    assert not result.surface.any()
    # No gradient, but far below rest density: sparse, so surface-only splatting keeps them.
    assert result.splat_keep is not None and result.splat_keep.all()


@pytest.mark.parametrize("bad", [0.0, -3.0, float("nan"), float("inf")])
def test_bad_client_densities_name_array_and_index(sph_engine: SphEngine, bad: float) -> None:
    positions = np.zeros((5, 3))
    densities = np.full(5, 1000.0)
    densities[3] = bad
    with pytest.raises(InputError) as info:
        sph_engine.compute(positions, params(), densities)
    assert info.value.field == "densities[3]"
    with pytest.raises(InputError) as info:
        make_frame(positions, densities=densities)
    assert info.value.field == "densities[3]"
    with pytest.raises(InputError) as info:
        check_densities(densities[:4], 5)
    assert info.value.field == "densities"


def test_positions_spanning_too_many_cells_are_an_input_error(sph_engine: SphEngine) -> None:
    positions = np.array([[0.0, 0.0, 0.0], [1e9, 0.0, 0.0]])
    with pytest.raises(InputError) as info:
        sph_engine.compute(positions, params(h=1e-3))
    assert info.value.field == "positions"


# -- surface flags, eq 29 --------------------------------------------------------------------


def test_surface_flags_on_lattice_ball_are_the_outer_layer(sph_engine: SphEngine) -> None:
    """On a perfect lattice ball the flagged particles are exactly those missing one of their six
    axis neighbours: the outer layer. The threshold (0.5 / h) sits between the layers: |n| h is
    >= 0.64 on the outer layer and <= 0.24 anywhere inside (0 deeper than h, where the
    neighbourhood is complete and symmetric), asserted below so a drift shows before a flip."""
    positions = jittered_lattice_ball(0.2, 0.01, jitter=0.0)
    h = 0.04
    result = sph_engine.compute(positions, params(h=h, mass=1000.0 * 0.02**3))
    offsets, _ = sph_engine.neighbour_lists(positions, 0.02 * 1.01)  # axis neighbours
    outer = np.diff(offsets) < 6
    assert outer.sum() > 0.1 * len(positions)
    assert np.array_equal(result.surface, outer)
    assert result.color_gradient is not None
    n_h = np.linalg.norm(result.color_gradient, axis=1) * h
    assert n_h[outer].min() > 0.6 and n_h[~outer].max() < 0.3


def test_adaptive_radius() -> None:
    d_surface = 800.0
    r_body = 0.015
    k = 0.25
    density = np.array([1200.0, 800.0, 700.0, 600.0, 318.0])
    radii = adaptive_radii(density, r_body, d_surface, min_fraction=0.5, decline=k)
    # The thesis's form with k_thesis = k d_surface^2 / r_body.
    k_thesis = k * d_surface**2 / r_body
    expected = [
        r_body,  # denser than the surface average: body radius
        r_body,  # equal: body radius
        r_body - (d_surface - 700.0) ** 2 / k_thesis,
        r_body - (d_surface - 600.0) ** 2 / k_thesis,
        0.5 * r_body,  # the formula goes below r_min: clamped
    ]
    np.testing.assert_allclose(radii, expected, rtol=1e-6)
    assert radii.dtype == np.float32
    # Per-particle body radii, and no surface at all (no d_surface): radii unchanged.
    body = np.array([0.01, 0.02, 0.03, 0.04, 0.05])
    np.testing.assert_allclose(
        adaptive_radii(density, body, None, min_fraction=0.5, decline=k), body, rtol=1e-7
    )
    scaled = adaptive_radii(density, body, d_surface, min_fraction=0.5, decline=k)
    np.testing.assert_allclose(scaled, body * np.asarray(expected) / r_body, rtol=1e-6)


def test_surface_density_is_mean_over_surface() -> None:
    density = np.array([1000.0, 800.0, 600.0, 990.0], dtype=np.float32)
    surface = np.array([False, True, True, False])
    assert surface_density(density, surface) == pytest.approx(700.0)
    assert surface_density(density, np.zeros(4, bool)) is None


def test_parameters_from_scene_defaults() -> None:
    p = SphParameters.from_scene(Scene(), 0.015)
    assert p.support_radius == pytest.approx(0.06)
    assert p.mass == pytest.approx(1000.0 * 0.03**3)
    assert p.surface_threshold == pytest.approx(0.5 / 0.06)
    scene = scene_from_dict({"sph": {"support_radius": 0.1, "mass": 2.0, "rest_density": 500}})
    p = SphParameters.from_scene(scene, 0.015)
    assert (p.support_radius, p.mass, p.rest_density) == (0.1, 2.0, 500.0)


@pytest.mark.parametrize(
    ("data", "field"),
    [
        ({"sph": {"rest_density": 0}}, "sph.rest_density"),
        ({"sph": {"support_radius": -1}}, "sph.support_radius"),
        ({"sph": {"min_radius": 1.5}}, "sph.min_radius"),
        ({"sph": {"adaptive_radius": 1}}, "sph.adaptive_radius"),
        ({"sph": {"safety_layer": 2}}, "sph.safety_layer"),
        ({"sph": {"threshold": 2}}, "sph.threshold"),
    ],
)
def test_sph_scene_errors_name_the_key(data: dict[str, object], field: str) -> None:
    with pytest.raises(InputError) as info:
        scene_from_dict(data)
    assert info.value.field == field


# -- the OpenCL context ----------------------------------------------------------------------


def test_program_is_built_once_per_context(cl_context: CLContext) -> None:
    first = cl_context.program("sph/sph.cl")
    assert cl_context.program("sph/sph.cl") is first
    assert "density" in first.kernel_names.split(";")


def test_kernel_file_is_package_data() -> None:
    assert "__kernel void density" in kernel_source("sph/sph.cl")


def test_context_refuses_other_threads(cl_context: CLContext, sph_engine: SphEngine) -> None:
    errors: list[BaseException] = []

    def use() -> None:
        try:
            sph_engine.compute(np.zeros((2, 3)), params())
        except BaseException as exc:
            errors.append(exc)

    thread = threading.Thread(target=use)
    thread.start()
    thread.join()
    assert len(errors) == 1 and isinstance(errors[0], RuntimeError)
    assert "thread" in str(errors[0])


def test_explicit_device_choice(cl_context: CLContext, monkeypatch: pytest.MonkeyPatch) -> None:
    info = cl_context.device_info
    monkeypatch.setenv("PYOPENCL_CTX", f"{info.platform_index}:{info.device_index}")
    with CLContext() as chosen:
        assert chosen.device_info == info
    with pytest.raises(CLUnavailableError) as error:
        CLContext("99:0")
    assert "matches no OpenCL device" in str(error.value) and info.platform_name in str(error.value)
    monkeypatch.setenv("PYOPENCL_CTX", "no such device")
    with pytest.raises(CLUnavailableError) as error:
        CLContext()
    assert "PYOPENCL_CTX" in str(error.value)


def test_kernel_values_match_the_pinned_spline() -> None:
    # The reference's spline is the formula; spot values checked by hand:
    # W(0) = 8/(pi h^3), W(1/2) = 8/(pi h^3) * 0.25, W(1) = 0.
    q = np.array([0.0, 0.5, 1.0, 1.5])
    expected = 8 / (math.pi * H**3) * np.array([1.0, 0.25, 0.0, 0.0])
    np.testing.assert_allclose(cubic_spline(q, H), expected, rtol=1e-12, atol=1e-12)


def test_auto_choice_is_the_first_device_that_builds(monkeypatch: pytest.MonkeyPatch) -> None:
    """GPUs, then accelerators, then CPUs, in platform order; devices that cannot build a kernel
    are skipped (on AMD Zen 5 the PyPI PoCL is listed but fails, Debian's PoCL works)."""
    import pyopencl

    monkeypatch.delenv("PYOPENCL_CTX", raising=False)
    order = {"gpu": 0, "accelerator": 1, "cpu": 2, "other": 3}
    candidates = sorted(list_devices(), key=lambda pair: order[pair[0].device_type])
    working = [info for info, device in candidates if probe_device(pyopencl, device)[1] is None]
    assert working, "no OpenCL device can build kernels here"
    with CLContext() as chosen:
        assert chosen.device_info == working[0]
