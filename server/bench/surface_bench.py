"""The real-SPH-surface part of `sphrender bench`: per quality setting, on the spatter scene
(analytic truth), the dam-break frame (pysplashsurf reference, where installed) and the
lattice ball: droplet error, edge alpha error, silhouette-band error (plain and
shift-tolerant, see `surface_quality.shift_tolerant_band_error_deg`), flicker under a 2 %-of-r
jitter with the truth's own flicker as its floor, and the ball's error; the front over all of
them; before/after crops (demo, dam break, spatter) as PNGs.

The pysplashsurf reconstructions (the frame and its jittered copy) take seconds each; they are
cached as .npz under the output folder, keyed by the particles' bytes and the parameters.
"""

from __future__ import annotations

import hashlib
import math
import time
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from sphrender.core.frame import make_frame
from sphrender.server.bench.mesh_reference import ReferenceMesh, rasterise, reconstruct
from sphrender.server.bench.metrics import surface_metrics
from sphrender.server.bench.scenes import (
    DAMBREAK_RADIUS,
    BenchScene,
    Truth,
    ball_scene,
    dambreak_frame,
    spheres_truth,
)
from sphrender.server.bench.surface_quality import (
    SpatterTruth,
    band_error_deg,
    droplet_error_deg,
    edge_alpha_error,
    flicker_deg,
    jittered,
    shift_tolerant_band_error_deg,
    silhouette_band,
    spatter_scene,
    spatter_truth,
    split_flicker_deg,
    supersampled_coverage,
    truth_flicker_deg,
)
from sphrender.server.bench.sweep import Setting, bench_scene_dict, preset_setting, scene_for
from sphrender.server.engine.frame_output import RenderedFrame
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.engine.sph.engine import SphParameters
from sphrender.server.scene import scene_from_dict

F64 = npt.NDArray[np.float64]
JITTER = 0.02  # of r
#: The folder under the output directory that holds the report's crops.
CROPS = "crops"


def _hard_cap(px: int) -> dict[str, Any]:
    """Overrides for a kernel cut at `px` pixels, no spread taps past it."""
    return {"quality": {"kernel_max_px": px, "kernel_max_stride": 1}}


#: Balanced's smoothing without its surface features (exact droplets, antialiasing, the normal
#: stencil and rules, gap closing, field normals, the normal guide): the baseline of the
#: report's before / after.
PLAIN_SMOOTHING = Setting(
    "plain smoothing",
    {
        "quality": {
            "exact_droplets": False,
            "antialias": False,
            "kernel_max_px": 32,
            "kernel_max_stride": 1,  # a hard cap
            "normal_stencil": 0.0,  # the 1-pixel difference
            "last_pass_sigma": 1.0,  # equal passes
            "normal_rules": "hard",  # the normals' hard switches
            "narrow_range_pairs": 0.0,  # no pair test
            "close_gaps": 0.0,
            "field_normals": 0.0,
            "normal_guide": 0.0,
        }
    },
    preset="balanced",
)
#: The particle spheres as they splat: no smoothing, no field normals.
UNFILTERED = Setting(
    "unfiltered",
    {"quality": {"filter": "none", "exact_droplets": False, "field_normals": 0.0}},
)
SURFACE_SETTINGS: tuple[Setting, ...] = (
    UNFILTERED,
    PLAIN_SMOOTHING,
    preset_setting("fast"),
    preset_setting("balanced"),
    preset_setting("best"),
    Setting("balanced, hard kernel cap 32 px", _hard_cap(32), preset="balanced"),
    Setting("balanced, hard kernel cap 64 px", _hard_cap(64), preset="balanced"),
    Setting("balanced, hard kernel cap 96 px", _hard_cap(96), preset="balanced"),
    Setting("balanced, no normal stencil", {"quality": {"normal_stencil": 0.0}}, "balanced"),
    Setting("balanced + anisotropy", {"sph": {"anisotropy": True}}, preset="balanced"),
    Setting("balanced, no gaps", {"quality": {"close_gaps": 0.0}}, preset="balanced"),
    Setting("balanced + silhouette normals", {"quality": {"silhouette_normals": 2.0}}, "balanced"),
    Setting("balanced, no field normals", {"quality": {"field_normals": 0.0}}, "balanced"),
)
#: Balanced without its field normals: what they buy (report.py's band line, the crops).
NO_FIELD_NORMALS = SURFACE_SETTINGS[-1]
QUICK_SURFACE_SETTINGS: tuple[Setting, ...] = (
    UNFILTERED,
    PLAIN_SMOOTHING,
    preset_setting("balanced"),
)


