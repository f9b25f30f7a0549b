"""`sphrender bench`: the whole benchmark in one command, writing the table, report and plot.

    sphrender bench --out bench-out/             # full run (tens of minutes on 2 CPU cores)
    sphrender bench --quick --out /tmp/bench     # smoke run (seconds): small scenes, no peers

Full run: the sweep on every reference scene at 1280x720, the headline comparison (a ~90k
ball, `sphrender render` to PNG against VTK's fluid mapper and PyVista on the same particles,
camera and resolution), pysplashsurf and scipy against the OpenCL SPH pass, the real SPH
surfaces with their before / after crops, and scaling with particle count and resolution.
`run_bench(studies=...)` adds a caller's own measurements to a full run (this repository's
REPORT.md: benchmarks/bench_report.py).
"""

from __future__ import annotations

import csv
import os
import platform
import time
from collections.abc import Callable
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from sphrender.core.frame import make_frame
from sphrender.server.bench import peers
from sphrender.server.bench.report import write_plot, write_report
from sphrender.server.bench.results import BenchResults
from sphrender.server.bench.scenes import (
    DAMBREAK_RADIUS,
    BenchScene,
    ball_scene,
    dambreak_frame,
    dambreak_scene,
    droplets_scene,
    slab_scene,
)
from sphrender.server.bench.solid_bench import (
    run_solid_bench,
    run_solid_costs,
    solid_section,
    today_renderer,
    write_solid_crops,
)
from sphrender.server.bench.solid_scenes import bevel_joint_scene, plate_scene, wall_scene
from sphrender.server.bench.surface_bench import (
    QUICK_SURFACE_SETTINGS,
    SURFACE_SETTINGS,
    SurfaceResults,
    SurfaceRow,
    run_surface_bench,
    write_crops,
)
from sphrender.server.bench.sweep import (
    QUICK_SWEEP,
    STAGES,
    SWEEP,
    Setting,
    SweepRow,
    bench_scene_dict,
    run_sweep,
    scene_for,
)
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer

CSV_COLUMNS = (
    "scene",
    "setting",
    "particles",
    "width",
    "height",
    *(f"{stage}_ms" for stage in STAGES),
    "total_ms",
    "host_ms",
    "normal_mean_deg",
    "normal_p95_deg",
    "depth_err_radii",
    "silhouette_iou",
    "psnr_db",
)


def _load() -> str:
    try:
        one, five, _ = os.getloadavg()
    except OSError:
        return "load average unknown"
    return f"load average {one:.2f} (1 min), {five:.2f} (5 min)"


def write_csv(rows: list[SweepRow], path: Path) -> None:
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(CSV_COLUMNS)
        for row in rows:
            m = row.metrics
            writer.writerow(
                [
                    row.scene,
                    row.setting,
                    row.particles,
                    row.width,
                    row.height,
                    *(f"{row.stage_ms[stage]:.2f}" for stage in STAGES),
                    f"{row.total_ms:.2f}",
                    f"{row.host_ms:.2f}",
                    f"{m.normal_mean_deg:.3f}",
                    f"{m.normal_p95_deg:.3f}",
                    f"{m.depth_err_radii:.3f}",
                    f"{m.silhouette_iou:.4f}",
                    f"{row.psnr_db:.2f}",
                ]
            )


def write_surface_csv(surfaces: SurfaceResults | None, path: Path) -> None:
    if surfaces is None:
        return
    names = [f.name for f in fields(SurfaceRow)]
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(names)
        for row in surfaces.rows:
            writer.writerow(
                [
                    v if isinstance(v, str) else f"{v:.4f}"
                    for v in (getattr(row, name) for name in names)
                ]
            )


def _median_frame_ms(renderer: SurfaceRenderer, scene: BenchScene, w: int, h: int) -> float:
    frame = make_frame(scene.positions)
    render_scene = scene_for(Setting("balanced", preset="balanced"), bench_scene_dict(scene, w, h))
    renderer.render(frame, render_scene)
    return float(np.median([renderer.render(frame, render_scene)[1].total_ms for _ in range(3)]))


#: The sweep's default row again with the device prepare: the same image, and the host column
#: of the path a GPU server takes (`auto` picks the host prepare on llvmpipe).
DEVICE_PREPARE = Setting("preset balanced, device prepare", preset="balanced")


def _device_prepare_rows(
    gl: GLContext,
    scene: BenchScene,
    width: int,
    height: int,
    frames: int,
    log: Callable[[str], None],
) -> list[SweepRow]:
    renderer = SurfaceRenderer(gl, prepare="device")
    try:
        return run_sweep(
            renderer, scene, (DEVICE_PREPARE,), width=width, height=height, frames=frames, log=log
        )
    finally:
        renderer.release()


