"""The studies this repository's REPORT.md adds to `sphrender bench` (`run_bench(studies=...)`,
run by benchmarks/bench_report.py): the dam break on every frame of the data set, the flicker
under both readings of the jitter, the compact frame encoding (wire_report.py), and the crops
of what field normals, `last_pass_sigma` and `destreak` change: each needs ../shared/data (and
pysplashsurf, or the reference cache) and is skipped without it. Shadows (cost per light, error),
the brushed plate's finish costs and crop, and the cost and error of glare and motion blur
(built-in scenes) need nothing outside.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from benchmarks.studies import heat_report
from benchmarks.studies.brushed_plate import measure as measure_brushed_plate
from benchmarks.studies.brushed_plate import section as brushed_plate_section
from benchmarks.studies.brushed_plate import write_crop as write_brushed_plate_crop
from benchmarks.studies.brushed_plate import write_marks
from benchmarks.studies.closeup_crop import BALANCED_DESTREAK, EQUAL_PASSES, write_closeup_crop
from benchmarks.studies.dam_frames import (
    dam_frame_counts,
    dam_frame_paths,
    dam_frames_section,
    run_dam_frames,
    surface_notes,
)
from benchmarks.studies.guide_crops import write_guide_crops
from benchmarks.studies.jitter_readings import jitter_readings_section, run_jitter_readings
from benchmarks.studies.post_effects import run_post_effects
from benchmarks.studies.shadows import shadows_section
from benchmarks.studies.wire_report import wire_section
from sphrender.server.bench.run import StudyContext
from sphrender.server.bench.surface_bench import (
    NO_FIELD_NORMALS,
    PLAIN_SMOOTHING,
    UNFILTERED,
    write_crops,
)
from sphrender.server.bench.sweep import preset_setting
from sphrender.server.engine.renderer import SurfaceRenderer

#: The report's first paragraph: how to regenerate it.
COMMAND = (
    "`.venv/bin/python benchmarks/bench_report.py` (after `pip install -e '.[bench]'`; about "
    "15 minutes on 2 CPU cores)"
)


def run_studies(ctx: StudyContext) -> None:
    """The studies into `ctx.results` (sections, target notes, crops) and `ctx.out`."""
    results, log = ctx.results, ctx.log
    results.command = COMMAND
    balanced = preset_setting("balanced")
    _dam_frames(ctx)
    log("flicker under both readings of the jitter")
    readings = run_jitter_readings(
        ctx.gl,
        ctx.renderer,
        (PLAIN_SMOOTHING, balanced),
        width=ctx.width,
        height=ctx.height,
        cache=ctx.cache,
        log=log,
    )
    if readings:
        results.extra_sections += [*jitter_readings_section(readings), ""]
    results.extra_sections += wire_section(quick=False, link=True, log=log)
    log("shadows: cost per light and error against the truth")
    results.extra_sections += shadows_section(ctx.renderer, log=log)
    _brushed_plate(ctx)
    log("glare and motion blur: cost and error")
    results.extra_sections += [*run_post_effects(ctx.renderer, ctx.width, ctx.height), ""]
    log("heat tint: cost; the demo's crop")
    results.extra_sections += heat_report.section(heat_report.measure(ctx.gl, log=log))
    heat_report.write_demo_crop(ctx.renderer, ctx.out)
    surfaces = results.surfaces
    if surfaces is None:
        return
    # what field normals change
    write_crops(
        ctx.renderer,
        ctx.out,
        surfaces,
        before=NO_FIELD_NORMALS,
        after=balanced,
        cache=ctx.cache,
        gl=ctx.gl,
        prefix="crop-field",
    )
    # what the normal guide changes, on whole images
    surfaces.crops += write_guide_crops(ctx.renderer, ctx.out)
    # what last_pass_sigma and destreak change on a close-up of a real frame
    for before, after, name in (
        (EQUAL_PASSES, balanced, "crop-closeup-dambreak.png"),
        (balanced, BALANCED_DESTREAK, "crop-closeup-destreak-dambreak.png"),
    ):
        write_closeup_crop(ctx.renderer, ctx.out, surfaces, before=before, after=after, name=name)


def _brushed_plate(ctx: StudyContext) -> None:
    """The finish's costs and crop, on a renderer that may read the image detail's height map
    (written into a temporary asset directory, as `sphrender render --env-dir` would name it)."""
    ctx.log("brushed plate: what the finish costs")
    with tempfile.TemporaryDirectory() as assets:
        write_marks(Path(assets))
        renderer = SurfaceRenderer(ctx.gl, environment_dirs=[assets])
        try:
            rows = measure_brushed_plate(renderer, log=ctx.log)
            ctx.results.extra_sections += brushed_plate_section(rows)
            write_brushed_plate_crop(renderer, ctx.out)
        finally:
            renderer.release()


def _dam_frames(ctx: StudyContext) -> None:
    """The dam break on every frame of the data set: its section, and its counts beside the
    surface targets (skipped without the data set or pysplashsurf)."""
    paths = dam_frame_paths()
    if not paths:
        ctx.log("dam break, every frame: skipped (../shared/data not found)")
        return
    ctx.log(f"dam break, every frame ({len(paths)}), {ctx.width}x{ctx.height}")
    settings = (PLAIN_SMOOTHING, UNFILTERED, preset_setting("balanced"))  # unfiltered: droplets
    try:
        rows = run_dam_frames(
            ctx.gl,
            ctx.renderer,
            settings,
            paths,
            width=ctx.width,
            height=ctx.height,
            cache=ctx.cache,
            log=ctx.log,
        )
    except ImportError as exc:
        ctx.log(f"  skipped: {exc}")
        return
    ctx.results.surface_notes.update(surface_notes(dam_frame_counts(rows, "preset balanced")))
    section = dam_frames_section(rows)
    if section:
        ctx.results.extra_sections += [*section, ""]
