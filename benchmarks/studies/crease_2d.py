"""The default preset against fast on box-like fluid: normal error (mean / p95 deg) of each
setting on the sweep's scenes and camera at 1280x720 (server/bench: scenes, sweep settings,
metrics), plus a fluid block pressed against a solid wall, with the frame and smooth-stage
times against the first setting's, measured interleaved in the same run.

    .venv/bin/python benchmarks/studies/crease_2d.py [--scenes ball,slab,...]
        [--settings fast,balanced,noguide,crease30]
        [--frames 1] [--demo OUT] [--error-maps OUT]

`--demo OUT` also renders the demo's bead (configs/demo.toml, 960x540) with each setting to
OUT/demo-<i>.png (streaks and a sawtooth rim show there, not in the errors); `--error-maps OUT`
writes each scene's per-pixel normal error (0-30 deg, black to white) to OUT/<scene>-<i>.png.
STUDIES.md "The default preset against fast: a 2-D crease rule" and "Adopted: the quarter-size
limits in balanced and best" have the results.
"""

from __future__ import annotations

import argparse
import statistics
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from sphrender.core.frame import make_frame
from sphrender.server.bench import peers
from sphrender.server.bench.analytic import angle_deg, pixel_rays
from sphrender.server.bench.mesh_reference import rasterise
from sphrender.server.bench.metrics import MIN_FACING, surface_metrics
from sphrender.server.bench.scenes import (
    DAMBREAK_RADIUS,
    BenchScene,
    Truth,
    ball_scene,
    dambreak_frame,
    dambreak_scene,
    droplets_scene,
    slab_scene,
)
from sphrender.server.bench.solid_scenes import wall_scene
from sphrender.server.bench.sweep import (
    NO_GUIDE,
    Setting,
    bench_scene_dict,
    preset_setting,
    scene_for,
)
from sphrender.server.engine.frame_output import RenderedFrame
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer

F64 = npt.NDArray[np.float64]
WIDTH, HEIGHT = 1280, 720

SETTINGS: dict[str, Setting] = {
    "fast": preset_setting("fast"),
    "balanced": preset_setting("balanced"),
    "noguide": NO_GUIDE,
    "crease30": Setting("balanced + crease test 30°", {"quality": {"crease_angle": 30.0}}),
}


@dataclass(frozen=True)
class StudyScene:
    scene: BenchScene
    solid: npt.NDArray[np.bool_] | None = None  # per-particle solid flags (None: all fluid)


def _wall() -> StudyScene:
    scene = wall_scene()
    return StudyScene(scene, scene.solid_flags())


def _dambreak(gl: GLContext, renderer: SurfaceRenderer) -> StudyScene | None:
    path = dambreak_frame()
    if path is None:
        return None

    def mesh_truth(positions: F64, radius: float, camera: Camera) -> Truth:
        result, mesh = peers.run_pysplashsurf(positions, radius)
        if mesh is None:
            raise ImportError(result.note)
        return rasterise(gl, renderer.programs, mesh, camera)

    return StudyScene(dambreak_scene(path, mesh_truth, DAMBREAK_RADIUS))


def study_scenes(names: list[str], gl: GLContext, renderer: SurfaceRenderer) -> list[StudyScene]:
    makers: dict[str, Callable[[], StudyScene | None]] = {
        "ball": lambda: StudyScene(ball_scene(90_000)),
        "slab": lambda: StudyScene(slab_scene(1.2, 4)),
        "sheet": lambda: StudyScene(slab_scene(1.0, 1, "sheet")),
        "droplets": lambda: StudyScene(droplets_scene(150)),
        "wall": _wall,
        "dambreak": lambda: _dambreak(gl, renderer),
    }
    return [made for name in names if name and (made := makers[name]()) is not None]


@dataclass(frozen=True)
class Row:
    setting: str
    normal_mean_deg: float
    normal_p95_deg: float
    frame_ms: float
    smooth_ms: float


def error_map(rendered: RenderedFrame, camera: Camera, truth: Truth) -> F64:
    """Per-pixel normal error (deg) over the pixels the metrics count, 0 elsewhere."""
    assert rendered.depth is not None and rendered.normals is not None
    facing = -np.einsum("ijk,ijk->ij", truth.normals, pixel_rays(camera).directions)
    mask = truth.hit & np.isfinite(rendered.depth) & (facing >= MIN_FACING)
    errors = np.zeros(mask.shape)
    errors[mask] = angle_deg(rendered.normals.astype(np.float64)[mask], truth.normals[mask])
    return errors