@dataclass(frozen=True)
class SurfaceRow:
    setting: str
    spatter_ms: float
    droplet_deg: float
    edge_alpha_err: float
    flicker_deg: float
    spatter_band_deg: float
    dam_band_deg: float = math.nan
    dam_band_fair_deg: float = math.nan
    dam_flicker_deg: float = math.nan
    ball_mean_deg: float = math.nan
    ball_p95_deg: float = math.nan
    #: The spatter's flicker within its truth's silhouette band and outside it.
    flicker_band_deg: float = math.nan
    flicker_inside_deg: float = math.nan


#: Columns of the front, all lower-is-better (time is the spatter frame's).
FRONT_COLUMNS = (
    "spatter_ms",
    "droplet_deg",
    "edge_alpha_err",
    "flicker_deg",
    "dam_band_fair_deg",
    "dam_flicker_deg",
    "ball_mean_deg",
)


@dataclass
class SurfaceResults:
    width: int
    height: int
    rows: list[SurfaceRow] = field(default_factory=list)
    spatter_flicker_floor: float = math.nan
    #: The spatter truth's own flicker within its silhouette band and outside it, and the
    #: band's share of the pixels both truths cover.
    spatter_floor_split: tuple[float, float, float] = (math.nan, math.nan, math.nan)
    dam_flicker_floor: float = math.nan
    dam_note: str = ""
    crops: list[tuple[str, str]] = field(default_factory=list)  # (caption, file name)


def surface_front(rows: list[SurfaceRow]) -> list[SurfaceRow]:
    """Rows no other row matches or beats on every FRONT_COLUMNS value (NaN = not measured,
    compared as equal) while beating it on one."""

    def value(row: SurfaceRow, name: str) -> float:
        v = float(getattr(row, name))
        return math.inf if math.isnan(v) else v

    def dominates(a: SurfaceRow, b: SurfaceRow) -> bool:
        pairs = [(value(a, c), value(b, c)) for c in FRONT_COLUMNS]
        return all(x <= y for x, y in pairs) and any(x < y for x, y in pairs)

    return [row for row in rows if not any(dominates(o, row) for o in rows if o is not row)]


def _key(positions: F64, radius: float) -> str:
    digest = hashlib.sha1(np.ascontiguousarray(positions, np.float64).tobytes())
    digest.update(f"{radius}|iso0.6|support4r|cube0.5|smooth25|normals10".encode())
    return digest.hexdigest()[:16]


def cached_reconstruction(positions: F64, radius: float, cache: Path) -> ReferenceMesh:
    """pysplashsurf's mesh of the particles, from the cache when it holds it (ImportError when
    pysplashsurf is missing and the cache does not)."""
    path = cache / f"splashsurf-{_key(positions, radius)}.npz"
    if path.exists():
        data = np.load(path)
        return ReferenceMesh(data["v"], data["t"], data["n"], float(data["s"]))
    mesh = reconstruct(positions, radius)
    cache.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, v=mesh.vertices, t=mesh.triangles, n=mesh.normals, s=mesh.seconds)
    return mesh


@dataclass(frozen=True)
class Case:
    """One scene of the surface bench: frames (as rendered and jittered) and truths."""

    scene: BenchScene
    camera: Camera
    frame: Any
    moved: Any
    truth: Truth
    band: npt.NDArray[np.bool_]


def spatter_case(
    renderer: SurfaceRenderer, width: int, height: int, *, fixed_length: bool = False
) -> tuple[Case, float, tuple[float, float, float]]:
    """The spatter's case, its truth's own flicker (the floor) and that flicker's split
    (band, inside, the band's share); `fixed_length`: see `surface_quality.jittered`."""
    spatter = spatter_scene()
    camera = Camera.from_config(spatter.camera_config(), width, height)
    params = SphParameters.from_scene(
        scene_from_dict({"particles": {"radius": spatter.radius}}), spatter.radius
    )
    # As a simulator writes them: the frame's kernel densities (eq 2, computed once here).
    densities = renderer.sph_engine().density(spatter.positions, params)
    moved_positions = jittered(spatter.positions, spatter.radius, JITTER, fixed_length=fixed_length)
    truth = spatter.truth(camera)
    n_pool = len(spatter.positions) - 40
    moved_truth = spatter_truth(moved_positions[:n_pool], moved_positions[n_pool:], spatter.radius)
    moved = moved_truth(camera)
    floor = truth_flicker_deg(truth, moved)
    band = silhouette_band(truth, spatter.radius)
    split = split_flicker_deg(truth.normals, moved.normals, truth.hit & moved.hit, band)
    case = Case(
        spatter,
        camera,
        make_frame(spatter.positions, densities=densities),
        make_frame(moved_positions, densities=densities),
        truth,
        band,
    )
    return case, floor, split


