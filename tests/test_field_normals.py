"""Field normals (`quality.field_normals`): the listing and blend compute passes against their
float64 brute-force numpy reference (tests/reference_field_normals.py) on ray-cast spheres,
a lone droplet's exact sphere normal, host and device prepare agreeing, and hard cases
(coincident and coplanar particles, huge coordinates, tiny and huge radii, particles behind
the camera, no particles): finite normals, depth untouched."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import pytest
import reference_field_normals
from reference_field_normals import field_gradient, field_normals_reference
from scipy import ndimage

from benchmarks.studies.study_shaders import shader_root
from sphrender.core.frame import make_frame
from sphrender.server.content.lattice import jittered_lattice_ball
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.gpu.draw import FullscreenTriangle, Target
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.gpu.programs import ProgramCache
from sphrender.server.engine.gpu.shader_loader import ShaderLoader
from sphrender.server.engine.passes import field_grid, field_normals
from sphrender.server.engine.passes.context import PassContext
from sphrender.server.engine.passes.field_grid import FieldParticles, table_size
from sphrender.server.engine.passes.gaps import EDGE_JUMP_RADII
from sphrender.server.engine.passes.normals import EDGE_JUMP_FOOTPRINTS, NormalsPass
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import CameraConfig, QualityConfig, scene_from_dict

W, H = 96, 64
R = 0.01
SUPPORT_RADII = QualityConfig().field_normals_support
SUPPORT = SUPPORT_RADII * R
REACH = 2.0  # quality.field_normals, projected particle radii
CAMERA = Camera.from_config(CameraConfig(eye=(0.0, 0.0, 0.6), target=(0.0, 0.0, 0.0)), W, H)
T = CAMERA.tan_half_fov_y
FOCAL = CAMERA.pixels_per_unit_at_unit_depth
TAN = (T * CAMERA.aspect, T)
SHADERS = Path(__file__).resolve().parents[1] / "shaders"


def rays() -> np.ndarray:
    """Unit view-space rays through the pixel centres, rows bottom first."""
    ys, xs = np.mgrid[0:H, 0:W] + 0.5
    ray = np.stack([(xs / W * 2 - 1) * TAN[0], (ys / H * 2 - 1) * TAN[1], -np.ones((H, W))], -1)
    return ray / np.linalg.norm(ray, axis=-1, keepdims=True)


def ray_cast(centres: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Eye depth (0 = none) and view-space normals of the union of spheres at view-space
    `centres`, rows bottom first."""
    ray = rays().reshape(-1, 3)
    best = np.full(len(ray), np.inf)
    normal = np.zeros_like(ray)
    for c in centres:
        b = ray @ c
        perp2 = c @ c - b * b
        hit = (perp2 < radius * radius) & (b > 0)
        t = b - np.sqrt(np.maximum(radius * radius - perp2, 0.0))
        closer = hit & (t < best)
        best = np.where(closer, t, best)
        normal[closer] = (t[closer, None] * ray[closer] - c) / radius
    depth = np.where(np.isfinite(best), best * -ray[:, 2], 0.0)
    return depth.reshape(H, W), normal.reshape(H, W, 3)


def gl_normals(
    gl: GLContext,
    depth: np.ndarray,
    centres: np.ndarray | None,
    radius: float = R,
    bulk: np.ndarray | None = None,
) -> np.ndarray:
    """The normals pass on an eye-depth image, with the field of `centres` (view space; None:
    field normals off; `bulk`: the bulk's depth under the droplets in `depth`, as
    `SplatOutput.bulk_depth`); view-space normals and the depth, rows bottom first."""
    context = PassContext(gl, ProgramCache(gl), FullscreenTriangle(gl))
    normals = NormalsPass(context)
    source = Target.float(gl.ctx, (W, H), 1)
    under = Target.float(gl.ctx, (W, H), 1) if bulk is not None else None
    try:
        source.texture.write(np.ascontiguousarray(depth, np.float32).tobytes())
        if under is not None:
            under.texture.write(np.ascontiguousarray(bulk, np.float32).tobytes())
        quality = QualityConfig(field_normals=REACH if centres is not None else 0.0)
        field = None
        if centres is not None:
            spheres = np.zeros((len(centres), 4), np.float32)
            spheres[:, :3] = centres
            spheres[:, 3] = radius
            field = FieldParticles(arrays=(spheres,))
        out = normals.run(
            source.texture,
            CAMERA,
            None,
            radius,
            quality,
            field,
            SUPPORT_RADII * radius,
            bulk=under.texture if under is not None else None,
        )
        pixels = np.frombuffer(out.texture.read(), np.float32).reshape(H, W, 4).astype(np.float64)
        pixels[..., :3] = pixels[..., :3] @ CAMERA.rotation.T
        return pixels
    finally:
        source.release()
        if under is not None:
            under.release()
        normals.release()
        context.fullscreen.release()
        context.programs.release()


