"""The surface bench's metrics against analytic cases: the shift-tolerant band error, the
truth's own flicker, the multi-metric front, and the jitter's two readings."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from benchmarks.studies.dam_frames import (
    DamCounts,
    DamFrameRow,
    all_finite,
    band_ratios,
    dam_frames_section,
    surface_notes,
)
from benchmarks.studies.jitter_readings import (
    READINGS,
    JitterReadingRow,
    case_flicker_deg,
    jitter_readings_section,
    mean_move_r,
)
from sphrender.server.bench.report import surface_section
from sphrender.server.bench.scenes import Truth, sphere_truth
from sphrender.server.bench.surface_bench import (
    PLAIN_SMOOTHING,
    UNFILTERED,
    SurfaceResults,
    SurfaceRow,
    spatter_case,
    surface_front,
)
from sphrender.server.bench.surface_quality import (
    band_error_deg,
    jittered,
    shift_tolerant_band_error_deg,
    silhouette_band,
    split_flicker_deg,
    truth_flicker_deg,
)
from sphrender.server.engine.frame_output import RenderedFrame
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import CameraConfig

CAMERA = Camera.from_config(CameraConfig(eye=(0.0, 0.0, 1.0), target=(0.0, 0.0, 0.0)), 120, 90)
R = 0.2


def as_frame(truth: Truth) -> RenderedFrame:
    rgba = np.zeros((*truth.hit.shape, 4), np.float32)
    depth = np.where(truth.hit, truth.depth, np.inf).astype(np.float32)
    return RenderedFrame(rgba, depth, truth.normals.astype(np.float32))


def test_shift_tolerance_forgives_a_one_pixel_rim_and_nothing_else() -> None:
    """The exact sphere shifted by one pixel: the plain band error is large (the normal turns
    by tens of degrees within a pixel of the rim), the tolerant one is 0 up to float32
    rounding, since every shifted pixel's normal is the truth's one pixel away. Normals
    flipped to face away from the rim (mirrored in the image plane) match nothing: the tolerant
    error stays at least half the plain one. The identical render scores 0 on both."""
    truth = sphere_truth(CAMERA, np.zeros(3), R)
    band = silhouette_band(truth, R / 10)
    same = as_frame(truth)
    assert band_error_deg(same, truth, band) < 0.05
    assert shift_tolerant_band_error_deg(same, truth, band) < 0.05
    pixel = 1.0 / CAMERA.pixels_per_unit_at_unit_depth  # one pixel at eye depth 1
    shifted = sphere_truth(CAMERA, np.array([pixel, 0.0, 0.0]), R)
    frame = as_frame(shifted)
    plain = band_error_deg(frame, truth, band)
    tolerant = shift_tolerant_band_error_deg(frame, truth, band)
    assert plain > 3.0 and tolerant < 0.25 * plain, (plain, tolerant)  # measured 5.6 / 0.57
    flipped = truth.normals * np.array([-1.0, -1.0, 1.0])
    bad = RenderedFrame(same.rgba, same.depth, flipped.astype(np.float32))
    assert shift_tolerant_band_error_deg(bad, truth, band) > 0.5 * band_error_deg(bad, truth, band)
    assert shift_tolerant_band_error_deg(bad, truth, band) > 60.0
    # Reversed normals: each truth normal within one pixel turns by at most a few degrees from
    # its neighbour's (the rim's steepest turn per pixel at R_px ~ 27: ~15 deg), so the error
    # stays above 180 - 15; a match against the truth's background (zero normals) would give 90.
    reversed_ = RenderedFrame(same.rgba, same.depth, -truth.normals.astype(np.float32))
    assert shift_tolerant_band_error_deg(reversed_, truth, band) > 150.0


def test_split_flicker_recombines_to_the_mean_and_puts_the_rims_turn_in_the_band() -> None:
    """The moved sphere's flicker split at its silhouette band: the band's and the inside's
    means weighted by their shares give the whole mean back, and the rim, whose normals are
    grazing, turns by more than the inside (the surface bench's flicker floor argument)."""
    a = sphere_truth(CAMERA, np.zeros(3), R)
    b = sphere_truth(CAMERA, np.array([0.01 * R, 0.0, 0.0]), R)
    band = silhouette_band(a, R / 10)
    covered = a.hit & b.hit
    rim, inside, share = split_flicker_deg(a.normals, b.normals, covered, band)
    total = truth_flicker_deg(a, b)
    assert 0.0 < share < 0.5
    assert math.isclose(share * rim + (1.0 - share) * inside, total, rel_tol=1e-9)
    assert inside < total < rim
    assert math.isnan(split_flicker_deg(a.normals, b.normals, covered, np.zeros_like(band))[0])


def test_truth_flicker_of_a_moved_sphere_is_its_normal_turn() -> None:
    """A sphere moved sideways by d: at a pixel well inside the rim the normal turns by about
    d / R radians (for the ray through the centre exactly asin(d / R)); the mean over the
    covered pixels lies between that and a few times it (the turn grows towards the rim)."""
    d = 0.01 * R
    a = sphere_truth(CAMERA, np.zeros(3), R)
    b = sphere_truth(CAMERA, np.array([d, 0.0, 0.0]), R)
    flicker = truth_flicker_deg(a, b)
    turn = math.degrees(math.asin(d / R))
    assert turn <= flicker <= 4 * turn, (flicker, turn)
    assert truth_flicker_deg(a, a) < 1e-5  # arccos rounding


def test_surface_front_keeps_rows_not_beaten_on_every_column() -> None:
    def row(name: str, ms: float, flicker: float, ball: float = 1.0) -> SurfaceRow:
        return SurfaceRow(name, ms, 1.0, 0.05, flicker, 3.0, ball_mean_deg=ball)

    rows = [row("fast", 10, 3.0), row("slow", 20, 1.0), row("worse", 20, 3.0), row("nan", 30, 0.5)]
    rows += [row("ball", 20, 1.0, ball=0.5), row("ball again", 20, 1.0, ball=0.5)]
    names = [r.setting for r in surface_front(rows)]
    # slow: beaten by ball; worse: by fast; two equal rows do not beat each other
    assert names == ["fast", "nan", "ball", "ball again"]


def _dam_row(frame: str, setting: str, band: float, flicker: float, floor: float) -> DamFrameRow:
    return DamFrameRow(frame, setting, 5.0, band, flicker, floor, True)


def _with_analytic(row: DamFrameRow, alpha: float, silhouettes: float, drops: float) -> DamFrameRow:
    """`row` with sphere-union figures: half of its edge pixels gaps, lone droplets unless nan."""
    return replace(
        row,
        edge_alpha=alpha,
        edge_alpha_silhouettes=silhouettes,
        gap_share=0.5,
        gap_spheres=0.6,
        gap_alpha=0.9,
        gap_reference=1.0,
        droplet_deg=drops,
        droplet_px=10 if math.isfinite(drops) else 0,
    )


def test_dam_frames_section_counts_the_frames_that_meet_each_item() -> None:
    before, after = PLAIN_SMOOTHING.name, "preset balanced"
    rows = [
        _dam_row("F_1", before, 10.0, 1.0, 0.2),
        _with_analytic(_dam_row("F_1", after, 3.0, 0.1, 0.2), 0.05, 0.04, math.nan),
        _dam_row("F_9", before, 20.0, 2.0, 1.2),
        _with_analytic(_dam_row("F_9", after, 9.0, 1.1, 1.2), 0.15, 0.05, 2.0),
        # Just past the limit: its ratio must not print as the limit itself.
        _dam_row("F_13", before, 22.10, 1.0, 0.9),
        _with_analytic(_dam_row("F_13", after, 8.90, 0.8, 0.9), 0.2, 0.12, 5.0),
    ]
    for frame in ("F_1", "F_9", "F_13"):
        rows.append(replace(_dam_row(frame, UNFILTERED.name, 30.0, 4.0, 1.0), droplet_deg=3.0))
    assert band_ratios(rows, after) == {"F_1": 0.3, "F_9": 0.45, "F_13": 8.90 / 22.10}
    text = "\n".join(dam_frames_section(rows, after))
    row_9 = (
        "| 9 | 20.00 | 9.00 | 45.0 % | 5.00 | 1.100 | 1.200 | 0.150 / 0.050 | 2.00 (3.00) | yes |"
    )
    assert row_9 in text
    assert "| 13 | 22.10 | 8.90 | 40.3 % |" in text
    assert "on 1 of 3 frames (worst 45.0 %)" in text  # band: F_1 only
    assert "flicker <= 0.3° on 1 of 3 frames; the truth's own flicker is <= 0.3° on 1" in text
    assert "edge pixels on 1 of 3 frames (worst 0.200)" in text
    assert "silhouettes against background on 2 of 3 (worst 0.120)" in text
    assert "(50 % of the edge pixels, mean over the frames): there the spheres cover 0.60" in text
    # F_1 has no lone particle in view; F_13's 5.0 deg is past 1.2 x 3.0
    assert "droplet error <= 1.2x the unfiltered splat's on 1 of the 2 frames" in text
    assert "finite on every frame and setting: yes" in text
    # no baseline rows: no section
    assert dam_frames_section([r for r in rows if r.setting == after], after) == []
    # no unfiltered rows: no droplet verdict, no unfiltered figure in the table
    text = "\n".join(dam_frames_section([r for r in rows if r.setting != UNFILTERED.name], after))
    assert "droplet error" not in text and "| 2.00 | yes |" in text
    assert "| 1 | 10.00 | 3.00 | 30.0 % | 5.00 | 0.100 | 0.200 | 0.050 / 0.040 | - | yes |" in text


def test_all_finite_takes_inf_depth_as_no_surface_and_nothing_else() -> None:
    frame = as_frame(sphere_truth(CAMERA, np.zeros(3), R))
    assert frame.depth is not None and np.isinf(frame.depth).any()
    assert all_finite(frame)
    for name, index in (("rgba", (40, 60, 3)), ("normals", (40, 60, 0)), ("depth", (40, 60))):
        broken = as_frame(sphere_truth(CAMERA, np.zeros(3), R))
        getattr(broken, name)[index] = np.nan
        assert not all_finite(broken), name


def test_jitter_moves_by_a_gaussian_per_axis_or_by_exactly_the_fraction() -> None:
    """Per axis (the bench's): the same draws as before the fixed-length reading existed (the
    reference caches are keyed by the moved positions), lengths averaging sqrt(8 / pi) sigma
    = 1.596 sigma (a 3-D Gaussian's length; over 20,000 particles its standard error is
    0.673 sigma / sqrt(20,000) = 0.005 sigma: 0.03 sigma is 6 of them). Fixed length: every
    particle moved by exactly fraction * r, in directions with no preferred side (the mean
    offset within 6 standard errors of 0, each axis's spread r f / sqrt(3))."""
    rng = np.random.default_rng(3)
    positions = rng.uniform(-1e5, 1e5, (20_000, 3))  # far from the origin: float64 throughout
    r, f = 0.01, 0.02
    gaussian = jittered(positions, r, f, seed=4)
    expected = positions + np.random.default_rng(4).normal(0.0, f * r, positions.shape)
    np.testing.assert_array_equal(gaussian, expected)
    lengths = np.linalg.norm(gaussian - positions, axis=1) / (f * r)
    assert abs(lengths.mean() - math.sqrt(8.0 / math.pi)) < 0.03
    offsets = jittered(positions, r, f, seed=4, fixed_length=True) - positions
    np.testing.assert_allclose(np.linalg.norm(offsets, axis=1), f * r, rtol=1e-6)
    spread = f * r / math.sqrt(3.0)
    assert np.all(np.abs(offsets.mean(axis=0)) < 6 * spread / math.sqrt(len(offsets)))


def test_spatter_case_moves_its_particles_as_its_reading_says(renderer: SurfaceRenderer) -> None:
    """The spatter case under each reading (real EGL and PoCL, 160x90): the measured mean move
    is the reading's (exactly 2 % r; 1.596 x 2 % r within 5 % over its ~4,000 particles), and
    the flicker of the balanced preset is finite and not zero (the particles did move)."""
    from sphrender.server.bench.sweep import preset_setting

    balanced = preset_setting("balanced")
    moves = {}
    for _, fixed_length in READINGS:
        case, floor, _ = spatter_case(renderer, 160, 90, fixed_length=fixed_length)
        moves[fixed_length] = mean_move_r(case)
        flicker = case_flicker_deg(renderer, case, balanced)
        assert math.isfinite(flicker) and flicker > 0.0
        assert math.isfinite(floor) and floor > 0.0
    assert math.isclose(moves[True], 0.02, rel_tol=1e-6)
    assert math.isclose(moves[False], 0.02 * math.sqrt(8.0 / math.pi), rel_tol=0.05)


def test_jitter_readings_section_says_who_meets_the_item_under_each_reading() -> None:
    (gauss, _), (fixed, _) = READINGS
    rows = [
        JitterReadingRow(gauss, "before", 0.032, 1.9, 0.5, 2.1, 0.8),
        JitterReadingRow(gauss, "after", 0.032, 0.65, 0.5, 0.98, 0.8),
        JitterReadingRow(fixed, "before", 0.02, 1.4, 0.25, 1.5, 0.28),
        JitterReadingRow(fixed, "after", 0.02, 0.29, 0.25, math.nan, 0.28),
    ]
    text = "\n".join(jitter_readings_section(rows))
    assert f"| {fixed} | 0.0200 r | after | 0.29 | 0.25 | nan | 0.28 |" in text
    assert (
        f"* {gauss}: flicker <= 0.3°: before does not meet it, after does not meet it; the "
        "truth itself does not meet it" in text
    )
    # a NaN (no dam break) is not a verdict: after meets it on the spatter alone
    assert (
        f"* {fixed}: flicker <= 0.3°: before does not meet it, after meets it; the truth "
        "itself meets it" in text
    )
    assert jitter_readings_section([]) == []


def test_dam_frames_section_worst_edge_alpha_skips_frames_without_edges() -> None:
    """A frame without edge pixels (nan) is not the worst of them, whatever its place."""
    after = "preset balanced"
    rows = [
        _dam_row("F_1", PLAIN_SMOOTHING.name, 10.0, 1.0, 0.2),
        _dam_row("F_1", after, 3.0, 0.1, 0.2),  # its sphere-union figures: nan
        _dam_row("F_9", PLAIN_SMOOTHING.name, 20.0, 2.0, 1.2),
        _with_analytic(_dam_row("F_9", after, 9.0, 1.1, 1.2), 0.15, 0.05, 2.0),
    ]
    text = "\n".join(dam_frames_section(rows, after))
    assert "edge pixels on 0 of 2 frames (worst 0.150)" in text
    assert "| 1 | 10.00 | 3.00 | 30.0 % | 5.00 | 0.100 | 0.200 | - / - | - | yes |" in text
    assert "background on 1 of 2 (worst 0.050)" in text


def test_the_reports_done_when_names_the_dam_frames_beside_the_spatter() -> None:
    """The spatter's droplet and edge alpha verdicts, and the one dam frame's band, carry the
    counts over every dam-break frame, so a 'met' on the spatter never reads as the whole item;
    without the per-frame rows the lines say nothing of them."""
    rows = [
        SurfaceRow("preset balanced", 200, 0.55, 0.093, 0.64, 1.3, 18.7, 8.13, 0.98, 1.5, 3.7),
        SurfaceRow(PLAIN_SMOOTHING.name, 100, 23.4, 0.25, 1.9, 35.8, 35.9, 21.53, 2.1, 2.2, 6.5),
        SurfaceRow(UNFILTERED.name, 55, 0.88, 0.038, 4.5, 17.4, 42.7, 31.19, 4.6, 40.0, 77.5),
    ]
    surfaces = SurfaceResults(960, 540, rows, 0.5, dam_flicker_floor=0.8)
    dam = DamCounts(
        frames=8,
        band_ok=7,
        worst_band_ratio=0.403,
        flicker_ok=2,
        floor_low=2,
        alpha_ok=2,
        worst_alpha=0.248,
        silhouettes_ok=8,
        worst_silhouettes=0.045,
        droplet_frames=6,
        droplets_ok=6,
        finite=True,
    )
    text = "\n".join(surface_section(surfaces, None, surface_notes(dam)))
    assert "(<= 1.2x) on the spatter: met; on the dam-break frames (below) on 6 of the 6" in text
    assert "edge alpha error 0.093 (<= 0.1) on the spatter: met; on the dam-break frames" in text
    assert (
        "on 2 of 8 over all its edge pixels (worst 0.248), on 8 of 8 over its silhouettes" in text
    )
    assert "every frame (below): on 7 of 8 (worst 40.3 %)" in text
    alone = "\n".join(surface_section(surfaces))
    assert "(<= 0.1) on the spatter: met\n" in alone and "dam-break frames (below)" not in alone