def dam_case(
    gl: GLContext,
    renderer: SurfaceRenderer,
    width: int,
    height: int,
    cache: Path,
    path: Path | None = None,
    *,
    fixed_length: bool = False,
) -> tuple[Case | None, float, str]:
    """The dam break's case (frame `path`, the bench's frame 5 by default), the floor of its
    flicker (the reference's own) and a note naming the frame, or why it was skipped;
    `fixed_length`: see `surface_quality.jittered`."""
    from sphrender.core.readers import read_particles
    from sphrender.server.bench.scenes import dambreak_scene

    path = path or dambreak_frame()
    if path is None:
        return None, math.nan, "dam break skipped: ../shared/data not found"
    particles = read_particles(path)
    moved_positions = jittered(
        particles.positions, DAMBREAK_RADIUS, JITTER, fixed_length=fixed_length
    )
    try:
        mesh = cached_reconstruction(particles.positions, DAMBREAK_RADIUS, cache)
        moved_mesh = cached_reconstruction(moved_positions, DAMBREAK_RADIUS, cache)
    except ImportError as exc:
        return None, math.nan, f"dam break skipped: {exc} (pip install pysplashsurf)"
    scene = dambreak_scene(
        path, lambda p, r, c: rasterise(gl, renderer.programs, mesh, c), DAMBREAK_RADIUS
    )
    camera = Camera.from_config(scene.camera_config(), width, height)
    truth = scene.truth(camera)
    floor = truth_flicker_deg(truth, rasterise(gl, renderer.programs, moved_mesh, camera))
    case = Case(
        scene,
        camera,
        make_frame(particles.positions, densities=particles.densities),
        make_frame(moved_positions, densities=particles.densities),
        truth,
        silhouette_band(truth, DAMBREAK_RADIUS),
    )
    return case, floor, f"{path.name}, {len(particles.positions)} particles"


def render_case(renderer: SurfaceRenderer, frame: Any, setting: Setting, case: Case) -> Any:
    w, h = case.camera.width, case.camera.height
    scene = scene_for(setting, bench_scene_dict(case.scene, w, h))
    return renderer.render(frame, scene, depth=True, normals=True)[0]


