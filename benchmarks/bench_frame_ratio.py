"""The default preset's frame time against the pre-issue-12 default, side by side (issue 12's
"within 1.5x of today's"; `fast` "no slower").

Not a test. Run:  .venv/bin/python benchmarks/bench_frame_ratio.py [--cycles 20] [--densities]

`--densities` gives the ball its kernel densities (computed once, as a simulator would write
them), so the droplet split runs as on such frames, and balanced asks which particles are alone
(`quality.droplet_lone_density`, sph/density_below.py; "balanced, no lone droplets" without:
2026-12-03, +0.04-0.09x of the pre-issue frame; as an SPH density pass it had cost 1.44x ->
2.0x).

Renders the bench's jittered-lattice ball (~100k particles, no densities) at 1280x720 with each
setting in turn, one frame each per cycle, all in one process on one renderer, so the settings
share every moment of this machine's drift (on these 2-core VMs the speed wanders by +-20 %
within minutes: separate runs, or blocks of frames per setting, give ratios that swing by
0.2-0.3). Prints per setting the median frame time, the ratio of the medians to the pre-issue
setting's and the median of the per-cycle ratios. Wall time of `SurfaceRenderer.render`, no
stage timings (they add a GPU wait per stage), the prepare `auto` picks (host on llvmpipe).
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

from sphrender.core.frame import ParticleFrame, make_frame
from sphrender.server.bench.surface_bench import PLAIN_SMOOTHING
from sphrender.server.bench.sweep import bench_scene_from_dict
from sphrender.server.content.lattice import jittered_lattice_ball
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.engine.sph.engine import SphParameters
from sphrender.server.scene import Scene, merge_scene_dicts
from sphrender.server.scene.presets import preset_sections

VIEW = {
    "image": {"width": 1280, "height": 720},
    "camera": {"eye": [1.3, 1.0, 1.7], "fov_y": 40.0},
    "particles": {"radius": 0.01},
}


def scene_for(preset: str, overrides: dict[str, Any]) -> Scene:
    return bench_scene_from_dict(merge_scene_dicts(preset_sections(preset), {**overrides, **VIEW}))


SETTINGS = {
    "plain smoothing": scene_for(
        PLAIN_SMOOTHING.preset or "balanced", dict(PLAIN_SMOOTHING.overrides)
    ),
    "balanced (default)": scene_for("balanced", {}),
    "balanced, no gaps": scene_for("balanced", {"quality": {"close_gaps": 0.0}}),
    "balanced, no field": scene_for("balanced", {"quality": {"field_normals": 0.0}}),
    "balanced, no pairs": scene_for("balanced", {"quality": {"narrow_range_pairs": 0.0}}),
    "balanced, no stencil": scene_for("balanced", {"quality": {"normal_stencil": 0.0}}),
    "balanced + destreak": scene_for("balanced", {"quality": {"destreak": 0.25}}),
    "balanced, equal passes": scene_for("balanced", {"quality": {"last_pass_sigma": 1.0}}),
    "balanced, no lone droplets": scene_for("balanced", {"quality": {"droplet_lone_density": 0.0}}),
    "balanced + crease test 30°": scene_for("balanced", {"quality": {"crease_angle": 30.0}}),
    "balanced, no guide": scene_for("balanced", {"quality": {"normal_guide": 0.0}}),
    "fast": scene_for("fast", {}),
}


def interleaved_ms(
    renderer: SurfaceRenderer, frame: ParticleFrame, settings: dict[str, Scene], cycles: int
) -> dict[str, list[float]]:
    """Wall ms of `frame` rendered with each setting in turn, one frame each per cycle, after
    two warm-up frames each (programs, targets, IBL caches)."""
    for scene in settings.values():
        renderer.render(frame, scene)
        renderer.render(frame, scene)
    times: dict[str, list[float]] = {name: [] for name in settings}
    for _ in range(cycles):
        for name, scene in settings.items():
            start = time.perf_counter()
            renderer.render(frame, scene)
            times[name].append((time.perf_counter() - start) * 1e3)
    return times


def print_ratios(times: dict[str, list[float]], base: str, width: int = 26) -> None:
    """Per setting: the median, the ratio of medians to `base`'s and the median per-cycle ratio."""
    reference = times[base]
    for name, values in times.items():
        per_cycle = statistics.median(a / b for a, b in zip(values, reference, strict=True))
        print(
            f"{name:{width}} median {statistics.median(values):7.1f} ms  ratio of medians "
            f"{statistics.median(values) / statistics.median(reference):.3f}  median per-cycle "
            f"ratio {per_cycle:.3f}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=20)
    parser.add_argument("--densities", action="store_true", help="frames that carry densities")
    args = parser.parse_args()
    positions = jittered_lattice_ball(0.58, 0.01, seed=0)
    with GLContext() as gl:
        renderer = SurfaceRenderer(gl)
        try:
            frame = make_frame(positions)
            if args.densities:
                params = SphParameters.from_scene(SETTINGS["balanced (default)"], 0.01)
                densities = renderer.sph_engine().density(positions, params)
                frame = make_frame(positions, densities=densities)
            times = interleaved_ms(renderer, frame, SETTINGS, args.cycles)
        finally:
            renderer.release()
    with_densities = ", with densities" if args.densities else ""
    print(f"{gl.renderer}; {frame.count} particles{with_densities}, 1280x720, {args.cycles} cycles")
    print_ratios(times, "plain smoothing")


if __name__ == "__main__":
    main()