def reference_blend(
    depth: np.ndarray,
    plain: np.ndarray,
    centres: np.ndarray,
    radius: float = R,
    bulk: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The reference's field normals of `centres` (particle radius `radius`) over the depth
    normals `plain`, and which pixels it changed, with this module's camera and the pass's
    settings; the depth and centres rounded to float32 as the GPU gets them."""
    return field_normals_reference(
        depth.astype(np.float32).astype(np.float64),
        plain,
        centres.astype(np.float32).astype(np.float64),
        tan_half_fov=TAN,
        focal_px=FOCAL,
        particle_radius=radius,
        support=SUPPORT_RADII * radius,
        reach_radii=REACH,
        edge_jump=EDGE_JUMP_RADII * radius,
        edge_jump_px=EDGE_JUMP_FOOTPRINTS,
        bulk=None if bulk is None else bulk.astype(np.float32).astype(np.float64),
    )


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cos = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def splash(seed: int, count: int = 3000) -> np.ndarray:
    """A jittered slab (a sheet with holes) in front of a farther blob, and a few droplets:
    rims against the background, depth steps, holes; view space, about 0.6 in front."""
    rng = np.random.default_rng(seed)
    sheet = rng.uniform([-0.15, -0.1, -0.52], [0.1, 0.1, -0.5], (count // 2, 3))
    sheet = sheet[rng.random(len(sheet)) > 0.15]  # holes
    blob = rng.normal([0.05, 0.0, -0.62], [0.06, 0.04, 0.02], (count // 2, 3))
    drops = np.array([[-0.2, 0.12, -0.45], [0.17, -0.12, -0.55], [0.0, 0.15, -0.5]])
    return np.concatenate([sheet, blob, drops])


def assert_matches_the_reference(
    gl: GLContext, centres: np.ndarray, facing_away: int = 0, droplets: np.ndarray | None = None
) -> int:
    """The field normals of `centres` (radius R) against the brute-force reference on their
    ray-cast depth, with more than `facing_away` well-conditioned pixels whose field normal
    faces away from the eye; returns how many pixels the field changed. `droplets`: drawn
    over the bulk `centres` as the renderer's exact droplets are (the bulk's depth under
    them given to the pass), and in the field."""
    bulk = None
    if droplets is not None:
        bulk, _ = ray_cast(centres, R)
        centres = np.concatenate([centres, droplets])
    depth, _ = ray_cast(centres, R)
    plain = gl_normals(gl, depth, None)
    field = gl_normals(gl, depth, centres, bulk=bulk)
    expected, changed = reference_blend(depth, plain[..., :3], centres, bulk=bulk)
    np.testing.assert_array_equal(field[..., 3], plain[..., 3])  # depth untouched
    # Away from rims the pass changes nothing, bit for bit.
    np.testing.assert_array_equal(field[~changed][:, :3], plain[~changed][:, :3])
    # Where the gradient is well conditioned (|grad| >= 5 % of the terms' sum, so float32
    # cancellation costs < ~1e-5 rad), the shader's normal is the reference's to 0.02 deg.
    ys, xs = np.nonzero(changed)
    z = depth[ys, xs]
    x = np.stack(
        [((xs + 0.5) / W * 2 - 1) * TAN[0] * z, ((ys + 0.5) / H * 2 - 1) * TAN[1] * z, -z], -1
    )
    g, scale = field_gradient(x, centres, SUPPORT)
    good = np.linalg.norm(g, axis=-1) >= 0.05 * scale
    assert good.mean() > 0.9
    error = angle_deg(field[ys, xs, :3], expected[ys, xs])
    assert error[good].max() < 0.02
    assert np.isfinite(field).all()
    # Every normal faces the eye (field normals facing away are mirrored to face it).
    assert (np.sum(g * x, axis=-1) > 0.0)[good].sum() >= facing_away
    assert (np.sum(field[ys, xs, :3] * x, axis=-1) <= 1e-6).all()
    return int(changed.sum())


def test_matches_the_numpy_reference(gl_context: GLContext) -> None:
    centres = splash(1)
    # About as many buckets as centres: buckets hold cells of far-apart places too, which the
    # distance test drops (test_buckets_shared_by_many_cells: ~20 centres per bucket).
    assert table_size(len(centres)) <= 2 * len(centres)
    # Rims, steps and hole edges all over the image, and field normals facing away.
    assert assert_matches_the_reference(gl_context, centres, facing_away=10) > 500


@pytest.mark.parametrize("size", [(97, 61), (33, 130)])
def test_matches_the_reference_on_images_of_partial_tiles(
    gl_context: GLContext, monkeypatch: pytest.MonkeyPatch, size: tuple[int, int]
) -> None:
    """Sides that are no multiple of the 4-px rim tiles: the listing's partial tiles at the far
    edges, and the first-ring search clipped to the image, list exactly the reference's
    pixels (this module's image constants swapped for the test)."""
    camera = Camera.from_config(CameraConfig(eye=(0.0, 0.0, 0.6), target=(0.0, 0.0, 0.0)), *size)
    tan = camera.tan_half_fov_y
    module = sys.modules[__name__]
    for name, value in {
        "W": size[0],
        "H": size[1],
        "CAMERA": camera,
        "T": tan,
        "FOCAL": camera.pixels_per_unit_at_unit_depth,
        "TAN": (tan * camera.aspect, tan),
    }.items():
        monkeypatch.setattr(module, name, value)
    # Droplets on the last column and the last row (the partial tiles), and in the far corner.
    z = 0.55
    last_x = ((size[0] - 0.5) / size[0] * 2 - 1) * tan * camera.aspect * z
    last_y = ((size[1] - 0.5) / size[1] * 2 - 1) * tan * z
    edges = np.array([[last_x, 0.0, -z], [0.0, last_y, -z], [last_x, last_y, -z]])
    assert assert_matches_the_reference(gl_context, np.concatenate([splash(1), edges])) > 300


def test_rims_of_a_nearer_sheet_over_a_wall_filling_the_image(gl_context: GLContext) -> None:
    """No background anywhere: the wall's rims are the edges of the nearer sheet only, which
    the listing's tile test must find from the far side too (its nearer-surface term)."""
    rng = np.random.default_rng(3)
    ys, xs = np.mgrid[-0.32:0.32:0.01, -0.46:0.46:0.01]
    wall = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, -0.7)], -1)
    wall += rng.normal(0.0, 0.001, wall.shape)
    sheet = rng.uniform([-0.08, -0.05, -0.51], [0.08, 0.05, -0.5], (400, 3))
    centres = np.concatenate([wall, sheet])
    depth, _ = ray_cast(centres, R)
    assert (depth > 0).all()  # the wall fills the image
    assert assert_matches_the_reference(gl_context, centres) > 100