def run_surface_bench(
    gl: GLContext,
    renderer: SurfaceRenderer,
    settings: tuple[Setting, ...],
    *,
    width: int,
    height: int,
    cache: Path,
    log: Callable[[str], None] = print,
) -> SurfaceResults:
    results = SurfaceResults(width, height)
    spatter, results.spatter_flicker_floor, results.spatter_floor_split = spatter_case(
        renderer, width, height
    )
    coverage = supersampled_coverage(
        lambda cam: spheres_truth(cam, spatter.scene.positions, spatter.scene.radius),
        spatter.scene.camera_config(),
        width,
        height,
    )
    dam, results.dam_flicker_floor, results.dam_note = dam_case(gl, renderer, width, height, cache)
    ball = ball_scene(30_000)
    ball_camera = Camera.from_config(ball.camera_config(), width // 2, height // 2)
    ball_truth = ball.truth(ball_camera)
    for setting in settings:
        scene = scene_for(setting, bench_scene_dict(spatter.scene, width, height))
        renderer.render(spatter.frame, scene, depth=True, normals=True)  # warm-up
        start = time.perf_counter()
        rendered, _ = renderer.render(spatter.frame, scene, depth=True, normals=True)
        ms = (time.perf_counter() - start) * 1e3
        truth = spatter.truth
        assert isinstance(truth, SpatterTruth)
        values: dict[str, float] = {
            "spatter_ms": ms,
            "droplet_deg": droplet_error_deg(rendered, truth),
            "edge_alpha_err": edge_alpha_error(rendered.rgba[..., 3].astype(np.float64), coverage),
            "spatter_band_deg": band_error_deg(rendered, truth, spatter.band),
        }
        moved_render = render_case(renderer, spatter.moved, setting, spatter)
        values["flicker_deg"] = flicker_deg(rendered, moved_render)[0]
        values["flicker_band_deg"], values["flicker_inside_deg"], _ = _split(
            rendered, moved_render, spatter.band
        )
        if dam is not None:
            dam_render: RenderedFrame = render_case(renderer, dam.frame, setting, dam)
            values["dam_band_deg"] = band_error_deg(dam_render, dam.truth, dam.band)
            values["dam_band_fair_deg"] = shift_tolerant_band_error_deg(
                dam_render, dam.truth, dam.band
            )
            moved = render_case(renderer, dam.moved, setting, dam)
            values["dam_flicker_deg"] = flicker_deg(dam_render, moved)[0]
        ball_scene_ = scene_for(setting, bench_scene_dict(ball, width // 2, height // 2))
        ball_frame, _ = renderer.render(
            make_frame(ball.positions), ball_scene_, depth=True, normals=True
        )
        m = surface_metrics(ball_frame, ball_camera, ball_truth, ball.radius)
        values["ball_mean_deg"], values["ball_p95_deg"] = m.normal_mean_deg, m.normal_p95_deg
        row = SurfaceRow(setting.name, **values)
        results.rows.append(row)
        log("  " + " ".join(f"{f.name}={getattr(row, f.name)}" for f in fields(row))[:400])
    return results


def _split(a: RenderedFrame, b: RenderedFrame, band: npt.NDArray[np.bool_]) -> tuple[float, ...]:
    """split_flicker_deg over the pixels both renders cover."""
    assert a.normals is not None and b.normals is not None
    assert a.depth is not None and b.depth is not None
    covered = np.isfinite(a.depth) & np.isfinite(b.depth)
    normals = (a.normals.astype(np.float64), b.normals.astype(np.float64))
    return split_flicker_deg(*normals, covered, band)


def write_crops(
    renderer: SurfaceRenderer,
    out: Path,
    results: SurfaceResults,
    *,
    before: Setting = PLAIN_SMOOTHING,
    after: Setting | None = None,
    width: int = 640,
    height: int = 360,
    cache: Path | None = None,
    gl: GLContext | None = None,
    prefix: str = "crop",
) -> None:
    """Before/after crops (the middle half of each image, side by side) as PNGs in
    `out / CROPS`, named `<prefix>-<scene>.png`."""
    from sphrender.server.content.demo import demo_frame
    from sphrender.server.output.encoders import write_png

    after = after or preset_setting("balanced")
    spatter, _, _ = spatter_case(renderer, width, height)
    cases: list[tuple[str, Callable[[Setting], RenderedFrame]]] = [
        ("spatter", lambda s: render_case(renderer, spatter.frame, s, spatter))
    ]
    if gl is not None and cache is not None:
        dam, _, _ = dam_case(gl, renderer, width, height, cache)
        if dam is not None:
            cases.append(("dambreak", lambda s: render_case(renderer, dam.frame, s, dam)))
    demo_sections = tomllib.loads(
        resources.files("sphrender.configs").joinpath("demo.toml").read_text()
    )
    for section in ("quality", "sph"):  # the setting decides these
        demo_sections.pop(section, None)
    demo_sections["image"] = {"width": width, "height": height}

    def render_demo(setting: Setting) -> RenderedFrame:
        return renderer.render(demo_frame(), scene_for(setting, demo_sections))[0]

    cases.append(("demo", render_demo))
    y0, x0 = height // 4, width // 4
    for name, render in cases:
        halves = [
            render(s).rgba[y0 : y0 + height // 2, x0 : x0 + width // 2] for s in (before, after)
        ]
        gap = np.ones((height // 2, 4, 4), np.float32)
        image = np.concatenate([halves[0], gap, halves[1]], axis=1)
        file = f"{CROPS}/{prefix}-{name}.png"
        (out / CROPS).mkdir(parents=True, exist_ok=True)
        write_png(RenderedFrame(image), out / file)
        results.crops.append((f"{name}: {before.name} (left) / {after.name} (right)", file))
