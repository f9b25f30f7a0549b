"""Degenerate geometry (tests/fuzz_inputs.py's DEGENERATE_SHAPES: coincident, near-coincident,
coplanar, collinear, every particle in one grid cell) through each stage whose work grows with
how crowded a neighbourhood is: the field grid of the field normals, the splat's occlusion
culling, the SPH kernels (density, colour field, anisotropy) and density_below.

Each test checks an answer the geometry fixes (N coincident particles give one particle's image
and N times its density; a sheet's normals are its plane's) and bounds the work by counting it
(grid entries, representatives, quads splatted), never by timing it.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from fuzz_inputs import DEGENERATE_SHAPES
from sph_reference import cubic_spline, reference_sph

from sphrender.core.frame import make_frame
from sphrender.server.engine.frame_output import RenderedFrame, RenderStats
from sphrender.server.engine.passes import field_grid
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.engine.sph import crowd
from sphrender.server.engine.sph.anisotropy import AnisotropyParameters
from sphrender.server.engine.sph.engine import SphEngine, SphParameters
from sphrender.server.scene import scene_from_dict

R = 0.02
H = 4 * R
MASS = 1000.0 * (2 * R) ** 3
CENTRE = np.array([0.01, -0.02, 0.015])
EYE = np.array([0.1, 0.08, 0.15])  # the camera's offset from CENTRE: a particle ~10 px wide
#: Enough particles that the splat's occlusion culling runs (occlusion.MIN_PARTICLES).
N = 3000


def params() -> SphParameters:
    return SphParameters(
        support_radius=H,
        mass=MASS,
        rest_density=1000.0,
        surface_threshold=0.5 / H,
        sparse_density=750.0,
        safety_reach=0.5 * H,
    )


def scene(**quality: Any) -> Any:
    return scene_from_dict(
        {
            "image": {"width": 64, "height": 48},
            "camera": {"eye": (CENTRE + EYE).tolist(), "target": CENTRE.tolist(), "fov_y": 40.0},
            "particles": {"radius": R},
            "quality": quality,
        }
    )


def test_every_shape_is_generated_with_its_geometry() -> None:
    """The fuzzers' shapes are what their names say."""
    rng = np.random.default_rng(1)
    shapes = {name: make(rng, 500) for name, make in DEGENERATE_SHAPES.items()}
    assert set(shapes) == {"coincident", "near_coincident", "coplanar", "collinear", "one_cell"}
    assert np.ptp(shapes["coincident"], axis=0).max() == 0.0
    assert np.ptp(shapes["near_coincident"], axis=0).max() < 1e-5
    assert np.linalg.matrix_rank(shapes["coplanar"], tol=1e-9) == 2
    assert np.linalg.matrix_rank(shapes["collinear"], tol=1e-9) == 1
    assert np.ptp(shapes["one_cell"], axis=0).max() < H / 2


# -- field grid (field normals) -----------------------------------------------------------------


@pytest.fixture()
def grid_entries(monkeypatch: pytest.MonkeyPatch) -> Iterator[list[int]]:
    """How many entries each field-grid build sorted (the normals pass's work per pixel)."""
    counts: list[int] = []
    build = field_grid.FieldGrid.build

    def counting(self: field_grid.FieldGrid, *args: Any, **kwargs: Any) -> field_grid.BuiltGrid:
        built = build(self, *args, **kwargs)
        counts.append(self.sorted_count(built))
        return built

    monkeypatch.setattr(field_grid.FieldGrid, "build", counting)
    yield counts


def render(renderer: SurfaceRenderer, positions: np.ndarray) -> tuple[RenderedFrame, RenderStats]:
    return renderer.render(make_frame(positions), scene(), depth=True, normals=True)


def angles_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cosine = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.asarray(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))


