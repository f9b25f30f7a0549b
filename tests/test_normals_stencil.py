"""The normals pass's wide stencil (`quality.normal_stencil`): against a float64 numpy
reference of the shader on synthetic depth images, and against analytic shapes."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from reference_normals import reference_normals

from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.gpu.draw import FullscreenTriangle, Target
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.gpu.programs import ProgramCache
from sphrender.server.engine.passes import normals as normals_pass
from sphrender.server.engine.passes.context import PassContext
from sphrender.server.engine.passes.normals import NormalsPass
from sphrender.server.scene import CameraConfig, QualityConfig

W, H = 96, 64
R = 0.02
CAMERA = Camera.from_config(CameraConfig(eye=(0.0, 0.0, 0.6), target=(0.0, 0.0, 0.0)), W, H)


def gl_normals(gl: GLContext, depth: np.ndarray, quality: QualityConfig) -> np.ndarray:
    """The normals pass alone on an eye-depth image (rows bottom first, as GL stores it);
    view-space normals (the camera's rotation undone), rows bottom first."""
    context = PassContext(gl, ProgramCache(gl), FullscreenTriangle(gl))
    nrm = NormalsPass(context)
    source = Target.float(gl.ctx, (W, H), 1)
    try:
        source.texture.write(np.ascontiguousarray(depth, np.float32).tobytes())
        out = nrm.run(source.texture, CAMERA, None, R, quality)
        pixels = np.frombuffer(out.texture.read(), np.float32).reshape(H, W, 4)
        return pixels[..., :3].astype(np.float64) @ CAMERA.rotation.T
    finally:
        source.release()
        nrm.release()
        context.fullscreen.release()
        context.programs.release()


def reference(depth: np.ndarray, quality: QualityConfig) -> np.ndarray:
    t = CAMERA.tan_half_fov_y
    return reference_normals(
        depth.astype(np.float64),
        (t * CAMERA.aspect, t),
        CAMERA.pixels_per_unit_at_unit_depth,
        R,
        normals_pass.EDGE_JUMP_RADII * R,
        normals_pass.EDGE_JUMP_FOOTPRINTS,
        quality.normal_stencil,
        quality.normal_stencil_max_px,
        normals_pass.KINK,
        quality.normal_rules == "smooth",
    )


def rippled_plane_with_steps(seed: int) -> np.ndarray:
    """A tilted plane with a ripple and noise of a few hundredths of r, a nearer block (a
    depth step), a background hole and a kink (two slopes meeting)."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    z = 0.6 + 0.002 * x + 0.001 * y + 0.01 * R * np.sin(x / 2.3) * np.cos(y / 3.1)
    z += rng.normal(0.0, 0.02 * R, z.shape)
    z[40:52, 10:30] -= 6 * R  # a nearer surface: a discontinuity
    z[5:9, 60:66] = 0.0  # background
    # A kink along x = 70: the slope beyond it (0.022 per pixel) is steep enough against the
    # pixel footprint (~0.008 at this depth) for the kink test's floor not to hide it.
    z[:, 70:] += 0.02 * (x[:, 70:] - 70)
    return z.astype(np.float32)


@pytest.mark.parametrize(
    "quality",
    [
        QualityConfig(normal_stencil=0.0),
        QualityConfig(normal_stencil=1.0, normal_stencil_max_px=4),
        QualityConfig(normal_stencil=2.0, normal_stencil_max_px=3),
        QualityConfig(normal_stencil=0.0, normal_rules="hard"),
        QualityConfig(normal_stencil=1.0, normal_stencil_max_px=4, normal_rules="hard"),
    ],
    ids=["one-pixel", "stencil 1 r", "stencil 2 r capped 3 px", "one-pixel hard", "1 r hard"],
)
def test_normals_match_numpy_reference(gl_context: GLContext, quality: QualityConfig) -> None:
    """Bound: float32 positions of depths ~0.6 differenced over >= 1 pixel (footprint 1e-3):
    relative rounding ~1e-7 / 1e-3 = 1e-4 rad on the chord; 1e-3 rad (0.06 deg) leaves margin.
    A pixel where a test (jump, kink) decides differently within rounding would differ by much
    more; the images keep every such comparison well away from its threshold except by noise,
    so at most 0.5 % of the pixels may differ beyond the bound."""
    depth = rippled_plane_with_steps(3)
    got = gl_normals(gl_context, depth, quality)
    want = reference(depth, quality)
    angle = np.arccos(np.clip(np.sum(got * want, axis=2), -1.0, 1.0))
    covered = depth > 0
    assert (np.abs(got[~covered]) == 0).all()
    assert np.mean(angle[covered] > 1e-3) <= 0.005, np.sort(angle[covered])[-10:]


def sphere_depth(center_z: float, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Eye depth (rows bottom first) and view-space normals of a sphere on the view axis."""
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    t = CAMERA.tan_half_fov_y
    d = np.stack(
        [
            ((x + 0.5) / W * 2 - 1) * t * CAMERA.aspect,
            ((y + 0.5) / H * 2 - 1) * t,
            -np.ones_like(x),
        ],
        axis=2,
    )
    d /= np.linalg.norm(d, axis=2, keepdims=True)
    c = np.array([0.0, 0.0, -center_z])
    b = d @ c
    disc = b * b - (c @ c - radius * radius)
    hit = disc >= 0
    t_hit = np.where(hit, b - np.sqrt(np.maximum(disc, 0)), 0.0)
    p = d * t_hit[..., None]
    n = np.where(hit[..., None], (p - c) / radius, 0.0)
    return np.where(hit, -p[..., 2], 0.0).astype(np.float32), n


def test_wide_stencil_on_a_sphere_stays_within_the_chord_bound(gl_context: GLContext) -> None:
    """A central difference over +-s pixels measures the chord between two surface points whose
    normals lie within s pixels of the centre's: on a sphere of projected radius R_px at angle
    theta <= 60 deg from the view, each axis turns by at most asin(sin theta + s / R_px) -
    theta, both together sqrt(2) times that (the 1-pixel one-sided bound of
    test_normals_beside_a_nearer_surface_come_from_their_own_surface with s pixels)."""
    radius = 0.1
    depth, truth = sphere_depth(0.6, radius)
    quality = QualityConfig(normal_stencil=1.0, normal_stencil_max_px=4)
    got = gl_normals(gl_context, depth, quality)
    facing = truth[..., 2]
    mask = (depth > 0) & (facing >= 0.5)
    errors = np.degrees(np.arccos(np.clip(np.sum(got * truth, axis=2), -1, 1)))[mask]
    radius_px = CAMERA.projected_radius_px(radius, 0.6 - radius)
    s = 4  # R * focal / z = 0.02 * 87.9 / 0.5 = 3.5 pixels -> 4 (the cap)
    theta = math.acos(0.5)
    bound = math.degrees(
        math.sqrt(2) * (math.asin(min(1.0, math.sin(theta) + s / radius_px)) - theta)
    )
    assert errors.max() <= bound, (errors.max(), bound)


def test_wide_stencil_averages_ripple_on_a_plane(gl_context: GLContext) -> None:
    """A plane facing the camera with white depth noise of sigma = 0.05 footprints. The central
    difference over +-s pixels has slope noise sqrt(2) sigma / (2 s) per axis, so its normal
    tilts by a Rayleigh-distributed angle of mean sqrt(pi / 2) sqrt(2) sigma / (2 s): 0.85 deg
    at s = 3 (stencil 1 r, R_px = 2.9 -> 3), where the kink test's weight is ~1 (the slopes'
    difference is a few hundredths of the limit's floor of s footprints). 15 % leaves room for
    the finite sample (5k pixels: ~1 %) and the weight's small share of the 1-pixel differences.
    Those are at least 1.5x noisier here: a central difference over +-1 would be 3x; the
    weights by the other side's squared step lean towards the flatter side, which on a flat
    plane lowers the noise (measured 1.50 deg against the stencil's 0.84)."""
    rng = np.random.default_rng(7)
    footprint = 0.6 / CAMERA.pixels_per_unit_at_unit_depth
    sigma = 0.05
    depth = (0.6 + rng.normal(0.0, sigma * footprint, (H, W))).astype(np.float32)

    def mean_error(quality: QualityConfig) -> float:
        n = gl_normals(gl_context, depth, quality)[4:-4, 4:-4]
        return float(np.degrees(np.arccos(np.clip(n[..., 2], -1, 1))).mean())

    one = mean_error(QualityConfig(normal_stencil=0.0))
    wide = mean_error(QualityConfig(normal_stencil=1.0, normal_stencil_max_px=4))
    expected = math.degrees(math.sqrt(math.pi / 2) * math.sqrt(2) * sigma / (2 * 3))
    print(f"1-pixel {one:.3f} deg, stencil {wide:.3f} deg, expected {expected:.3f}")
    assert abs(wide - expected) <= 0.15 * expected, (wide, expected)
    assert wide * 1.5 <= one, (one, wide)


def sweep_normals(gl: GLContext, depth: np.ndarray, quality: QualityConfig, x0: int) -> np.ndarray:
    """The normal's angle in the x-z plane (degrees) at column x0, one per row (bottom first)."""
    n = gl_normals(gl, depth, quality)[:, x0]
    return np.degrees(np.arctan2(n[:, 0], n[:, 2]))


@pytest.mark.parametrize(
    ("case", "quality"),
    [
        ("kink", QualityConfig(normal_stencil=1.0, normal_stencil_max_px=4)),
        ("ridge", QualityConfig(normal_stencil=0.0)),
    ],
    ids=["kink", "ridge"],
)
def test_smooth_rules_leave_no_switch_for_a_small_move_to_flip(
    gl_context: GLContext, case: str, quality: QualityConfig
) -> None:
    """Each row a little more of what the hard rules switch on, the normal at the column where
    they switch (x0), under both rules:
    * kink (the wide stencil, s = 3 px here): a plane whose slope beyond x0 grows row by row,
      sweeping the kink test's ratio from 0 to 1.6 of its limit (the hard rule cuts from the
      central difference to the 1-pixel one at 1);
    * ridge (the 1-pixel differences): a roof at x0 whose two sides' steps cross row by row,
      from 0.8 to 1.25 of each other (the hard rule jumps from one side's slope to the other's
      at 1).
    The hard rules' largest change between rows is that jump J (asserted > 5 deg, so the test
    tells the rules apart; measured 8.4 and 160 deg). The smooth rules' weights move per row by
    at most their steepest slope times the step: the smoothstep over twice the limit, 0.75 x
    1.6 / 63 = 0.019 for the kink; the squared-step weights s_-^2 / (s_+^2 + s_-^2), 1/2 per
    unit of ln(s_+ / s_-) at equal steps, x 2 ln(1.25 / 0.8) / 63 = 0.007 for the ridge. The
    normal then moves by a few hundredths of J per row (the angle is not linear in the weight:
    near the ridge's balance the blended slope is flat and its normal turns fastest), plus what
    both rules share, the slopes themselves changing by 1/63 of their range (measured 0.024 J
    and 0.014 J). A bound of 0.15 J leaves that room; a rule with any switch left moves by J
    somewhere."""
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    x0, t = W // 2, y / (H - 1)  # t: 0 .. 1 from the bottom row to the top
    footprint = 0.6 / CAMERA.pixels_per_unit_at_unit_depth
    if case == "kink":
        slope = 1.5 * footprint  # per pixel, above the kink test's floor of one footprint
        # d_plus - d_minus = extra * s, limit = KINK * (slope + extra) * s: the kink test's
        # ratio r at extra = r KINK slope / (1 - r KINK); rows sweep r from 0 to 1.6
        ratio = 1.6 * t
        extra = ratio * normals_pass.KINK * slope / (1.0 - ratio * normals_pass.KINK)
        depth = 0.6 + slope * (x - x0) + extra * np.maximum(x - x0, 0)
    else:
        # steps of the two sides at x0: slope * k and slope / k, k from 0.8 to 1.25 (ratio 1 at
        # the middle row); a ridge in depth, nearer at x0
        slope = 6.0 * footprint
        k = 0.8 * (1.25 / 0.8) ** t
        depth = 0.6 + np.where(x >= x0, slope * k * (x - x0), slope / k * (x0 - x))
    depth = depth.astype(np.float32)
    smooth = sweep_normals(gl_context, depth, quality, x0)
    hard = sweep_normals(gl_context, depth, replace(quality, normal_rules="hard"), x0)
    jump = np.abs(np.diff(hard)).max()
    step = np.abs(np.diff(smooth)).max()
    print(f"{case}: hard rules' largest change between rows {jump:.2f} deg, smooth {step:.3f}")
    assert jump > 5.0, jump
    assert step <= 0.15 * jump, (step, jump)


def test_a_pixel_with_no_neighbour_of_its_surface_along_an_axis(gl_context: GLContext) -> None:
    """One-pixel rows that no neighbour continues (every step beyond the edge jump, 4 r):
    between a nearer block and the farther plane, and against the background behind a nearer
    plane, the row is a surface seen edge-on behind its nearer neighbour: its normal is
    differenced toward that neighbour (a steep slope: almost perpendicular to the view), not
    turned to the camera. A row between two nearer surfaces (a slit) keeps "no depth change".
    GL against the float64 reference on exactly those pixels (bound as above)."""
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    depth = 0.6 + 0.002 * x + 0.001 * y
    depth[21:30, 10:30] -= 12 * R  # a nearer block
    depth[20, 10:30] -= 6 * R  # its edge-on rim: 6 r behind it, 6 r in front of the plane
    depth[40:50, 40:60] -= 12 * R  # a second block with a slit row between its halves
    depth[45, 40:60] += 6 * R
    depth[56:, 70:90] = 0.0  # background above the plane ...
    depth[55, 70:90] += 6 * R  # ... and a row 6 r behind the plane's edge before it
    depth = depth.astype(np.float32)
    quality = QualityConfig()
    got, want = gl_normals(gl_context, depth, quality), reference(depth, quality)
    rows = {"rim": (20, slice(12, 28)), "slit": (45, slice(42, 58)), "edge": (55, slice(72, 88))}
    for name, (row, cols) in rows.items():
        angle = np.arccos(np.clip(np.sum(got[row, cols] * want[row, cols], axis=1), -1.0, 1.0))
        assert angle.max() <= 1e-3, (name, angle.max())
    # The exact values are the reference's (checked above); this tells the two rules apart.
    # "No depth change" along the axis leaves the plane's |n_z| ~ 0.98; the slope toward the
    # nearer neighbour, 6 r = 0.12 over a ~0.011 pixel footprint (~11), gives |n_z| ~ 0.1 on
    # the view axis, more off it and with the plane's tilt (measured: rim 0.18-0.19, edge row
    # ~0.37). 0.5 lies between the two rules, not fitted to either value.
    facing = {name: np.abs(got[row, cols, 2]) for name, (row, cols) in rows.items()}
    assert facing["rim"].max() < 0.5 and facing["edge"].max() < 0.5, facing
    assert facing["slit"].min() > 0.9, facing["slit"]  # the plane's own normal, about (0, 0, 1)
