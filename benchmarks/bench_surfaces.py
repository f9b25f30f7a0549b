"""Surface quality on splashy frames: droplet error (spatter over a pool), edge alpha error,
flicker, and the lattice ball, per quality setting; one GL context, small images.

Usage: python benchmarks/bench_surfaces.py [--width 960 --height 540] [--setting NAME ...]
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np

from sphrender.client.frame import make_frame
from sphrender.client.readers import read_particles
from sphrender.server.bench.mesh_reference import rasterise
from sphrender.server.bench.metrics import surface_metrics
from sphrender.server.bench.peers import run_pysplashsurf
from sphrender.server.bench.scenes import (
    DAMBREAK_RADIUS,
    ball_scene,
    dambreak_frame,
    dambreak_scene,
    spheres_truth,
)
from sphrender.server.bench.surface_quality import (
    SpatterTruth,
    band_error_deg,
    droplet_error_deg,
    edge_alpha_error,
    flicker_deg,
    jittered,
    silhouette_band,
    spatter_scene,
    supersampled_coverage,
)
from sphrender.server.bench.sweep import Setting, bench_scene_dict, scene_for
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.engine.sph.engine import SphParameters
from sphrender.server.scene import scene_from_dict

SETTINGS = {
    "unfiltered": Setting(
        "unfiltered", overrides={"quality": {"filter": "none", "exact_droplets": False}}
    ),
    "previous_default": Setting(
        "previous_default",
        preset="balanced",
        overrides={"quality": {"exact_droplets": False, "antialias": False, "kernel_max_px": 32}},
    ),
    "fast": Setting("fast", preset="fast"),
    "balanced": Setting("balanced", preset="balanced"),
    "best": Setting("best", preset="best"),
}
SETTINGS["balanced_aa"] = Setting(
    "balanced_aa",
    preset="balanced",
    overrides={"quality": {"exact_droplets": True, "antialias": True}},
)
SETTINGS["balanced_aniso"] = Setting(
    "balanced_aniso",
    preset="balanced",
    overrides={
        "quality": {"exact_droplets": True, "antialias": True},
        "sph": {"anisotropy": True},
    },
)
SETTINGS["balanced_droplets"] = Setting(
    "balanced_droplets", preset="balanced", overrides={"quality": {"exact_droplets": True}}
)
for _lam in (2.0, 3.0, 4.0, 6.0):
    SETTINGS[f"balanced_nr{_lam:g}"] = Setting(
        f"balanced_nr{_lam:g}",
        preset="balanced",
        overrides={"quality": {"narrow_range_threshold": _lam}},
    )
for _mode in ("truncate", "blend", "both"):
    SETTINGS[f"balanced_{_mode}"] = Setting(
        f"balanced_{_mode}", preset="balanced", overrides={"quality": {"keep_features": _mode}}
    )
    for _lam in (2.0, 3.0, 4.0):
        SETTINGS[f"balanced_{_mode}_nr{_lam:g}"] = Setting(
            f"balanced_{_mode}_nr{_lam:g}",
            preset="balanced",
            overrides={"quality": {"keep_features": _mode, "narrow_range_threshold": _lam}},
        )


def measure(renderer: SurfaceRenderer, setting: Setting, width: int, height: int) -> dict[str, Any]:
    out: dict[str, Any] = {"setting": setting.name}
    spatter = spatter_scene()
    base = bench_scene_dict(spatter, width, height)
    scene = scene_for(setting, base)
    camera = Camera.from_config(spatter.camera_config(), width, height)
    truth = spatter.truth(camera)
    assert isinstance(truth, SpatterTruth)
    # As a simulator writes them: the kernel densities of the frame (eq 2, computed once here).
    frame = make_frame(spatter.positions, densities=spatter_densities(renderer, spatter))
    renderer.render(frame, scene, depth=True, normals=True)
    start = time.perf_counter()
    rendered, _ = renderer.render(frame, scene, depth=True, normals=True)
    out["spatter_ms"] = (time.perf_counter() - start) * 1e3
    out["droplet_deg"] = droplet_error_deg(rendered, truth)
    coverage = supersampled_coverage(
        lambda cam: spheres_truth(cam, spatter.positions, spatter.radius),
        spatter.camera_config(),
        width,
        height,
    )
    out["edge_alpha_err"] = edge_alpha_error(rendered.rgba[..., 3].astype(np.float64), coverage)
    moved = make_frame(jittered(spatter.positions, spatter.radius, 0.02), densities=frame.densities)
    other, _ = renderer.render(moved, scene, depth=True, normals=True)
    out["flicker_mean_deg"], out["flicker_p99_deg"] = flicker_deg(rendered, other)
    out["spatter_band_deg"] = band_error_deg(
        rendered, truth, silhouette_band(truth, spatter.radius)
    )
    if DAMBREAK is not None:
        dam, dam_truth = DAMBREAK
        dam_camera = Camera.from_config(dam.camera_config(), width, height)
        dam_scene = scene_for(setting, bench_scene_dict(dam, width, height))
        dam_frame = make_frame(dam.positions, densities=DAMBREAK_DENSITIES)
        dam_render, _ = renderer.render(dam_frame, dam_scene, depth=True, normals=True)
        m = surface_metrics(dam_render, dam_camera, dam_truth, dam.radius)
        out["dam_mean_deg"], out["dam_p95_deg"] = m.normal_mean_deg, m.normal_p95_deg
        out["dam_band_deg"] = band_error_deg(
            dam_render, dam_truth, silhouette_band(dam_truth, dam.radius)
        )
        moved, _ = renderer.render(
            make_frame(jittered(dam.positions, dam.radius, 0.02), densities=DAMBREAK_DENSITIES),
            dam_scene,
            depth=True,
            normals=True,
        )
        out["dam_flicker_deg"], _ = flicker_deg(dam_render, moved)
    ball = ball_scene(30_000)
    ball_base = bench_scene_dict(ball, width // 2, height // 2)
    ball_camera = Camera.from_config(ball.camera_config(), width // 2, height // 2)
    ball_frame, _ = renderer.render(
        make_frame(ball.positions), scene_for(setting, ball_base), depth=True, normals=True
    )
    metrics = surface_metrics(ball_frame, ball_camera, ball.truth(ball_camera), ball.radius)
    out["ball_mean_deg"], out["ball_p95_deg"] = metrics.normal_mean_deg, metrics.normal_p95_deg
    return out


DAMBREAK: tuple[Any, Any] | None = None
DAMBREAK_DENSITIES: Any = None


def spatter_densities(renderer: SurfaceRenderer, scene: Any) -> Any:
    params = SphParameters.from_scene(
        scene_from_dict({"particles": {"radius": scene.radius}}), scene.radius
    )
    return renderer.sph_engine().density(scene.positions, params)


def load_dambreak(gl: GLContext, renderer: SurfaceRenderer, width: int, height: int) -> None:
    """The dam-break frame and its pysplashsurf truth at this size (needs ../shared/data and
    pysplashsurf; skipped otherwise)."""
    global DAMBREAK, DAMBREAK_DENSITIES
    path = dambreak_frame()
    if path is None:
        print("dam break skipped: ../shared/data not found")
        return
    result, mesh = run_pysplashsurf(read_particles(path).positions, DAMBREAK_RADIUS)
    if mesh is None:
        print(f"dam break skipped: {result.note}")
        return
    scene = dambreak_scene(
        path, lambda p, r, c: rasterise(gl, renderer.programs, mesh, c), DAMBREAK_RADIUS
    )
    camera = Camera.from_config(scene.camera_config(), width, height)
    DAMBREAK = (scene, scene.truth(camera))
    DAMBREAK_DENSITIES = read_particles(path).densities  # SPlisHSPlasH's own


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--width", type=int, default=960)
    parser.add_argument("--height", type=int, default=540)
    parser.add_argument("--setting", action="append", choices=sorted(SETTINGS))
    args = parser.parse_args()
    names = args.setting or list(SETTINGS)
    with GLContext() as gl:
        renderer = SurfaceRenderer(gl)
        try:
            load_dambreak(gl, renderer, args.width, args.height)
            for name in names:
                row = measure(renderer, SETTINGS[name], args.width, args.height)
                print(
                    " ".join(
                        f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}"
                        for k, v in row.items()
                    ),
                    flush=True,
                )
        finally:
            renderer.release()


if __name__ == "__main__":
    main()