@dataclass(frozen=True)
class StudyContext:
    """What a full run hands `run_bench`'s `studies` after the real SPH surfaces: the GL
    context and renderer, the results so far (a study adds `surface_notes`, `extra_sections`
    and crops), the output folder, the surfaces' resolution and their reference cache."""

    gl: GLContext
    renderer: SurfaceRenderer
    results: BenchResults
    out: Path
    width: int
    height: int
    cache: Path
    log: Callable[[str], None]


def run_bench(
    out: Path,
    *,
    quick: bool,
    width: int,
    height: int,
    frames: int,
    with_peers: bool,
    log: Callable[[str], None] = print,
    studies: Callable[[StudyContext], None] | None = None,
) -> BenchResults:
    """The benchmark into `out`; `studies` runs after the surfaces of a full run."""
    out.mkdir(parents=True, exist_ok=True)
    results = BenchResults()
    results.machine = [
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPU cores, "
        f"{platform.system()} {platform.release()}",
        f"at start: {_load()}",
    ]
    mesh_note = ""
    with GLContext() as gl:
        results.machine.insert(0, f"GL: {gl.renderer}")
        renderer = SurfaceRenderer(gl)
        try:
            scenes, settings, mesh_note = _sweep_scenes(gl, renderer, results, quick)
            for scene in scenes:
                log(f"{scene.name}: {scene.description}, {width}x{height}")
                try:
                    results.rows += run_sweep(
                        renderer,
                        scene,
                        settings,
                        width=width,
                        height=height,
                        frames=frames,
                        log=log,
                    )
                except ImportError as exc:
                    log(f"  {scene.name} skipped: {exc}")
            results.rows += _device_prepare_rows(gl, scenes[0], width, height, frames, log)
            surface_w, surface_h, cache = _run_surfaces(gl, renderer, results, out, quick, log)
            if not quick:
                _run_solids(gl, renderer, results, out, frames, log)
            if studies is not None and not quick:
                context = StudyContext(gl, renderer, results, out, surface_w, surface_h, cache, log)
                studies(context)
            if not quick:
                _run_scaling(renderer, results, log)
        finally:
            renderer.release()
    if mesh_note:
        log(mesh_note)
    if with_peers and not quick:
        _run_peers(results, frames, log)
    results.machine.append(f"at end: {_load()}")
    _write_outputs(results, out, log)
    return results


def _sweep_scenes(
    gl: GLContext, renderer: SurfaceRenderer, results: BenchResults, quick: bool
) -> tuple[list[BenchScene], tuple[Setting, ...], str]:
    """The sweep's scenes and settings, and a note when the dam break could not be added (its
    splashsurf reconstruction's time goes into `results.cpu_peers`)."""
    if quick:
        return [ball_scene(3000), slab_scene(0.3, 3)], QUICK_SWEEP, ""
    scenes = [ball_scene(90_000), slab_scene(1.2, 4), slab_scene(1.0, 1, "sheet")]
    scenes += [droplets_scene(150), plate_scene(), bevel_joint_scene(), wall_scene()]
    dam = dambreak_frame()
    if dam is None:
        return scenes, SWEEP, "dam break skipped: ../shared/data not found"
    from sphrender.server.bench.mesh_reference import rasterise

    def mesh_truth(positions: Any, radius: float, camera: Any) -> Any:
        result, mesh = peers.run_pysplashsurf(positions, radius)
        label = f"{result.name} (dam break, {len(positions)} particles)"
        results.cpu_peers.append((label, result.ms, result.note))
        if mesh is None:
            raise ImportError(result.note)
        return rasterise(gl, renderer.programs, mesh, camera)

    scenes.append(dambreak_scene(dam, mesh_truth, DAMBREAK_RADIUS))
    return scenes, SWEEP, ""


def _run_surfaces(
    gl: GLContext,
    renderer: SurfaceRenderer,
    results: BenchResults,
    out: Path,
    quick: bool,
    log: Callable[[str], None],
) -> tuple[int, int, Path]:
    """The real SPH surfaces and the report's before / after crops; returns their resolution
    and the folder that caches their pysplashsurf references."""
    surface_w, surface_h = (480, 270) if quick else (960, 540)  # quick: a quarter of the pixels
    cache = out / ".reference-cache"
    log(f"real SPH surfaces (spatter, dam break, ball), {surface_w}x{surface_h}")
    surfaces = run_surface_bench(
        gl,
        renderer,
        QUICK_SURFACE_SETTINGS if quick else SURFACE_SETTINGS,
        width=surface_w,
        height=surface_h,
        cache=cache,
        log=log,
    )
    results.surfaces = surfaces
    log(f"  {surfaces.dam_note}")
    write_crops(renderer, out, surfaces, cache=cache, gl=gl)
    return surface_w, surface_h, cache


