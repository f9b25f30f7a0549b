"""Glare and motion blur: cost and error (benchmarks/studies/post_effects.py), and, given a
checkout of another revision with its own .venv (--baseline), the frame time of scenes that use
neither feature here and there, interleaved in one run (the "off costs nothing" check).

    .venv/bin/python benchmarks/bench_post.py [--width 960 --height 540] [--baseline DIR]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

import repo_path  # noqa: F401

from benchmarks.studies.post_effects import run_post_effects
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer

ROOT = Path(__file__).resolve().parents[1]

#: Times the demo (png) and a spatter frame with velocities (shutter 0) in one process: JSON out,
#: wall and CPU time (every thread of the process, llvmpipe's included) per frame, best of all.
_TIMING = """
import json, statistics, sys, time
import numpy as np
from sphrender.core.frame import make_frame
from sphrender.server.content.demo import demo_frame, demo_scene_dict
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.output.local import render_for_output
from sphrender.server.scene import scene_from_dict
width, height, frames = (int(a) for a in sys.argv[1:4])
data = demo_scene_dict(); data["image"] = {"width": width, "height": height}
demo = scene_from_dict(data)
rng = np.random.default_rng(4)
pos = rng.uniform(-0.25, 0.25, (60, 3))
spatter = make_frame(pos, temperatures=np.full(60, 2400, np.float32),
                     velocities=rng.normal(size=(60, 3)).astype(np.float32))
still = scene_from_dict({"image": {"width": width, "height": height},
                         "camera": {"eye": [0.0, 0.0, 1.0]}, "particles": {"radius": 0.008}})
out = {}
with GLContext() as gl:
    r = SurfaceRenderer(gl)
    for name, frame, scene in (("demo", demo_frame(), demo), ("spatter", spatter, still)):
        render_for_output(r, frame, scene, "png")
        wall, cpu = [], []
        for _ in range(frames):
            t, c = time.perf_counter(), time.process_time()
            render_for_output(r, frame, scene, "png")
            wall.append((time.perf_counter() - t) * 1e3)
            cpu.append((time.process_time() - c) * 1e3)
        out[name] = min(wall); out[name + " (CPU)"] = min(cpu)
    r.release()
print(json.dumps(out))
"""


def _timings(python: Path, cwd: Path, width: int, height: int, frames: int) -> dict[str, float]:
    args = [str(python), "-c", _TIMING, str(width), str(height), str(frames)]
    done = subprocess.run(args, cwd=cwd, check=True, capture_output=True, text=True)
    result: dict[str, float] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


def off_versus_baseline(baseline: Path, width: int, height: int, rounds: int) -> list[str]:
    here: dict[str, list[float]] = {}
    there: dict[str, list[float]] = {}
    for _ in range(rounds):  # interleaved, so load on the machine hits both alike
        for python, cwd, into in (
            (Path(sys.executable), ROOT, here),
            (baseline / ".venv" / "bin" / "python", baseline, there),
        ):
            for name, ms in _timings(python, cwd, width, height, 5).items():
                into.setdefault(name, []).append(ms)
    lines = [
        "",
        f"Features off against the baseline ({baseline.name}), {width}x{height} png, median of "
        f"{rounds} interleaved processes, each the best of 5 frames; wall time, and CPU time of "
        "all the process's threads, which the machine's other users disturb less:",
        "",
        "| scene, time | this tree ms | baseline ms | ratio |",
        "|---|---|---|---|",
    ]
    for name in here:
        a, b = statistics.median(here[name]), statistics.median(there[name])
        lines.append(f"| {name} | {a:.1f} | {b:.1f} | {a / b:.3f}x |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--width", type=int, default=960)
    parser.add_argument("--height", type=int, default=540)
    parser.add_argument("--frames", type=int, default=3)
    parser.add_argument("--baseline", type=Path, help="a checkout with its own .venv")
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    with GLContext() as gl:
        renderer = SurfaceRenderer(gl)
        lines = run_post_effects(renderer, args.width, args.height, args.frames)
        renderer.release()
    if args.baseline is not None:
        lines += off_versus_baseline(args.baseline, args.width, args.height, args.rounds)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