@pytest.mark.parametrize("shape", ["coincident", "near_coincident"])
def test_coincident_particles_render_as_one(
    renderer: SurfaceRenderer, grid_entries: list[int], shape: str
) -> None:
    """N particles on one point (or within 1e-7 of it) give one particle's image: the same
    depth, the same normals (the field's gradient N times one particle's) and colour; the splat
    draws one of them and the field grid holds at most its 64 slots."""
    one, _ = render(renderer, CENTRE[None, :])
    rng = np.random.default_rng(3)
    noise = rng.normal(size=(N, 3)) * 1e-7 if shape == "near_coincident" else np.zeros((N, 3))
    positions = CENTRE + noise
    many, stats = render(renderer, positions)
    # The point lies on the view axis, on grid cells' corners: the noise straddles up to 8.
    assert stats.particles_splatted <= 8  # one per r/64 cell the noise straddles
    assert grid_entries and max(grid_entries) <= 8 * field_grid.SLOTS
    assert one.depth is not None and many.depth is not None
    covered = np.isfinite(one.depth)
    assert covered.sum() > 20
    np.testing.assert_array_equal(np.isfinite(many.depth), covered)
    # Exact up to float rounding; 1e-7 of noise moves the rims' grazing depths by ~1e-5.
    rtol = 1e-5 if shape == "coincident" else 1e-4
    np.testing.assert_allclose(many.depth[covered], one.depth[covered], rtol=rtol)
    assert one.normals is not None and many.normals is not None
    assert angles_deg(many.normals[covered], one.normals[covered]).max() < 0.1
    np.testing.assert_allclose(many.rgba, one.rgba, atol=2e-3)


def test_a_sheet_renders_with_its_planes_normal(
    renderer: SurfaceRenderer, grid_entries: list[int]
) -> None:
    """A dense sheet (coplanar, ~30 particles per grid cell) seen from above, its rims outside
    the image: the normals are the plane's normal, and the grid sorts fewer entries than
    particles (crowded cells merged)."""
    rng = np.random.default_rng(4)
    positions = CENTRE + np.column_stack([rng.uniform(-0.2, 0.2, (N, 2)), np.zeros(N)])
    rendered, _ = render(renderer, positions)
    assert grid_entries and max(grid_entries) < N
    assert rendered.normals is not None and rendered.depth is not None
    # The middle of the image, well inside the sheet's outline.
    middle = rendered.normals[16:32, 20:44]
    inside = middle[np.isfinite(rendered.depth[16:32, 20:44])]
    assert len(inside) > 100
    errors = angles_deg(inside, np.array([0.0, 0.0, 1.0]))
    assert np.median(errors) < 1.0 and np.percentile(errors, 90) < 5.0


def test_a_line_renders_with_normals_across_it(
    renderer: SurfaceRenderer, grid_entries: list[int]
) -> None:
    """Collinear particles (a dense line along x): a capsule, whose normals are perpendicular
    to the line along its length; the grid's entries stay bounded by its cells' slots."""
    rng = np.random.default_rng(5)
    positions = CENTRE + np.column_stack([rng.uniform(-0.3, 0.3, N), np.zeros((N, 2))])
    rendered, _ = render(renderer, positions)  # its ends outside the image
    cells = 0.6 / (H / 2) + 2
    assert grid_entries and max(grid_entries) <= cells * field_grid.SLOTS
    assert rendered.normals is not None and rendered.depth is not None
    covered = np.isfinite(rendered.depth)
    assert covered.sum() > 50
    inner = covered.copy()  # two pixels inside the outline: the depth filter bends the rims
    for axis in (0, 1):
        for step in (-2, 2):
            inner &= np.roll(covered, step, axis=axis)
    along = np.abs(rendered.normals[inner][:, 0])
    assert inner.sum() > 20 and np.median(along) < 0.05


# -- SPH ----------------------------------------------------------------------------------------


def test_coincident_particles_sum_as_copies(sph_engine: SphEngine) -> None:
    """N coincident particles: every density is N m W(0), the colour field N V W(0) = 1, the
    gradient zero; one representative carries them all."""
    positions = np.tile(CENTRE, (N, 1))
    merged = crowd.find_crowds(positions, H)
    assert merged is not None and merged.representatives.tolist() == [0]
    assert merged.weights.tolist() == [N]
    result = sph_engine.compute(positions, params(), splat_mask=True)
    expected = N * MASS * cubic_spline(np.zeros(1), H)[0]
    np.testing.assert_allclose(result.density, expected, rtol=1e-5)
    np.testing.assert_allclose(result.color_field, 1.0, rtol=1e-5)
    assert result.color_gradient is not None
    np.testing.assert_array_equal(result.color_gradient, 0.0)
    np.testing.assert_allclose(sph_engine.density(positions, params()), expected, rtol=1e-5)
    # The client's densities pass through; each volume m / rho is its own.
    client = np.full(N, 800.0, np.float32)
    given = sph_engine.compute(positions, params(), client)
    np.testing.assert_array_equal(given.density, client)
    volume_sum = N * MASS / 800.0 * cubic_spline(np.zeros(1), H)[0]
    np.testing.assert_allclose(given.color_field, volume_sum, rtol=1e-5)


