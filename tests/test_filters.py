"""The GPU depth filters against the numpy reference in `reference_filters.py`.

Tolerance: depths are ~2 scene units and a pixel sums at most a few hundred float32 terms, so
accumulation error is ~1e-6 relative; GLSL's exp() on llvmpipe is within a few ulp. We allow
2e-5 absolute (1e-5 relative; measured at most 7e-6), far below what any wrong rule produces:
a box filter posing as a Gaussian differs by > 1e-2 on the same image (BOX_DIFFERENCE, asserted
for every filter and image below, so this test can fail; measured 1.6e-2 at the least).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from reference_filters import ambiguous_reach, filter_depth, temperature_blur
from single_passes import SinglePasses

from sphrender.server.engine.passes import smooth
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import QualityConfig
from sphrender.server.scene.schema_quality import FilterName

RADIUS = 0.01
PX_PER_UNIT = 260.0  # r_px = 1.3 px at z = 2
TOLERANCE = 2e-5
BOX_DIFFERENCE = 1e-2  # 500 x TOLERANCE


def synthetic_depth(height: int = 36, width: int = 44) -> np.ndarray:
    """Smooth surface + particle-scale noise, a background hole, a near block (step of 30 r)
    and a far block (step of 15 r): every branch of every filter is exercised."""
    rng = np.random.default_rng(3)
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    depth = 2.0 + 0.05 * np.sin(x / 5.0) * np.cos(y / 7.0) + rng.uniform(-1, 1, x.shape) * RADIUS
    depth[(x - 30) ** 2 + (y - 10) ** 2 < 25] = 0.0  # hole: background
    depth[22:30, 6:16] -= 30 * RADIUS  # a nearer block
    depth[4:10, 4:12] += 15 * RADIUS  # a farther block
    return depth.astype(np.float32)


# The separable narrow range without quality.normal_guide: the numpy reference has no guide.
NO_GUIDE = 0.0

QUALITIES = {
    "gaussian-separable": QualityConfig(filter="gaussian", separable=True, iterations=1),
    "gaussian-2d": QualityConfig(filter="gaussian", separable=False, iterations=1),
    "bilateral-separable": QualityConfig(filter="bilateral", separable=True, iterations=2),
    "bilateral-2d": QualityConfig(filter="bilateral", separable=False, iterations=1),
    "narrow-range-separable": QualityConfig(
        filter="narrow_range", separable=True, iterations=2, normal_guide=NO_GUIDE
    ),
    "narrow-range-2d": QualityConfig(filter="narrow_range", separable=False, iterations=1),
    # the passes as they were before quality.last_pass_sigma (the others: its default 0.5)
    "narrow-range-equal-passes": QualityConfig(
        filter="narrow_range", iterations=2, last_pass_sigma=1.0, normal_guide=NO_GUIDE
    ),
    # the light last pass across the axis filtered last (x y y x, then y at 0.3 sigma; x y,
    # then x at 0.45 sigma; values whose reaches on these images are unambiguous)
    "narrow-range-destreak": QualityConfig(
        filter="narrow_range", iterations=2, destreak=0.3, normal_guide=NO_GUIDE
    ),
    "gaussian-destreak": QualityConfig(filter="gaussian", iterations=1, destreak=0.45),
    # depth_falloff's linear decline (eq 25): depths 1.65..2.2 straddle falloff_depth 2.0;
    # 3 sigma = 7.5 px up to it, losing 9 px per unit beyond it (down to 5.7 px)
    "gaussian-depth-falloff": QualityConfig(
        filter="gaussian",
        kernel_size="depth_falloff",
        falloff_sigma_px=2.5,
        falloff_depth=2.0,
        falloff_rate=9.0,
    ),
}


def assert_matches_reference(
    renderer: SurfaceRenderer,
    depth: np.ndarray,
    px_per_unit: float,
    quality: QualityConfig,
    *,
    box_check: bool = True,
) -> None:
    """GPU = numpy within TOLERANCE; `box_check`: and the image tells a Gaussian from a box
    (off for images too smooth for it: the test then shows its own sensitivity)."""
    quality = replace(quality, close_gaps=0.0)  # the reference is the filter alone
    gpu = SinglePasses(renderer).filter_depth_image(
        depth, particle_radius=RADIUS, px_per_unit=px_per_unit, quality=quality
    )
    reference = filter_depth(depth, RADIUS, px_per_unit, quality)
    ambiguous = np.vectorize(lambda z: z > 0 and ambiguous_reach(z, RADIUS, px_per_unit, quality))(
        depth
    )
    assert not ambiguous.any(), "pick a synthetic image whose kernel reaches are unambiguous"
    assert np.array_equal(gpu > 0, depth > 0), "background must stay background, surface surface"
    error = np.abs(gpu - reference)
    if quality.filter == "narrow_range" and quality.separable and quality.crease_angle > 0.0:
        # The crease test is a hard limit on float32 products: a chord pair within the GPU's
        # rounding of it flips the test at one far tap (on the 72 x 90 image, with an atan
        # form of the test: 1 pixel at 30 and 45 deg, none at 29 and 31), and the later passes
        # carry it to a few neighbours (up to 11 pixels, 0.11 r). At most 1 pixel in 200,
        # each within 0.25 r.
        flipped = error > TOLERANCE
        assert flipped.sum() <= max(1, error.size // 200), f"{flipped.sum()} pixels differ"
        assert error.max() <= 0.25 * RADIUS, f"max |gpu - numpy| = {error.max():.3g}"
        error = np.where(flipped, 0.0, error)
    assert error.max() <= TOLERANCE, f"max |gpu - numpy| = {error.max():.3g}"

    # The comparison is sharp enough to catch the classic porting bug: spatial weights that
    # degenerate to a box filter.
    if not box_check:
        return
    box = filter_depth(depth, RADIUS, px_per_unit, quality, box=True)
    assert np.abs(gpu - box).max() > BOX_DIFFERENCE


@pytest.mark.parametrize("name", list(QUALITIES))
def test_filter_matches_numpy_reference(renderer: SurfaceRenderer, name: str) -> None:
    assert_matches_reference(renderer, synthetic_depth(), PX_PER_UNIT, QUALITIES[name])


SEPARABLE = [name for name, quality in QUALITIES.items() if quality.separable]


@pytest.mark.parametrize("width", [41, 42, 43])
@pytest.mark.parametrize("name", SEPARABLE)
def test_packed_filters_at_widths_not_divisible_by_four(
    renderer: SurfaceRenderer, name: str, width: int
) -> None:
    """The separable filters work on four pixels per texel; the image's last texel is partly
    outside it (those pixels must read as background, not as garbage or as edge copies)."""
    depth = synthetic_depth()[:, :width]  # cropped: the same (unambiguous) values
    assert_matches_reference(renderer, depth, PX_PER_UNIT, QUALITIES[name])


@pytest.mark.parametrize("name", SEPARABLE)
def test_packed_filters_with_wide_and_capped_kernels(renderer: SurfaceRenderer, name: str) -> None:
    """Kernels reaching across many packed texels (r_px = 4.6 at z = 2: reach ~28 px, sliding
    seven texel pairs per side), kernels capped by kernel_max_px, and kernels spread past the
    cap (every pixel out to 7, then every 2nd or 3rd out to 3 sigma, less near the image's
    ends: groups of each spacing, per texel, and reaches cut by the room to the ends)."""
    depth = synthetic_depth(height=72, width=90)
    # last_pass_sigma 0.5 (first pass sqrt(1.75) sigma): the default 0.7's first pass at
    # sqrt(1.51) sigma has ambiguous reaches on this image (the other tests run the default)
    quality = QUALITIES[name]
    if quality.last_pass_sigma == QualityConfig().last_pass_sigma:
        quality = replace(quality, last_pass_sigma=0.5)
    assert_matches_reference(renderer, depth, 920.0, quality)
    capped = replace(quality, kernel_max_px=11, kernel_max_stride=1)
    assert_matches_reference(renderer, depth, 920.0, capped)
    spread = replace(quality, kernel_max_px=7, kernel_max_stride=3)
    assert_matches_reference(renderer, depth, 920.0, spread)
    # cap 6: the row walk's whole texels end at 8, the spread taps start past them
    assert_matches_reference(renderer, depth, 920.0, replace(spread, kernel_max_px=6))


def perspective_plane(height: int, width: int, px_per_unit: float) -> np.ndarray:
    """The eye depth of a plane tilted towards the bottom of the image, seen in perspective:
    1/z is affine in the pixel coordinates (z 0.25 at the bottom row to 0.43 at the top of a
    180-row image at 247 px per unit, as a pool filling a close-up)."""
    rows = np.arange(height, dtype=np.float64)[:, None] * np.ones((1, width))
    cols = np.arange(width, dtype=np.float64)[None, :]
    inverse = 1.0 / 0.32 + 2.2 * (rows - (height - 1) / 2) / px_per_unit + 0.3 * cols / 1e3
    return (1.0 / inverse).astype(np.float32)


PLANE_QUALITIES = {
    "separable": QualityConfig(),
    "separable-capped": QualityConfig(kernel_max_px=11),
    "2d": QualityConfig(separable=False, iterations=1),
}


@pytest.mark.parametrize("name", list(PLANE_QUALITIES))
def test_narrow_range_keeps_a_plane_in_perspective_up_to_the_image_edges(
    renderer: SurfaceRenderer, name: str
) -> None:
    """The narrow range averages inverse depth, which is affine over a plane, and where a kernel
    reaches past the image's end it fits a line (plane) through the inverse depths inside: a
    plane filling the image is a fixed point, edges included. An average of z bends it by half
    its second derivative times sigma^2 (0.12 r here), a fit of z at the edges by 0.06 r, a
    one-sided mean without the fit by its slope times the taps' mean offset. (Dropping the taps
    past the end, the old rule, is exact on a plane too: `test_engine_groundtruth`'s slab that
    fills the image is what shows its unsmoothed edges.) Bound: float32 sums of a few hundred
    terms, 1e-5 of z relative at worst (at z = 0.3, 3e-4 r; 2e-3 r allows the 2-D plane fit's
    normal equations; measured 6.6e-5 r for the 1-D passes, 6.4e-4 r for the 2-D)."""
    px_per_unit = 247.0
    quality = replace(PLANE_QUALITIES[name], close_gaps=0.0)
    height, width = (180, 320) if quality.separable else (60, 90)
    depth = perspective_plane(height, width, px_per_unit)
    out = SinglePasses(renderer).filter_depth_image(
        depth, particle_radius=RADIUS, px_per_unit=px_per_unit, quality=quality
    )
    error = np.abs(out.astype(np.float64) - depth) / RADIUS
    assert error.max() <= 2e-3, f"max |filtered - plane| = {error.max():.3g} r"


@pytest.mark.parametrize("margin", [0, 1, 3, 4, 5, 11, 64])
@pytest.mark.parametrize("size", [(1, 1), (7, 3), (41, 20), (44, 9), (130, 140)])
def test_border_split_gives_every_texel_near_an_image_end_to_the_border_variant(
    size: tuple[int, int], margin: int
) -> None:
    """Brute force over every texel: the inside part holds only texels all of whose pixels lie
    more than `margin` pixels from both ends along the axis (a kernel at most that long stays
    in the image there), and the parts tile the packed image without overlap."""
    from sphrender.server.engine.geometry.screen_box import packed_border_split

    width, height = size
    texels = ((width + 3) // 4, height)
    for axis in (0, 1):
        inside, strips = packed_border_split(size, axis, margin)
        cover = np.zeros((texels[1], texels[0]), np.int32)
        for x, y, w, h in ([inside] if inside is not None else []) + strips:
            cover[y : y + h, x : x + w] += 1
        assert (cover == 1).all(), f"axis {axis}: texels covered {np.unique(cover)} times"
        if inside is None:
            continue
        x, y, w, h = inside
        for tx in range(x, x + w):
            for ty in range(y, y + h):
                pixels = [4 * tx + i for i in range(4) if 4 * tx + i < width] if axis == 0 else [ty]
                end = width if axis == 0 else height
                assert all(margin <= p <= end - 1 - margin for p in pixels), (axis, tx, ty)


@pytest.mark.parametrize("filter_name", ["narrow_range", "gaussian", "bilateral"])
def test_border_variant_gives_the_packed_walks_result_bit_for_bit_inside(
    renderer: SurfaceRenderer, monkeypatch: pytest.MonkeyPatch, filter_name: FilterName
) -> None:
    """A separable filter is drawn as the packed walk inside and as the border variant in
    strips at the image's ends; where no tap crosses an end the two add the same terms in the
    same order, so drawing the variant everywhere changes no bit (no seam where the strips
    end). With a hard cap: spread taps (kernel_max_stride) belong to the packed walk only,
    the strips keep the cap by design (their kernels are cut at the cap either way)."""
    from sphrender.server.engine.passes import smooth

    depth = synthetic_depth(height=72, width=90)
    quality = QualityConfig(
        filter=filter_name, kernel_max_px=11, kernel_max_stride=1, close_gaps=0.0
    )

    def run() -> np.ndarray:
        return SinglePasses(renderer).filter_depth_image(
            depth, particle_radius=RADIUS, px_per_unit=920.0, quality=quality
        )

    split = run()
    everywhere = smooth.packed_border_split
    monkeypatch.setattr(
        smooth, "packed_border_split", lambda size, axis, _: everywhere(size, axis, 10**6)
    )
    assert np.array_equal(run(), split)


def test_filter_smooths_noise_and_keeps_steps(renderer: SurfaceRenderer) -> None:
    """Behavioural check of the narrow-range filter: particle-scale noise shrinks, the 30 r step
    to the nearer block stays a step (not blurred into a ramp)."""
    depth = synthetic_depth()
    quality = QualityConfig()
    out = SinglePasses(renderer).filter_depth_image(
        depth, particle_radius=RADIUS, px_per_unit=PX_PER_UNIT, quality=quality
    )
    flat = np.s_[14:20, 20:28]
    assert np.std(np.diff(out[flat], axis=1)) < 0.3 * np.std(np.diff(depth[flat], axis=1))
    step_before = depth[26, 17] - depth[26, 14]
    step_after = out[26, 17] - out[26, 14]
    assert step_after > 0.8 * step_before


def filament_on_a_slope(height: int = 30, width: int = 40) -> np.ndarray:
    """A plane sloping by 0.4 r per pixel along x with particle-scale noise, and a filament
    (rows 13-17, 5 px tall, along x) 6 r in front of it: inside lambda = 10 r, so the narrow
    range alone takes the plane into the filament's average across it (the kernel, reach
    8 px, is wider than it); the first pass, along x, runs along it."""
    rng = np.random.default_rng(7)
    x = np.mgrid[0:height, 0:width][1].astype(np.float64)
    depth = 2.0 + 0.4 * RADIUS * (x - width / 2) + rng.uniform(-0.3, 0.3, x.shape) * RADIUS
    depth[13:18, 6:34] -= 6.0 * RADIUS
    return depth.astype(np.float32)


def test_pair_test_keeps_a_filament_in_front_of_a_surface_and_leaves_the_slope(
    renderer: SurfaceRenderer,
) -> None:
    """quality.narrow_range_pairs: across the filament, a mirrored pair whose two taps both lie
    on the plane 6 r behind departs from the filament's centre line by 6 r > 4 r and is
    dropped (from the second pass on: the first runs along the filament); without it the
    filament is pulled back towards the plane. Both match the numpy reference, and so does the
    transposed image (a filament across the first pass's axis, where only the first pass
    differs from the reference if it tests pairs: it must not). What the test
    keeps is the filament's middle: its edge rows still average with the plane across their
    one-sided pairs (a pair with one tap on each departs by 3 r), and the next pass takes
    those into the middle's average, so the centre line moves back by 1.89 r with the test
    and by 3.03 r without (measured); bounds 2.3 / 2.6 r, either side of both. Far from it the
    plane's noise is smoothed the same with and without (the slope's pairs never depart;
    1e-4 r)."""
    depth = filament_on_a_slope()
    # the pair test alone (the crease test and the normal guide would stop kernels at the
    # filament's sides too; the reference has neither)
    on = QualityConfig(
        filter="narrow_range",
        iterations=2,
        narrow_range_pairs=4.0,
        crease_angle=0,
        normal_guide=NO_GUIDE,
    )
    off = replace(on, narrow_range_pairs=0.0)
    results = {}
    for name, quality in (("on", on), ("off", off)):
        # too smooth for the box check; the on/off difference below is this test's own
        assert_matches_reference(renderer, depth, PX_PER_UNIT, quality, box_check=False)
        results[name] = SinglePasses(renderer).filter_depth_image(
            depth,
            particle_radius=RADIUS,
            px_per_unit=PX_PER_UNIT,
            quality=replace(quality, close_gaps=0.0),
        )
    # across the first pass's axis (a filament along y): the first pass keeps its pairs
    # there, and the reference, which never tests them on the first pass, must still agree
    assert_matches_reference(
        renderer, np.ascontiguousarray(depth.T), PX_PER_UNIT, on, box_check=False
    )
    line = np.s_[15, 14:26]
    pulled = {n: float(np.mean(out[line] - depth[line])) / RADIUS for n, out in results.items()}
    assert pulled["on"] < 2.3 and pulled["off"] > 2.6, pulled
    far = np.s_[:5, :]  # 8 px from the filament: out of every kernel's reach
    assert np.abs(results["on"][far] - results["off"][far]).max() / RADIUS < 1e-4


def test_kernel_scale_changes_result(renderer: SurfaceRenderer) -> None:
    depth = synthetic_depth()
    narrow = SinglePasses(renderer).filter_depth_image(
        depth, particle_radius=RADIUS, px_per_unit=PX_PER_UNIT, quality=QualityConfig()
    )
    wide = SinglePasses(renderer).filter_depth_image(
        depth,
        particle_radius=RADIUS,
        px_per_unit=PX_PER_UNIT,
        quality=replace(QualityConfig(), kernel_scale=4.0),
    )
    assert np.abs(narrow - wide).max() > 1e-3


def test_temperature_blur_matches_numpy_reference(renderer: SurfaceRenderer) -> None:
    """The depth-aware temperature blur (shade stage) against `reference_filters.
    temperature_blur`, on the synthetic depth image (steps, hole) with a temperature ramp plus
    per-particle noise. Kelvin values ~1e3 and float32 sums of <= 50 terms: 1e-5 relative
    (measured below 2e-6). A blur that ignored the depth guide differs by far more (asserted)."""
    from sphrender.server.engine.passes.temperature import (
        TEMPERATURE_DEPTH_RANGE_RADII,
        TEMPERATURE_MAX_REACH_PX,
        TEMPERATURE_SIGMA_RADII,
    )

    depth = synthetic_depth(height=40, width=90)
    rng = np.random.default_rng(6)
    columns = np.arange(depth.shape[1])[None, :]
    kelvin = (300.0 + 25.0 * columns + rng.uniform(-150, 150, depth.shape)).astype(np.float32)
    kelvin[depth <= 0] = 0.0
    for px_per_unit in (260.0, 900.0):  # reach 2-3 px, and 8-10 px
        gpu = SinglePasses(renderer).blur_temperature_image(
            kelvin, depth, particle_radius=RADIUS, px_per_unit=px_per_unit
        )
        reference = temperature_blur(
            kelvin,
            depth,
            RADIUS * px_per_unit,
            TEMPERATURE_SIGMA_RADII,
            TEMPERATURE_MAX_REACH_PX,
            TEMPERATURE_DEPTH_RANGE_RADII * RADIUS,
        )
        assert np.array_equal(gpu > 0, depth > 0)
        error = np.abs(gpu - reference) / np.maximum(reference, 1.0)
        assert error.max() <= 1e-5, f"max relative |gpu - numpy| = {error.max():.3g}"
        unguided = temperature_blur(
            kelvin,
            depth,
            RADIUS * px_per_unit,
            TEMPERATURE_SIGMA_RADII,
            TEMPERATURE_MAX_REACH_PX,
            np.inf,
        )
        assert (np.abs(gpu - unguided) / np.maximum(unguided, 1.0)).max() > 1e-2


def test_temperature_border_variant_gives_the_same_bits_inside(
    renderer: SurfaceRenderer, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The temperature blur's variant at the image's ends adds the same terms as the plain one
    where no tap falls past an end: drawn everywhere, it changes no bit (no seam where its
    strips end)."""
    from sphrender.server.engine.passes import temperature

    depth = synthetic_depth(height=40, width=120)
    columns = np.arange(depth.shape[1])[None, :]
    kelvin = np.where(depth > 0, 300.0 + 20.0 * columns + 0 * depth, 0.0).astype(np.float32)

    def run() -> np.ndarray:
        return SinglePasses(renderer).blur_temperature_image(
            kelvin, depth, particle_radius=RADIUS, px_per_unit=900.0
        )

    split = run()
    everywhere = temperature.packed_border_split
    monkeypatch.setattr(
        temperature, "packed_border_split", lambda size, axis, _: everywhere(size, axis, 10**6)
    )
    assert np.array_equal(run(), split)