def _run_solids(
    gl: GLContext,
    renderer: SurfaceRenderer,
    results: BenchResults,
    out: Path,
    frames: int,
    log: Callable[[str], None],
) -> None:
    """The solid workpieces' section: plate and joint at 960x540, costs, crops."""
    log("solid workpieces (plate, bevel joint), 960x540")
    rows = run_solid_bench(renderer, width=960, height=540, frames=frames, log=log)
    today = today_renderer(gl)
    try:
        costs = run_solid_costs(renderer, today, frames=max(3, frames), fluid=ball_scene(90_000))
    finally:
        today.release()
    crops = write_solid_crops(renderer, out)
    results.extra_sections += solid_section(rows, costs, (960, 540), crops)


def _run_scaling(
    renderer: SurfaceRenderer, results: BenchResults, log: Callable[[str], None]
) -> None:
    """The balanced preset's frame time against particle count and against resolution."""
    log("scaling (balanced preset)")
    for count in (10_000, 100_000, 1_000_000):
        scene = ball_scene(count)
        ms = _median_frame_ms(renderer, scene, 1280, 720)
        results.scaling_particles.append((len(scene.positions), ms))
        log(f"  {len(scene.positions):8d} particles 1280x720: {ms:8.1f} ms")
    ball = ball_scene(90_000)
    for w, h in ((640, 360), (1280, 720), (1920, 1080)):
        ms = _median_frame_ms(renderer, ball, w, h)
        results.scaling_resolution.append((w, h, ms))
        log(f"  {len(ball.positions):8d} particles {w}x{h}: {ms:8.1f} ms")


def _write_outputs(results: BenchResults, out: Path, log: Callable[[str], None]) -> None:
    """The sweep's and the surfaces' tables, the Pareto plot and REPORT.md, under `out`."""
    write_csv(results.rows, out / "bench-table.csv")
    plot = write_plot(results.rows, out / "pareto.png")
    if plot is not None:
        log(plot)
    write_surface_csv(results.surfaces, out / "surface-table.csv")
    write_report(results, out / "REPORT.md", plot_name="pareto.png")
    log(f"wrote {out / 'bench-table.csv'}")


def _run_peers(results: BenchResults, frames: int, log: Callable[[str], None]) -> None:
    ball = ball_scene(90_000)
    results.headline_scene = f"{ball.description}, 1280x720, PNG"
    log(f"headline: {results.headline_scene}")
    args = (ball.positions, ball.radius, 1280, 720, ball.camera)
    # sphrender runs before and after the peers, so a change of machine load during the run
    # shows up as a difference between the two instead of silently favouring one side.
    ours = [peers.run_sphrender_render(*args, max(frames, 8))]
    log(f"  sphrender render (balanced): {ours[0].ms} ms  {ours[0].note}")
    others = []
    for name in peers.CHILD_PEERS:
        result = peers.run_child_peer(name, *args, frames)
        others.append(result)
        log(f"  {name}: {result.ms} ms  {result.note}")
    ours.append(peers.run_sphrender_render(*args, max(frames, 8)))
    log(f"  sphrender render (balanced), again: {ours[1].ms} ms  {ours[1].note}")
    times = [r.ms for r in ours if r.ms is not None]
    note = (
        "mean of two runs (before / after the peers: "
        + " / ".join(f"{t:.0f}" for t in times)
        + f" ms); {ours[0].note}"
    )
    results.headline.append(
        peers.PeerResult("sphrender_render", sum(times) / len(times) if times else None, note)
    )
    results.headline += others
    # CPU peers of the SPH pass, on the same ball.
    support = 4 * ball.radius
    mass = 1000.0 * (2 * ball.radius) ** 3
    scipy_ms = peers.scipy_density_ms(ball.positions, support, mass)
    results.cpu_peers.append(("scipy_sph_density", scipy_ms, "cKDTree pairs + float64 sums"))
    log(f"  scipy SPH density: {scipy_ms:.0f} ms")
    try:
        from sphrender.server.engine.gpu.cl_context import CLContext
        from sphrender.server.engine.sph.engine import SphEngine, SphParameters

        with CLContext() as cl:
            engine = SphEngine(cl)
            try:
                params = SphParameters(support, mass, 1000.0, 0.5 / support, 750.0, 0.9 * support)
                engine.compute(ball.positions, params)
                start = time.perf_counter()
                for _ in range(3):
                    engine.compute(ball.positions, params)
                cl_ms = (time.perf_counter() - start) / 3 * 1e3
            finally:
                engine.release()
        results.cpu_peers.append(
            ("sphrender_sph_opencl", cl_ms, f"{cl.device_info.label}: density+colour+flags")
        )
        log(f"  sphrender SPH pass (OpenCL): {cl_ms:.0f} ms")
    except Exception as exc:
        results.cpu_peers.append(("sphrender_sph_opencl", None, f"skipped: {exc}"))
    result, _ = peers.run_pysplashsurf(ball.positions, ball.radius)
    results.cpu_peers.append((f"{result.name} (ball)", result.ms, result.note))
    log(f"  pysplashsurf reconstruction: {result.ms} ms  {result.note}")