def test_a_droplet_in_front_of_the_bulk_is_no_rim_of_it(gl_context: GLContext) -> None:
    """Exact droplets drawn over the bulk (a wall filling the image, so it has no rim of its
    own), 10 to 25 r in front of it: the droplets' own rims take the field's normals, as the
    reference's with the bulk's depth under them; the wall beside them keeps its depth
    normals bit for bit (its surface goes on behind a droplet: no edge of it lies there, and
    its field normal differs from its depth normal by a few degrees, a ring around every
    droplet in a mirror-like metal). The same depth without the bulk's (every surface one
    bulk) does change the wall beside them: the test tells the two apart."""
    rng = np.random.default_rng(5)
    ys, xs = np.mgrid[-0.32:0.32:0.01, -0.46:0.46:0.01]
    wall = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, -0.7)], -1)
    wall += rng.normal(0.0, 0.001, wall.shape)
    droplets = np.array(
        [[-0.12, 0.06, -0.6], [0.1, -0.05, -0.55], [0.02, 0.1, -0.45], [-0.05, -0.1, -0.5]]
    )
    bulk, _ = ray_cast(wall, R)
    depth, _ = ray_cast(np.concatenate([wall, droplets]), R)
    assert (bulk > 0).all()
    on_droplet = depth < bulk
    assert on_droplet.sum() > 20
    assert assert_matches_the_reference(gl_context, wall, droplets=droplets) > 20
    centres = np.concatenate([wall, droplets])
    plain = gl_normals(gl_context, depth, None)
    with_bulk = gl_normals(gl_context, depth, centres, bulk=bulk)
    as_one = gl_normals(gl_context, depth, centres)
    np.testing.assert_array_equal(with_bulk[~on_droplet], plain[~on_droplet])
    assert (angle_deg(with_bulk[on_droplet][:, :3], plain[on_droplet][:, :3]) > 0.1).any()
    beside = angle_deg(as_one[~on_droplet][:, :3], plain[~on_droplet][:, :3])
    assert (beside > 0.5).sum() > 20, np.sort(beside)[-5:]