def ridge(
    height: int = 30, width: int = 40, px_per_unit: float = PX_PER_UNIT, middle: float = 14.5
) -> tuple[np.ndarray, np.ndarray]:
    """Two planes meeting at a ridge along x (row `middle`) nearest the eye, each at 45 deg to
    the image plane (depth slope one pixel's width, 0.77 r per pixel at r_px = 1.3 at z = 2: a
    90 deg crease), with particle-scale noise of +-0.3 r: (the true depth, the noisy one)."""
    rng = np.random.default_rng(11)
    y = np.mgrid[0:height, 0:width][0].astype(np.float64)
    plane = 2.0 + 0.77 * RADIUS * (PX_PER_UNIT / px_per_unit) * np.abs(y - middle)
    noisy = plane + rng.uniform(-0.3, 0.3, y.shape) * RADIUS
    return plane.astype(np.float32), noisy.astype(np.float32)


def test_crease_test_keeps_a_ridge_and_smooths_the_faces(renderer: SurfaceRenderer) -> None:
    """quality.crease_angle: the kernels across the ridge stop where the chords turn by more
    than 30 deg, so the rows within 3 px of it keep nearer their true depth: 0.80 r mean
    error with the test, 1.26 r without (measured; bound 0.8x, between 0.64x and 1). Far from
    it (8 px on) the faces' noise is smoothed as without the test: no chord turns there but
    the noise's, over runs shorter than a projected radius (0.02-0.03 r both; bound +0.01 r).
    Both match the numpy reference, which has no normal guide (off here)."""
    truth, depth = ridge()
    on = QualityConfig(
        filter="narrow_range", iterations=2, crease_angle=30.0, normal_guide=NO_GUIDE
    )
    off = replace(on, crease_angle=0.0)
    errors = {}
    for name, quality in (("on", on), ("off", off)):
        assert_matches_reference(renderer, depth, PX_PER_UNIT, quality, box_check=False)
        smoothed = SinglePasses(renderer).filter_depth_image(
            depth,
            particle_radius=RADIUS,
            px_per_unit=PX_PER_UNIT,
            quality=replace(quality, close_gaps=0.0),
        )
        errors[name] = np.abs(smoothed - truth)[:, 8:32] / RADIUS  # clear of the image's ends
    near = slice(12, 18)
    faces = np.r_[0:7, 23:30]
    assert errors["on"][near].mean() < 0.8 * errors["off"][near].mean()
    assert errors["on"][faces].mean() <= errors["off"][faces].mean() + 0.01