def measure(
    renderer: SurfaceRenderer,
    study: StudyScene,
    settings: list[Setting],
    frames: int,
    error_maps: Path | None,
) -> list[Row]:
    """One row per setting; the settings render round-robin (after a warm-up frame each), so a
    change of load on the machine hits each alike."""
    scene = study.scene
    frame = make_frame(scene.positions, solid=study.solid)
    base = bench_scene_dict(scene, WIDTH, HEIGHT)
    camera = Camera.from_config(scene.camera_config(), WIDTH, HEIGHT)
    truth = scene.truth(camera)
    scenes = [scene_for(setting, base) for setting in settings]
    for render_scene in scenes:
        renderer.render(frame, render_scene)
    frame_ms: list[list[float]] = [[] for _ in settings]
    smooth_ms: list[list[float]] = [[] for _ in settings]
    last: list[RenderedFrame] = []
    for _ in range(frames):
        last = []
        for index, render_scene in enumerate(scenes):
            rendered, stats = renderer.render(frame, render_scene, depth=True, normals=True)
            frame_ms[index].append(stats.total_ms)
            smooth_ms[index].append(stats.stage_ms.get("smooth", 0.0))
            last.append(rendered)
    rows = []
    for index, setting in enumerate(settings):
        metrics = surface_metrics(last[index], camera, truth, scene.radius)
        if error_maps is not None:
            _write_gray(error_map(last[index], camera, truth) / 30.0, error_maps, scene, index)
        rows.append(
            Row(
                setting.name,
                metrics.normal_mean_deg,
                metrics.normal_p95_deg,
                statistics.median(frame_ms[index]),
                statistics.median(smooth_ms[index]),
            )
        )
    return rows


def _write_gray(values: F64, folder: Path, scene: BenchScene, index: int) -> None:
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    image = (np.clip(values, 0.0, 1.0) * 255).astype(np.uint8)
    Image.fromarray(image).save(folder / f"{scene.name}-{index}.png")


def render_demo(renderer: SurfaceRenderer, settings: list[Setting], out: Path) -> None:
    """The demo's bead with each setting laid over configs/demo.toml, to OUT/demo-<i>.png."""
    from sphrender.server.content.demo import demo_frame, demo_scene_dict
    from sphrender.server.output.local import encode_for_scene, render_for_output

    out.mkdir(parents=True, exist_ok=True)
    frame = demo_frame()
    for index, setting in enumerate(settings):
        scene = scene_for(setting, demo_scene_dict())
        rendered, _ = render_for_output(renderer, frame, scene, "png")
        (out / f"demo-{index}.png").write_bytes(encode_for_scene(rendered, scene, "png"))
        print(f"demo-{index}.png: {setting.name}", flush=True)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--scenes", default="ball,slab,sheet,droplets,wall,dambreak")
    parser.add_argument("--settings", default=",".join(SETTINGS))
    parser.add_argument("--frames", type=int, default=1)
    parser.add_argument("--demo", type=Path, default=None)
    parser.add_argument("--error-maps", type=Path, default=None)
    args = parser.parse_args(argv)
    settings = [SETTINGS[name] for name in args.settings.split(",")]
    with GLContext() as gl:
        renderer = SurfaceRenderer(gl)
        try:
            if args.demo is not None:
                render_demo(renderer, settings, args.demo)
            for study in study_scenes(args.scenes.split(","), gl, renderer):
                _print_rows(
                    study.scene.name,
                    measure(renderer, study, settings, args.frames, args.error_maps),
                )
        finally:
            renderer.release()


def _print_rows(scene: str, rows: list[Row]) -> None:
    first = rows[0]
    for row in rows:
        print(
            f"{scene:9} {row.setting:30} {row.normal_mean_deg:8.4f} / {row.normal_p95_deg:8.4f}  "
            f"frame {row.frame_ms:7.1f} ms ({row.frame_ms / first.frame_ms:4.2f}x)  smooth "
            f"{row.smooth_ms:6.1f} ms ({row.smooth_ms / max(first.smooth_ms, 1e-9):4.2f}x)",
            flush=True,
        )


if __name__ == "__main__":
    main()