def test_a_depth_step_turns_into_a_rim_smoothly(
    gl_context: GLContext, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A wall (eye depth 0.61) and a nearer rectangle on it, the depth images given exactly (no
    silhouette moves between steps), over a lattice of wall particles (tilted, so that
    their field's normal differs from the depth image's) and one of the rectangle's, which
    moves with it: the rectangle's step swept from 7 to 24 r. The rim rule's
    jump next to it is 8 footprints x d (0.79 r each here) = 6.3 r x d, so the wall's pixels
    at d = 2 and 3 from the rectangle meet it at 12.6 and 18.9 r (the d = 1 ring, where the
    depth normals stop differencing across the step at 6.3 r, keeps its one-sided ones over
    the whole sweep). With the rim strength rising smoothly from one jump to
    FIELD_RIM_FEATHER (2) jumps, and the field turning smoothly as the rectangle's particles
    leave the wall's support, the largest change of a wall normal between neighbouring steps
    halves when the steps do (ratio ~2, asserted >= 1.6). Cut at the jump instead (the
    reference with RIM_FEATHER -> 1) the weight jumps at each ring's jump, whatever the step
    (ratio ~1, asserted <= 1.3: the test tells the two rules apart)."""
    # The wall's particles tilted by 30 degrees about y, so that its field normal differs from
    # the depth image's (a plane facing the eye) and the weight shows in the blend.
    ys, xs = np.mgrid[-0.2:0.2001:0.01, -0.3:0.3001:0.01]
    wall = np.stack([xs.ravel(), ys.ravel(), -0.62 + np.tan(np.radians(30)) * xs.ravel()], -1)
    ys, xs = np.mgrid[-0.06:0.0601:0.01, -0.1:0.1001:0.01]
    rectangle = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], -1)
    lift = np.array([0.0, 0.0, 1.0])

    def normals_at(step_radii: float, feather: float | None) -> np.ndarray:
        depth = np.full((H, W), 0.61)
        depth[20:44, 30:66] -= step_radii * R
        centres = np.concatenate([wall, rectangle + (step_radii * R - 0.62) * lift])
        if feather is None:
            return gl_normals(gl_context, depth, centres)[..., :3]
        monkeypatch.setattr(reference_field_normals, "RIM_FEATHER", feather)
        return reference_blend(depth, gl_normals(gl_context, depth, None)[..., :3], centres)[0]

    on_wall = np.ones((H, W), bool)
    on_wall[20:44, 30:66] = False

    def largest_change(feather: float | None, increment: float) -> float:
        largest, previous = 0.0, None
        for step in np.arange(7.0, 24.0 + 1e-9, increment):
            normals = normals_at(step, feather)[on_wall]
            if previous is not None:
                largest = max(largest, float(angle_deg(normals, previous).max()))
            previous = normals
        return largest

    ratios = {}
    for name, feather in (("smooth", None), ("cut", 1.0 + 1e-6)):
        coarse, fine = largest_change(feather, 1.0), largest_change(feather, 0.5)
        ratios[name] = coarse / fine
        print(f"{name}: largest change per 1 r of step {coarse:.2f} deg, per 0.5 r {fine:.2f}")
    assert ratios["smooth"] >= 1.6, ratios
    assert ratios["cut"] <= 1.3, ratios


def test_rows_wrapping_at_the_tables_end(
    gl_context: GLContext, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A row of cells whose run of buckets passes the table's last one goes on at bucket 0
    (common/field_grid.glsl). The smallest table, and a jittered sheet facing the camera in the
    cells (0 .. 8, -2 .. 1, -28), whose cell (4, 0, -28) hashes to bucket 0 there: the rows
    the sheet's pixels scan through it start in the table's last buckets."""
    cell = SUPPORT / 2
    constants = grid_constants()
    hashed = (4 + 0 * constants["FIELD_HASH_Y"] - 28 * constants["FIELD_HASH_Z"]) % 2**32
    assert hashed % field_grid.MIN_BUCKETS == 0
    xs, ys = np.meshgrid(np.arange(0.0, 9 * cell, 1.2 * R), np.arange(-2 * cell, 2 * cell, 1.2 * R))
    rng = np.random.default_rng(7)
    centres = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, -27.5 * cell)], -1)
    centres += rng.uniform(-0.15 * R, 0.15 * R, centres.shape)
    monkeypatch.setattr(field_grid, "table_size", lambda count: field_grid.MIN_BUCKETS)
    assert assert_matches_the_reference(gl_context, centres) > 100  # the sheet's rim


