"""Host work per frame: what the render thread does outside GL/CL calls (issue 13).

Not a test. Run:  .venv/bin/python benchmarks/bench_host.py [--frames 5] [--sizes 100k,1m]

Renders a jittered-lattice ball (the bench headline shape) with the default preset on the main
thread, as `sphrender render` does, and prints per size: the median wall time of
`SurfaceRenderer.render`, the time inside moderngl/pyopencl calls and the difference (host work,
measured with cProfile: `server/bench/host_time.py`), the engine's own `host_ms` estimate, and
the stage times of an unprofiled frame. On a GPU the host column is the frame time's floor.
"""

from __future__ import annotations

import argparse
import statistics

import numpy as np

from sphrender.client.frame import make_frame
from sphrender.server.bench.host_time import profiled
from sphrender.server.content.lattice import jittered_lattice_ball
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import scene_from_dict

#: name -> (ball radius for ~that many particles at r = 0.01, width, height)
SIZES = {"100k": (0.58, 1280, 720), "1m": (1.25, 1920, 1080)}


def measure(renderer: SurfaceRenderer, name: str, frames: int) -> None:
    ball, width, height = SIZES[name]
    r = 0.01
    frame = make_frame(jittered_lattice_ball(ball, r))
    scale = ball / 0.58
    scene = scene_from_dict(
        {
            "image": {"width": width, "height": height},
            "camera": {"eye": [1.3 * scale, 1.0 * scale, 1.7 * scale], "fov_y": 40.0},
            "particles": {"radius": r},
        }
    )
    renderer.render(frame, scene)  # warm-up: compile, allocate
    walls, devices, hosts, estimates = [], [], [], []
    for _ in range(frames):
        (_, stats), split = profiled(lambda: renderer.render(frame, scene))
        walls.append(split.wall_ms)
        devices.append(split.device_ms)
        hosts.append(split.host_ms)
        estimates.append(getattr(stats, "host_ms", float("nan")))
    _, stats = renderer.render(frame, scene)
    stages = " ".join(f"{k}={v:.1f}" for k, v in stats.stage_ms.items())
    print(
        f"{name:>5} {frame.count:>8} {width}x{height}  wall {statistics.median(walls):7.1f}  "
        f"in GL/CL {statistics.median(devices):7.1f}  host {statistics.median(hosts):6.2f} ms "
        f"(engine estimate {statistics.median(estimates):6.2f})  unprofiled total "
        f"{stats.total_ms:.1f}: {stages}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--frames", type=int, default=5)
    parser.add_argument("--sizes", default="100k,1m")
    parser.add_argument(
        "--prepare", default="host,device", help="prepare modes to measure, comma-separated"
    )
    args = parser.parse_args()
    np.random.seed(0)
    with GLContext() as gl:
        print(f"{gl.renderer}")
        for mode in args.prepare.split(","):
            renderer = SurfaceRenderer(gl, stage_timings=False, prepare=mode)  # type: ignore[arg-type]
            for name in args.sizes.split(","):
                print(f"prepare={mode:6}", end=" ")
                measure(renderer, name, args.frames)
            renderer.release()


if __name__ == "__main__":
    main()