@pytest.mark.parametrize("shape", ["near_coincident", "coplanar", "collinear", "one_cell"])
def test_sph_of_degenerate_shapes_matches_brute_force(sph_engine: SphEngine, shape: str) -> None:
    """Each shape's densities, colour field and gradient against the float64 reference (the
    crowded cells merged into at most crowd.CAP representatives each)."""
    rng = np.random.default_rng(6)
    scale = {"coplanar": 0.4, "collinear": 2.0}.get(shape, 1.0)
    positions = CENTRE + DEGENERATE_SHAPES[shape](rng, 2000) * scale
    merged = crowd.find_crowds(positions, H)
    if merged is not None:
        assert merged.weights.sum() == len(positions)
        cells = np.floor((positions[merged.representatives] - positions.min(0)) / H)
        _, per_cell = np.unique(cells, axis=0, return_counts=True)
        assert per_cell.max() <= crowd.CAP
    result = sph_engine.compute(positions, params())
    reference = reference_sph(positions, H, MASS)
    # Merging moves a particle by at most a sub-cell (h / 32 here): ~1 % of a kernel term.
    tolerance = 2e-2 if shape == "one_cell" else 1e-3
    np.testing.assert_allclose(result.density, reference.density, rtol=tolerance)
    np.testing.assert_allclose(result.color_field, reference.color_field, rtol=tolerance)


def anisotropy_params() -> AnisotropyParameters:
    return AnisotropyParameters(radius=2 * H, max_ratio=4.0, min_neighbours=25, smoothing=0.9)


@pytest.mark.parametrize(
    ("shape", "flat"), [("coplanar", True), ("collinear", False), ("coincident", None)]
)
def test_anisotropy_follows_the_shape(sph_engine: SphEngine, shape: str, flat: bool | None) -> None:
    """A sheet's ellipsoids are thinnest across it, a line's longest along it, and coincident
    particles stay spheres (no direction to stretch) with every other particle a neighbour."""
    rng = np.random.default_rng(7)
    if shape == "coplanar":
        positions = np.column_stack([rng.uniform(-0.1, 0.1, (N, 2)), np.zeros(N)])
    elif shape == "collinear":
        positions = np.column_stack([rng.uniform(-0.1, 0.1, N), np.zeros((N, 2))])
    else:
        positions = np.zeros((N, 3))
    result = sph_engine.anisotropy(positions, anisotropy_params(), R)
    middle = np.abs(positions[:, 0]) < 0.05
    if flat is None:
        assert result.is_sphere.all()
        assert (result.neighbour_count == N - 1).all()
        return
    assert not result.is_sphere[middle].any()
    lengths = np.linalg.norm(result.axes[middle], axis=1)  # per column (semi-axis)
    order = np.argsort(lengths, axis=1)
    columns = result.axes[middle][np.arange(middle.sum()), :, order[:, 0 if flat else 2]]
    axis = np.array([0.0, 0.0, 1.0]) if flat else np.array([1.0, 0.0, 0.0])
    alignment = np.abs(columns @ axis) / np.linalg.norm(columns, axis=1)
    assert np.median(alignment) > 0.99


def test_density_below_of_a_crowd(sph_engine: SphEngine) -> None:
    """A crowd of coincident particles is dense, a lone particle beside it is not; the crowd's
    buckets overflow density_below's slots, so its fallback (density, merged) answers."""
    positions = np.vstack([np.zeros((N, 3)), [[5 * H, 0.0, 0.0]]])
    below = sph_engine.density_below(positions, params(), 0.5 * 1000.0)
    assert not below[:N].any() and below[N]