def test_buckets_shared_by_many_cells(
    gl_context: GLContext, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The smallest table under 20k far-away centres (off to the side, beyond every pixel's
    support): ~20 per bucket, sharing the buckets of the splash's cells. The distance test
    drops them and each row of cells is still one run of buckets: the full table's normals."""
    centres = splash(2, count=600)
    depth, _ = ray_cast(centres, R)
    far = np.random.default_rng(3).uniform([3.0, -1.0, -2.0], [4.0, 1.0, -0.5], (20_000, 3))
    everything = np.concatenate([centres, far])
    assert table_size(len(everything)) >= 16 * field_grid.MIN_BUCKETS
    covered = depth > 0
    full = gl_normals(gl_context, depth, everything)[covered][:, :3]
    alone = gl_normals(gl_context, depth, centres)[covered][:, :3]
    monkeypatch.setattr(field_grid, "table_size", lambda count: field_grid.MIN_BUCKETS)
    shared = gl_normals(gl_context, depth, everything)[covered][:, :3]
    assert angle_deg(shared, full).max() < 1e-3
    assert angle_deg(alone, full).max() < 1e-3


def grid_constants() -> dict[str, int]:
    source = (SHADERS / "common" / "field_grid.glsl").read_text()
    found = dict(re.findall(r"#define (FIELD_\w+) (\d+)u?\b", source))
    return {name: int(value) for name, value in found.items()}


def test_rows_of_one_window_never_share_a_bucket() -> None:
    """common/field_grid.glsl's promise: the rows of cells one point scans (|dy|, |dz| <= m
    from its own) start in buckets more than 4 m apart modulo the smallest table, so their
    runs of at most 2 m + 1 buckets never overlap in any table (each size a multiple of it):
    no centre counted twice. And the host's smallest table is the shader's."""
    constants = grid_constants()
    m = constants["FIELD_CELLS_PER_SUPPORT"]
    modulus = constants["FIELD_MIN_BUCKETS"]
    assert modulus == field_grid.MIN_BUCKETS == table_size(1)
    assert table_size(modulus + 1) % modulus == 0
    window = range(-2 * m, 2 * m + 1)
    for dy in window:
        for dz in window:
            if dy or dz:
                step = dy * constants["FIELD_HASH_Y"] + dz * constants["FIELD_HASH_Z"]
                residue = step % modulus
                assert min(residue, modulus - residue) > 4 * m, (dy, dz)


def test_blend_dispatch_in_rows(gl_context: GLContext, monkeypatch: pytest.MonkeyPatch) -> None:
    """The blend pass's indirect dispatch spreads the listed pixels over rows of work groups
    (GROUPS_X per row; 4096 in the engine, more than a small image lists): with 2 groups per
    row (128 pixels) every listed pixel is still blended once, the same normals."""
    centres = splash(1)
    depth, _ = ray_cast(centres, R)
    covered = depth > 0
    plain = gl_normals(gl_context, depth, None)[covered][:, :3]
    one_row = gl_normals(gl_context, depth, centres)[covered][:, :3]
    monkeypatch.setattr(field_normals, "GROUPS_X", 2)
    rows = gl_normals(gl_context, depth, centres)[covered][:, :3]
    changed = angle_deg(one_row, plain) > 0.01
    assert changed.sum() > 4 * 128  # more listed pixels than a few rows hold
    # The same blend (the grid's order of summation varies from build to build: < 1e-4 deg).
    assert angle_deg(rows, one_row).max() < 1e-3
    np.testing.assert_array_equal(angle_deg(rows, plain) > 0.01, changed)


def test_a_grazing_surface_far_away_is_no_rim(gl_context: GLContext) -> None:
    """A plane seen at a grazing angle steps by more than 4 r between pixels where a pixel's
    footprint is large; the normals pass takes it as one surface (steps up to 8 footprints),
    so must the field: its normals stay the depth normals away from the plane's outline (a
    rim rule of 4 r alone put the field's lattice ripple in stripes across such surfaces)."""
    radius = 0.004  # ~0.6 px at this depth; the reach (2 r) is 1 px
    # A smooth plane (the depth image, exact) 15 deg off the view direction, its particles on
    # it (the field): steps of 1.2-2 footprints / tan 15 deg = 4.7-8.5 r between pixels.
    slope = np.tan(np.radians(15.0))
    origin = np.array([0.0, -0.12, -0.45])
    along = np.array([0.0, slope, -1.0])  # down the plane, away from the eye
    xs, zs = np.meshgrid(np.arange(-40, 41) * 2 * radius, np.arange(0, 100) * 2 * radius)
    centres = origin + xs.reshape(-1, 1) * [1.0, 0.0, 0.0] + zs.reshape(-1, 1) * along
    normal = np.cross([1.0, 0.0, 0.0], along)
    normal /= np.linalg.norm(normal)
    ray = rays()
    t = (origin @ normal) / (ray @ normal)
    point = ray * t[..., None]
    u = point[..., 0]
    v = (point - origin) @ along / (along @ along)
    inside = (t > 0) & (np.abs(u) <= 0.32) & (v >= 0.0) & (v <= 0.8)
    depth = np.where(inside, -point[..., 2], 0.0)
    steps = np.abs(np.diff(np.where(inside, depth, np.nan), axis=0))
    assert np.nanmax(steps) > 1.5 * EDGE_JUMP_RADII * radius  # the case the footprints cover
    plain = gl_normals(gl_context, depth, None, radius)
    field = gl_normals(gl_context, depth, centres, radius)
    inner = inside.copy()
    for _ in range(3):  # 3 px inside the outline: beyond the reach of its rims
        inner[1:-1, 1:-1] &= inner[:-2, 1:-1] & inner[2:, 1:-1] & inner[1:-1, :-2] & inner[1:-1, 2:]
        inner[[0, -1], :] = False
        inner[:, [0, -1]] = False
    assert inner.sum() > 300
    np.testing.assert_array_equal(field[inner], plain[inner])
    assert (angle_deg(field[inside & ~inner][:, :3], plain[inside & ~inner][:, :3]) > 0.1).any()


def test_a_lone_droplet_gets_its_exact_sphere_normal(gl_context: GLContext) -> None:
    centre = np.array([[0.01, -0.005, -0.45]])
    radius = 0.03  # ~6 px: every pixel within the reach of the rim
    depth, truth = ray_cast(centre, radius)
    plain = gl_normals(gl_context, depth, None, radius)
    field = gl_normals(gl_context, depth, centre, radius)
    hit = depth > 0
    _, changed = reference_blend(depth, plain[..., :3], centre, radius)
    on_rim = hit & changed
    assert on_rim.sum() == hit.sum()
    before = angle_deg(plain[hit][:, :3], truth[hit])
    after = angle_deg(field[hit][:, :3], truth[hit])
    # One kernel's gradient is radial: the sphere's normal wherever the field weight is 1
    # (next to the rim), and a blend of it with the depth normal inside.
    next_to_rim = hit & (np.roll(~hit, 1, 0) | np.roll(~hit, -1, 0) | np.roll(~hit, 1, 1)
                         | np.roll(~hit, -1, 1))  # fmt: skip
    assert angle_deg(field[next_to_rim][:, :3], truth[next_to_rim]).max() < 0.05
    assert after.mean() < 0.5 * before.mean()


@pytest.mark.parametrize("prepare", ["host", "device"])
def test_host_and_device_prepare_agree(gl_context: GLContext, prepare: str) -> None:
    """The grid built from the host's arrays and from the device prepare's spheres (culled
    particles left out) gives the same normals; depth identical."""
    rng = np.random.default_rng(3)
    positions = np.concatenate(
        [rng.normal(0.0, 0.05, (1500, 3)), rng.uniform(-0.3, 0.3, (30, 3)), [[0.0, 0.0, 5.0]]]
    )
    base = {
        "particles": {"radius": 0.01},
        "image": {"width": 80, "height": 60},
        "camera": {"eye": [0.0, 0.1, 0.6], "target": [0.0, 0.0, 0.0]},
    }
    # Densities that make the 30 scattered particles exact droplets: the host prepare keeps
    # them apart from the bulk (the grid must still get both).
    densities = np.concatenate([np.full(1500, 1000.0), np.full(31, 50.0)])
    results = {}
    for mode in ("host", prepare):
        renderer = SurfaceRenderer(gl_context, prepare=mode)  # type: ignore[arg-type]
        try:
            for reach in (0.0, REACH):
                scene = scene_from_dict({**base, "quality": {"field_normals": reach}})
                frame, _ = renderer.render(
                    make_frame(positions, densities=densities), scene, depth=True, normals=True
                )
                results[mode, reach] = frame
        finally:
            renderer.release()
    host, other = results["host", REACH], results[prepare, REACH]
    assert host.depth is not None and other.depth is not None
    assert host.normals is not None and other.normals is not None
    covered = np.isfinite(host.depth)
    np.testing.assert_allclose(other.depth[covered], host.depth[covered], rtol=1e-6)
    assert angle_deg(other.normals[covered], host.normals[covered]).max() < 0.05
    plain = results["host", 0].normals
    assert plain is not None
    assert angle_deg(host.normals[covered], plain[covered]).max() > 5.0  # the field did act


def test_the_same_frame_gives_the_same_normals_bit_for_bit(gl_context: GLContext) -> None:
    """The grid's count ranks the centres of a bucket in the order its atomics ran; its last
    phase places them by source index, so a reader sums them in one order and the normals
    repeat bit for bit (the service's frames are compared byte for byte with in-process
    renders). Fresh renderers, many shared buckets (a dense ball: ~2 centres per cell). Eight
    renders: the atomics' order varies with llvmpipe's thread timing, and a grid that kept it
    gave three equal renders in one of four tries (tools/mutation_check.py's
    field-grid-atomic-order)."""
    positions = jittered_lattice_ball(0.12, 0.01, seed=4)
    scene = scene_from_dict(
        {
            "particles": {"radius": 0.01},
            "image": {"width": 160, "height": 120},
            "camera": {"eye": [0.0, 0.1, 0.45], "target": [0.0, 0.0, 0.0]},
            "quality": {"field_normals": REACH},
        }
    )
    normals = []
    for _ in range(8):
        renderer = SurfaceRenderer(gl_context)
        try:
            frame, _ = renderer.render(make_frame(positions), scene, normals=True)
        finally:
            renderer.release()
        assert frame.normals is not None
        normals.append(frame.normals)
    for other in normals[1:]:
        np.testing.assert_array_equal(other, normals[0])


def test_the_grid_leaves_out_only_particles_far_from_every_rim(
    gl_context: GLContext, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The field grid sorts only the particles whose support reaches a rim block with a listed
    pixel (common/rim_blocks.glsl): on a ball filling a 320 x 240 image, those projecting well
    inside its outline are left out, and the normals are those of the grid of every particle."""
    positions = jittered_lattice_ball(0.3, 0.01, seed=2)
    scene = scene_from_dict(
        {
            "particles": {"radius": 0.01},
            "image": {"width": 320, "height": 240},
            # Oblique to the lattice: seen along an axis, its channels are rims all over.
            "camera": {"eye": [0.45, 0.35, 0.6], "target": [0.0, 0.0, 0.0]},
            "quality": {"field_normals": REACH},
        }
    )
    sorted_counts: list[int] = []
    build = field_grid.FieldGrid.build

    def counting(self: field_grid.FieldGrid, *args: object, **kwargs: object) -> object:
        built = build(self, *args, **kwargs)  # type: ignore[arg-type]
        sorted_counts.append(self.sorted_count(built))
        return built

    monkeypatch.setattr(field_grid.FieldGrid, "build", counting)
    renderer = SurfaceRenderer(gl_context)
    try:
        culled, _ = renderer.render(make_frame(positions), scene, normals=True)
        monkeypatch.setattr(
            field_grid.FieldGrid,
            "build",
            lambda self, particles, support, cull=None: counting(self, particles, support),
        )
        every, _ = renderer.render(make_frame(positions), scene, normals=True)
    finally:
        renderer.release()
    assert culled.normals is not None and every.normals is not None
    assert sorted_counts[1] == len(positions)
    assert sorted_counts[0] < 0.75 * len(positions)  # the rims' blocks, 2 blocks around
    covered = np.linalg.norm(every.normals, axis=-1) > 0.5
    # The same terms summed in another order (the grid's atomics): up to ~0.03 deg where the
    # gradient nearly cancels; a particle left out that counts moves normals by degrees.
    error = angle_deg(culled.normals[covered], every.normals[covered])
    assert error.max() < 0.1
    assert np.percentile(error, 99.9) < 0.01


HARD_CASES = {
    "coincident": lambda: np.zeros((50, 3)),
    "coplanar sheet": lambda: np.stack(
        [*np.meshgrid(np.arange(-10, 11) * 0.02, np.arange(-8, 9) * 0.02), np.zeros((17, 21))],
        -1,
    ).reshape(-1, 3),
    "collinear": lambda: np.stack([np.arange(30) * 0.01 - 0.15, np.zeros(30), np.zeros(30)], -1),
    "two particles": lambda: np.array([[0.0, 0.0, 0.0], [0.015, 0.0, 0.0]]),
    "across the camera": lambda: np.stack(
        [np.zeros(80), np.zeros(80), np.linspace(-0.5, 1.5, 80)], -1
    ),
}


@pytest.mark.parametrize("case", sorted(HARD_CASES))
@pytest.mark.parametrize("shift", [0.0, 1e5])
def test_hard_cases_stay_finite(renderer: SurfaceRenderer, case: str, shift: float) -> None:
    positions = HARD_CASES[case]() + shift
    eye = np.array([0.05, 0.08, 0.6]) + shift
    images = []
    for reach in (0.0, REACH):
        scene = scene_from_dict(
            {
                "particles": {"radius": 0.01},
                "image": {"width": 64, "height": 48},
                "camera": {"eye": eye.tolist(), "target": [shift] * 3, "near": 0.01},
                "quality": {"field_normals": reach},
            }
        )
        frame, _ = renderer.render(make_frame(positions), scene, depth=True, normals=True)
        assert np.isfinite(frame.rgba).all()
        assert frame.normals is not None and frame.depth is not None
        covered = np.isfinite(frame.depth)
        assert np.isfinite(frame.normals[covered]).all()
        np.testing.assert_allclose(np.linalg.norm(frame.normals[covered], axis=-1), 1.0, atol=1e-4)
        images.append(frame)
    np.testing.assert_array_equal(images[0].depth, images[1].depth)


@pytest.mark.parametrize("radius", [1e-5, 1e3])
def test_tiny_and_huge_radii(renderer: SurfaceRenderer, radius: float) -> None:
    """The grid's cells scale with the support: the field acts the same at any scale."""
    rng = np.random.default_rng(7)
    positions = rng.normal(0.0, 3.0 * radius, (400, 3))
    frames = []
    for reach in (0.0, REACH):
        scene = scene_from_dict(
            {
                "particles": {"radius": radius},
                "image": {"width": 64, "height": 48},
                "camera": {"eye": [0.0, 0.0, 60.0 * radius], "target": [0.0, 0.0, 0.0],
                           "near": radius},
                "quality": {"field_normals": reach},
            }
        )  # fmt: skip
        frame, _ = renderer.render(make_frame(positions), scene, depth=True, normals=True)
        assert frame.normals is not None and frame.depth is not None
        assert np.isfinite(frame.rgba).all()
        frames.append(frame)
    depth = frames[1].depth
    assert depth is not None
    covered = np.isfinite(depth)
    assert covered.sum() > 100
    normals = [f.normals[covered] for f in frames if f.normals is not None]
    assert np.isfinite(normals[1]).all()
    assert (angle_deg(normals[0], normals[1]) > 1.0).sum() > 20


def test_a_droplet_leaves_no_ring_on_the_pool_behind_it(renderer: SurfaceRenderer) -> None:
    """Through the whole renderer (balanced): three droplets 10 to 20 r over a jittered pool,
    drawn as exact spheres over its smoothed depth. The pool's normals within 6 px of them
    match those of the same frame without the droplets: the field normals' rims are measured
    on the bulk's own depth under a droplet (`SplatOutput.bulk_depth`), so the pool has no rim
    there. What differs is the edge rule's: the pixels next to a droplet difference one-sided,
    which moves a normal of the smoothed pool by about half its change per pixel (measured
    here <= 0.2 deg; bound 1 deg). Taken as rims (the droplets' depth alone), the pool's field
    normals ring every droplet: up to 26 deg, 2.2 deg mean, here."""
    rng = np.random.default_rng(2)
    radius = 0.01
    g = np.arange(-0.3, 0.3001, 2 * radius)
    xs, zs, ys = np.meshgrid(g, g, np.arange(-0.06, 0.0001, 2 * radius), indexing="ij")
    pool = np.stack([xs.ravel(), ys.ravel(), zs.ravel()], -1)
    pool += rng.normal(0.0, 0.3 * radius, pool.shape)
    drops = np.array([[0.0, 0.15, 0.0], [0.08, 0.10, -0.05], [-0.1, 0.2, 0.05]])
    # Real densities (the split uses them): the pool at rest, a lone particle at 0.32 rest.
    densities = rng.uniform(980.0, 1020.0, len(pool))
    scene = scene_from_dict(
        {
            "image": {"width": 192, "height": 128},
            "camera": {"eye": [0.0, 0.6, 0.5], "target": [0.0, 0.0, 0.0]},
            "particles": {"radius": radius},
        }
    )
    with_drops = make_frame(
        np.concatenate([pool, drops]), densities=np.concatenate([densities, [320.0] * 3])
    )
    both, _ = renderer.render(with_drops, scene, depth=True, normals=True)
    without = make_frame(pool, densities=densities)
    alone, _ = renderer.render(without, scene, depth=True, normals=True)
    assert both.depth is not None and alone.depth is not None
    assert both.normals is not None and alone.normals is not None
    on_drop = np.isfinite(both.depth) & ~(both.depth >= alone.depth)
    pool_px = np.isfinite(alone.depth) & ~on_drop
    beside = pool_px & (ndimage.distance_transform_edt(~on_drop) <= 6.0)
    assert on_drop.sum() > 40 and beside.sum() > 300
    change = angle_deg(both.normals[beside].astype(float), alone.normals[beside].astype(float))
    assert change.max() < 1.0, np.sort(change)[-5:]


def test_no_particles(renderer: SurfaceRenderer) -> None:
    scene = scene_from_dict(
        {"image": {"width": 32, "height": 24}, "quality": {"field_normals": 2.0}}
    )
    frame, _ = renderer.render(make_frame(np.zeros((0, 3))), scene, depth=True, normals=True)
    assert np.isfinite(frame.rgba).all()


@pytest.mark.parametrize(
    "kernel", ["studies/field_gradient_gather.comp.glsl", "studies/field_gradient_tiled.comp.glsl"]
)
def test_bench_gradient_kernels_match_the_reference(gl_context: GLContext, kernel: str) -> None:
    """benchmarks/bench_field_gradient.py's two kernels (the normals pass's gather, and tiles
    in shared memory) give the brute-force gradient at the points that need it, and zero at
    the others: the timing compares two right answers."""
    centres = splash(4)
    depth, _ = ray_cast(centres, R)
    ys, xs = np.nonzero(depth > 0)
    z = depth[ys, xs]
    view = np.stack(
        [((xs + 0.5) / W * 2 - 1) * TAN[0] * z, ((ys + 0.5) / H * 2 - 1) * TAN[1] * z, -z], -1
    )
    needed = np.random.default_rng(5).random(len(ys)) < 0.5
    points = np.zeros((H, W, 4), np.float32)
    points[ys, xs, :3] = view
    points[ys, xs, 3] = needed
    with shader_root() as root:  # the study kernels sit beside the product shaders
        programs = ProgramCache(gl_context, ShaderLoader(root))
        context = PassContext(gl_context, programs, FullscreenTriangle(gl_context))
        grid = field_grid.FieldGrid(context)
        ctx = gl_context.ctx
        point_image = ctx.texture((W, H), 4, points.tobytes(), dtype="f4")
        gradient_image = ctx.texture((W, H), 4, dtype="f4")
        try:
            spheres = np.zeros((len(centres), 4), np.float32)
            spheres[:, :3], spheres[:, 3] = centres, R
            built = grid.build(FieldParticles(arrays=(spheres,)), SUPPORT)
            grid.bind_for_reading()
            point_image.bind_to_image(0, read=True, write=False)
            gradient_image.bind_to_image(1, read=False, write=True)
            shader = context.programs.compute(kernel)
            shader["u_support"] = built.support
            shader["u_bucket_mask"] = built.bucket_mask
            shader.run(-(-W // 8), -(-H // 8))
            ctx.memory_barrier()
            out = np.frombuffer(gradient_image.read(), np.float32).reshape(H, W, 4)
        finally:
            point_image.release()
            gradient_image.release()
            grid.release()
            context.fullscreen.release()
            context.programs.release()
    np.testing.assert_array_equal(out[ys[~needed], xs[~needed]], 0.0)
    expected, scale = field_gradient(
        view[needed].astype(np.float32).astype(np.float64),
        centres.astype(np.float32).astype(np.float64),
        SUPPORT,
    )
    got = out[ys[needed], xs[needed]].astype(np.float64)
    good = np.linalg.norm(expected, axis=-1) >= 0.05 * scale
    assert good.mean() > 0.9
    assert angle_deg(got[good, :3], expected[good]).max() < 0.02
    np.testing.assert_allclose(got[:, 3], scale, rtol=1e-4)