def guide_on_and_off() -> tuple[QualityConfig, QualityConfig]:
    """The narrow range with quality.normal_guide at its default (as balanced and best have it)
    and without it."""
    on = QualityConfig(filter="narrow_range", iterations=2, close_gaps=0.0)
    assert on.normal_guide > 0.0
    return on, replace(on, normal_guide=0.0)


GUIDE_PX_PER_UNIT = 520.0  # r_px = 2.6 at z = 2


def test_normal_guide_keeps_a_ridge_and_smooths_the_faces(renderer: SurfaceRenderer) -> None:
    """quality.normal_guide: the kernels stop at the limits found on the quarter-size pilot, so
    the rows within 6 px (2.3 projected radii) of a 90 deg ridge stay near their true depth.
    The ridge is placed at each half pixel across one 4-row block of the guide's quarter grid,
    where its effect varies most: 0.06-0.20 r of the guide-less filter's 1.22-1.28 r mean error
    there (measured; bound 0.3x). Far from it (20 px on, clear of the image's ends) the faces'
    noise is smoothed as without: 0.0373 against 0.0371 r mean error (bound +0.002 r; a
    guide that cut the faces' taps would leave the noise's 0.15 r). At r_px 1.3 (the crease
    test's ridge) the pilot is too coarse for every placement: 0.12-0.94x by where the ridge
    falls on the quarter grid, hence r_px 2.6 here."""
    on, off = guide_on_and_off()
    height, width = 100, 80
    rows = np.arange(height)
    for middle in np.arange(46.0, 50.01, 0.5):
        truth, depth = ridge(height, width, GUIDE_PX_PER_UNIT, middle)
        errors = {}
        for name, quality in (("on", on), ("off", off)):
            smoothed = SinglePasses(renderer).filter_depth_image(
                depth, particle_radius=RADIUS, px_per_unit=GUIDE_PX_PER_UNIT, quality=quality
            )
            assert np.array_equal(smoothed > 0, depth > 0)
            errors[name] = np.abs(smoothed - truth)[:, 16:64] / RADIUS  # clear of the ends
        near = np.abs(rows - middle) <= 6
        far = (np.abs(rows - middle) >= 20) & (rows >= 8) & (rows < height - 8)
        assert errors["on"][near].mean() < 0.3 * errors["off"][near].mean(), middle
        assert errors["on"][far].mean() <= errors["off"][far].mean() + 0.002, middle


