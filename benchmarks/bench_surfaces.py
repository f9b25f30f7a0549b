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
from sphrender.server.bench.metrics import surface_metrics
from sphrender.server.bench.scenes import ball_scene, spheres_truth
from sphrender.server.bench.surface_quality import (
    SpatterTruth,
    droplet_error_deg,
    edge_alpha_error,
    flicker_deg,
    jittered,
    spatter_scene,
    supersampled_coverage,
)
from sphrender.server.bench.sweep import Setting, bench_scene_dict, scene_for
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer

SETTINGS = {
    "unfiltered": Setting("unfiltered", overrides={"quality": {"filter": "none"}}),
    "fast": Setting("fast", preset="fast"),
    "balanced": Setting("balanced", preset="balanced"),
    "best": Setting("best", preset="best"),
}
SETTINGS["balanced_aa"] = Setting(
    "balanced_aa",
    preset="balanced",
    overrides={"quality": {"exact_droplets": True, "antialias": True}},
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
    frame = make_frame(spatter.positions)
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
    moved = make_frame(jittered(spatter.positions, spatter.radius, 0.02))
    other, _ = renderer.render(moved, scene, depth=True, normals=True)
    out["flicker_mean_deg"], out["flicker_p99_deg"] = flicker_deg(rendered, other)
    ball = ball_scene(30_000)
    ball_base = bench_scene_dict(ball, width // 2, height // 2)
    ball_camera = Camera.from_config(ball.camera_config(), width // 2, height // 2)
    ball_frame, _ = renderer.render(
        make_frame(ball.positions), scene_for(setting, ball_base), depth=True, normals=True
    )
    metrics = surface_metrics(ball_frame, ball_camera, ball.truth(ball_camera), ball.radius)
    out["ball_mean_deg"], out["ball_p95_deg"] = metrics.normal_mean_deg, metrics.normal_p95_deg
    return out


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
