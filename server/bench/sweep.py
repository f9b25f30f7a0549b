"""Quality settings timed on the engine, with their error against the scene's truth.

Each setting is a set of scene-section overrides applied on top of the bench scene (and of a
preset, for the preset rows). One GL context renders everything; every setting gets a warm-up
frame (programs, IBL caches, render targets) and then `frames` timed frames whose per-stage
medians are reported. Depth and normals are read back for the metrics, so `readback` includes
them (a PNG render reads back colour only).
"""

from __future__ import annotations

import statistics
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sphrender.core.frame import make_frame
from sphrender.server.bench.metrics import (
    SurfaceMetrics,
    display_rgb,
    psnr_db,
    surface_metrics,
)
from sphrender.server.bench.scenes import BenchScene
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import Scene, merge_scene_dicts, scene_from_dict
from sphrender.server.scene.presets import preset_sections

STAGES = ("sph", "prepare", "splat", "smooth", "normals", "solids", "shade", "readback")

Overrides = Mapping[str, Mapping[str, Any]]


@dataclass(frozen=True)
class Setting:
    name: str
    overrides: Overrides = field(default_factory=dict)
    preset: str | None = None


def preset_setting(name: str) -> Setting:
    return Setting(f"preset {name}", preset=name)


#: Balanced without its normal guide: what the guide buys (the sweep's row, the report's crops).
NO_GUIDE = Setting("balanced, no normal guide", {"quality": {"normal_guide": 0.0}})

SWEEP: tuple[Setting, ...] = (
    preset_setting("fast"),
    preset_setting("balanced"),
    preset_setting("best"),
    Setting("filter none", {"quality": {"filter": "none"}}),
    Setting("no occlusion culling", {"quality": {"occlusion_culling": False}}),
    NO_GUIDE,
    Setting("balanced + crease test 30°", {"quality": {"crease_angle": 30.0}}),
    Setting("narrow_range 3 iter", {"quality": {"iterations": 3}}),
    Setting("narrow_range k=1", {"quality": {"kernel_scale": 1.0}}),
    Setting("narrow_range k=1.5", {"quality": {"kernel_scale": 1.5}}),
    Setting("narrow_range k=3", {"quality": {"kernel_scale": 3.0}}),
    Setting("narrow_range k=1.5 1 iter", {"quality": {"kernel_scale": 1.5, "iterations": 1}}),
    Setting("narrow_range 2-D", {"quality": {"separable": False}}),
    Setting("bilateral", {"quality": {"filter": "bilateral"}}),
    Setting("gaussian", {"quality": {"filter": "gaussian"}}),
    Setting("surface-only splat", {"sph": {"surface_only": True}}),
    Setting("IBL none", {"shading": {"ibl_mode": "none"}}),
    Setting("IBL sampled 16", {"shading": {"ibl_mode": "sampled", "ibl_samples": 16}}),
    Setting("IBL sampled 256", {"shading": {"ibl_mode": "sampled", "ibl_samples": 256}}),
)

QUICK_SWEEP: tuple[Setting, ...] = (
    preset_setting("fast"),
    preset_setting("balanced"),
    preset_setting("best"),
    Setting("filter none", {"quality": {"filter": "none"}}),
)

# The image-error reference: the best preset with many GGX samples for the specular light.
REFERENCE = Setting(
    "reference", {"shading": {"ibl_mode": "sampled", "ibl_samples": 1024}}, preset="best"
)


@dataclass(frozen=True)
class SweepRow:
    scene: str
    setting: str
    particles: int
    width: int
    height: int
    stage_ms: dict[str, float]
    total_ms: float
    metrics: SurfaceMetrics
    psnr_db: float
    #: Median render-thread work outside GL calls (RenderStats.host_ms): a GPU frame's floor.
    host_ms: float = 0.0


def bench_scene_dict(scene: BenchScene, width: int, height: int) -> dict[str, dict[str, Any]]:
    """The scene sections every setting starts from: image, camera, radius, one key light."""
    return {
        "image": {"width": width, "height": height},
        "camera": dict(scene.camera),
        "particles": {"radius": scene.radius},
        "lights": [{"direction": [-0.4, -1.0, -0.6], "intensity": 2.0}],  # type: ignore[dict-item]
    }


def bench_scene_from_dict(data: Mapping[str, Any]) -> Scene:
    """`scene_from_dict` that also reads the benchmark's own settings, which scene files do not
    have: ``quality.occlusion_culling`` (off measures what it saves) and ``quality.normal_rules``
    (``"hard"``: the baseline's normals)."""
    return scene_from_dict(data, bench=True)


def scene_for(setting: Setting, base: Mapping[str, Any]) -> Scene:
    sections: dict[str, Any] = dict(preset_sections(setting.preset)) if setting.preset else {}
    sections = merge_scene_dicts(sections, base)
    return bench_scene_from_dict(merge_scene_dicts(sections, setting.overrides))


def run_sweep(
    renderer: SurfaceRenderer,
    scene: BenchScene,
    settings: tuple[Setting, ...],
    *,
    width: int,
    height: int,
    frames: int,
    log: Any = print,
) -> list[SweepRow]:
    frame = make_frame(scene.positions, solid=scene.solid_flags())
    base = bench_scene_dict(scene, width, height)
    camera = Camera.from_config(scene.camera_config(), width, height)
    truth = scene.truth(camera)
    reference_scene = scene_for(REFERENCE, base)
    renderer.render(frame, reference_scene)  # warm-up
    reference_rgb = display_rgb(renderer.render(frame, reference_scene)[0])
    rows = []
    for setting in settings:
        render_scene = scene_for(setting, base)
        renderer.render(frame, render_scene, depth=True, normals=True)  # warm-up
        runs = [
            renderer.render(frame, render_scene, depth=True, normals=True) for _ in range(frames)
        ]
        stage_ms = {
            stage: statistics.median(stats.stage_ms.get(stage, 0.0) for _, stats in runs)
            for stage in STAGES
        }
        total = statistics.median(stats.total_ms for _, stats in runs)
        host = statistics.median(stats.host_ms for _, stats in runs)
        rendered = runs[-1][0]
        metrics = surface_metrics(rendered, camera, truth, scene.radius)
        row = SweepRow(
            scene.name,
            setting.name,
            len(scene.positions),
            width,
            height,
            stage_ms,
            total,
            metrics,
            psnr_db(display_rgb(rendered), reference_rgb),
            host,
        )
        log(
            f"  {scene.name:9} {setting.name:27} {total:8.1f} ms (host {host:5.2f})  normal "
            f"{metrics.normal_mean_deg:5.2f}/{metrics.normal_p95_deg:5.2f} deg  depth "
            f"{metrics.depth_err_radii:5.2f} r  IoU {metrics.silhouette_iou:.3f}  "
            f"PSNR {row.psnr_db:5.1f} dB"
        )
        rows.append(row)
    return rows


def finite(value: float) -> bool:
    return bool(np.isfinite(value))