@pytest.mark.parametrize(
    ("height", "width", "px_per_unit"), [(30, 40, PX_PER_UNIT), (60, 80, 520.0)]
)
def test_normal_guide_leaves_a_plane_alone(
    renderer: SurfaceRenderer, height: int, width: int, px_per_unit: float
) -> None:
    """On a noisy tilted plane no pilot normal turns past the guide's limit, so no tap is cut,
    the weights stay symmetric and the line fit is the mean: the result is the guide-less one
    within 1e-3 r (measured 1.2e-4 r at most: the float32 sums' order; one cut tap moves a
    pixel by a fraction of the noise's 0.3 r)."""
    rng = np.random.default_rng(5)
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    slope = RADIUS * PX_PER_UNIT / px_per_unit  # the same tilt at either scale
    plane = 2.0 + 0.4 * slope * x + 0.2 * slope * y
    depth = (plane + rng.uniform(-0.3, 0.3, x.shape) * RADIUS).astype(np.float32)
    results = [
        SinglePasses(renderer).filter_depth_image(
            depth, particle_radius=RADIUS, px_per_unit=px_per_unit, quality=quality
        )
        for quality in guide_on_and_off()
    ]
    inner = np.s_[height // 4 : height - height // 4, width // 5 : width - width // 5]
    assert np.abs(results[0] - results[1])[inner].max() < 1e-3 * RADIUS


NO_CODE = 4095  # guide_limits.frag.glsl: no limit on that side


def crease_runs_reference(codes: np.ndarray, axis: int, run: int, shift: int) -> np.ndarray:
    """numpy's reading of guide_runs.frag.glsl: a side's limit is kept where that side has
    limits in at least `run` neighbouring lines across the pass (rows for axis 0) in a row,
    each within `shift` pixels along the pass of the last (the nearest; ties: the lower)."""
    sides = np.stack([codes // 4096, codes % 4096])  # plus, minus
    if axis == 1:
        sides = sides.transpose(0, 2, 1)  # lines across the pass: columns
    limited = sides < NO_CODE
    lines, along = limited.shape[1:]

    def nearest_first(offset: int) -> tuple[int, int]:
        return abs(offset), offset

    kept = sides.copy()
    for side in (0, 1):
        for line, x in zip(*np.nonzero(limited[side]), strict=True):
            length = 1
            for step in (1, -1):
                at = x
                for d in range(1, run):
                    other = line + step * d
                    if not 0 <= other < lines:
                        break
                    near = [at + o for o in sorted(range(-shift, shift + 1), key=nearest_first)]
                    near = [a for a in near if 0 <= a < along and limited[side, other, a]]
                    if not near:
                        break
                    at = near[0]
                    length += 1
            if length < run:
                kept[side, line, x] = NO_CODE
    if axis == 1:
        kept = kept.transpose(0, 2, 1)
    return (kept[0] * 4096 + kept[1]).astype(np.float32)


def test_normal_guide_keeps_limits_on_crease_lines_only(renderer: SurfaceRenderer) -> None:
    """The guide's crease runs (guide_runs.frag.glsl): a one-sided limit survives only on a
    line of limits on the same side GUIDE_RUN long across the pass, stepping at most
    GUIDE_RUN_SHIFT along it between lines (a box edge); a shorter spot (a fold, a ripple's
    crest) loses it. Against the numpy reading of the rule, exactly (codes are integers), on
    random limits and on lines drawn to either side of each bound."""
    run, shift = smooth.GUIDE_RUN, smooth.GUIDE_RUN_SHIFT
    rng = np.random.default_rng(7)
    height, width = 2 * run + 6, 31 + (shift + 1) * run + 4
    shape = (height, width)
    plus = np.where(rng.random(shape) < 0.15, rng.integers(4, 40, shape), NO_CODE)
    minus = np.where(rng.random(shape) < 0.1, rng.integers(4, 40, shape), NO_CODE)
    plus[:, 28:] = NO_CODE  # the random part ends clear of the drawn lines
    minus[:, 28:] = NO_CODE
    short = 31 + run + shift + 2
    for i in range(run):
        plus[1 + i, 31 + i] = 9  # a line `run` long, stepping 1 along the pass: kept
        minus[1 + i, short] = 9 if i < run - 1 else NO_CODE  # one line short of it: gone
        plus[run + 3 + i, 31 + (shift + 1) * i] = 9  # stepping past the bound: gone
    codes = (plus * 4096 + minus).astype(np.float32)
    kept = SinglePasses(renderer).guide_crease_runs(codes)
    for axis in (0, 1):
        assert np.array_equal(kept[axis], crease_runs_reference(codes, axis, run, shift)), axis
    rows = kept[0] // 4096
    assert (rows[1 : 1 + run, 30:] < NO_CODE).sum() == run
    assert (kept[0][:, short] % 4096 == NO_CODE).all()
    assert (rows[run + 3 :, 30:] == NO_CODE).all()
