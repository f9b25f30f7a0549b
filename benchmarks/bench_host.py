"""Host work per frame: what the render thread does outside GL/CL calls (issue 13).

Not a test. Run:  .venv/bin/python benchmarks/bench_host.py [--frames 5] [--sizes 100k,1m,4k]

Renders a jittered-lattice ball (the bench headline shape) with the default preset on the main
thread, as `sphrender render` does, and prints per size: the median wall time of
`SurfaceRenderer.render`, the time inside moderngl/pyopencl calls and the difference (host work,
measured with cProfile: `benchmarks/studies/host_time.py`), the engine's own `host_ms` estimate in
the same profiled frames, then the engine's estimate in unprofiled frames (cProfile's own cost,
~1 us a call on this VM, is part of the first two; the engine's estimate counts the unwrapped
GL calls as host work, so it errs high), the same with the Z and N AOVs read back, and the
stage times of an unprofiled frame. On a GPU the host column is the frame time's floor.
`--stage-timing-cost` adds, per prepare mode, the first size's frame with a `finish` after each
stage (true stage times: what the service runs) against the same without, frame by frame.

On llvmpipe the rasteriser's worker threads run beside the render thread on the same cores
(under SCHED_BATCH since `gpu/rasteriser_threads.py`, so they no longer preempt it when they
wake; `SPHRENDER_LLVMPIPE_BATCH=0` measures the old way, `benchmarks/bench_rasteriser_sched.py`
both side by side). `--lp-threads default,0` measures llvmpipe as it runs by default and with
`LP_NUM_THREADS=0` (llvmpipe rasterises inside the GL calls, so nothing runs beside the render
thread outside them).
Each setting runs in its own process (Mesa reads the variable when the context is made).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time

import numpy as np
import repo_path  # noqa: F401

from benchmarks.studies.host_time import profiled
from sphrender.core.frame import ParticleFrame, make_frame
from sphrender.server.content.lattice import jittered_lattice_ball
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import Scene, scene_from_dict

#: name -> (ball radius for ~that many particles at r = 0.01, width, height). "4k" is the
#: control: the same passes and the same Python calls as "100k" (over the occlusion culling's
#: 2048-particle threshold), with almost no GL work. On llvmpipe the GL work is the CPU's, and
#: the render thread's code after each GL call runs on caches the rasteriser has just evicted
#: (and beside its threads): the control's host time is what the same Python costs beside a
#: device that does not share the CPU.
SIZES = {"100k": (0.58, 1280, 720), "1m": (1.25, 1920, 1080), "4k": (0.2, 160, 90)}


def ball_case(name: str) -> tuple[ParticleFrame, Scene]:
    ball, width, height = SIZES[name]
    r = 0.01
    scale = ball / 0.58
    scene = scene_from_dict(
        {
            "image": {"width": width, "height": height},
            "camera": {"eye": [1.3 * scale, 1.0 * scale, 1.7 * scale], "fov_y": 40.0},
            "particles": {"radius": r},
        }
    )
    return make_frame(jittered_lattice_ball(ball, r)), scene


def measure(renderer: SurfaceRenderer, name: str, frames: int) -> None:
    frame, scene = ball_case(name)
    width, height = scene.image.width, scene.image.height
    renderer.render(frame, scene)  # warm-up: compile, allocate
    walls, devices, hosts, estimates = [], [], [], []
    for _ in range(frames):
        (_, stats), split = profiled(lambda: renderer.render(frame, scene))
        walls.append(split.wall_ms)
        devices.append(split.device_ms)
        hosts.append(split.host_ms)
        estimates.append(getattr(stats, "host_ms", float("nan")))
    plain = [renderer.render(frame, scene)[1] for _ in range(frames)]
    aovs = [renderer.render(frame, scene, depth=True, normals=True)[1] for _ in range(frames)]
    stages = " ".join(f"{k}={v:.1f}" for k, v in plain[-1].stage_ms.items())
    print(
        f"{name:>5} {frame.count:>8} {width}x{height}  wall {statistics.median(walls):7.1f}  "
        f"in GL/CL {statistics.median(devices):7.1f}  host {statistics.median(hosts):6.2f} ms "
        f"(engine estimate {statistics.median(estimates):6.2f}; unprofiled "
        f"{statistics.median(s.host_ms for s in plain):6.2f}, with Z+N "
        f"{statistics.median(s.host_ms for s in aovs):6.2f})  unprofiled total "
        f"{plain[-1].total_ms:.1f}: {stages}"
    )


def stage_timing_cost(gl: GLContext, mode: str, name: str, frames: int) -> None:
    """The frame with true stage times (a `finish` after each stage: what `sphrender serve`
    and `render -v` run) against the same frame without, alternating frame by frame on two
    renderers of one context: on a GPU the finishes stop the CPU from running ahead."""
    frame, scene = ball_case(name)
    renderers = {
        timed: SurfaceRenderer(gl, stage_timings=timed, prepare=mode)  # type: ignore[arg-type]
        for timed in (True, False)
    }
    walls: dict[bool, list[float]] = {True: [], False: []}
    try:
        for renderer in renderers.values():
            renderer.render(frame, scene)
        for _ in range(frames):
            for timed, renderer in renderers.items():
                start = time.perf_counter()
                renderer.render(frame, scene)
                walls[timed].append((time.perf_counter() - start) * 1e3)
    finally:
        for renderer in renderers.values():
            renderer.release()
    with_, without = statistics.median(walls[True]), statistics.median(walls[False])
    print(
        f"prepare={mode:6} {name:>5} stage timings on (a finish per stage) {with_:7.1f} ms, "
        f"off {without:7.1f} ms: {with_ / without:.3f}x"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--frames", type=int, default=5)
    parser.add_argument("--sizes", default="100k,1m,4k", help=f"of {', '.join(SIZES)}")
    parser.add_argument(
        "--prepare", default="host,device", help="prepare modes to measure, comma-separated"
    )
    parser.add_argument(
        "--stage-timing-cost",
        action="store_true",
        help="also time the first size's frame with and without a finish per stage",
    )
    parser.add_argument(
        "--lp-threads",
        default="",
        help="llvmpipe thread settings to measure, each in its own process: 'default' and/or "
        "a number for LP_NUM_THREADS (e.g. default,0); empty: this process as it is",
    )
    args = parser.parse_args()
    if args.lp_threads:
        for setting in args.lp_threads.split(","):
            env = dict(os.environ)
            env.pop("LP_NUM_THREADS", None)
            if setting != "default":
                env["LP_NUM_THREADS"] = setting
            print(f"--- LP_NUM_THREADS={env.get('LP_NUM_THREADS', '(default)')}", flush=True)
            same = ["--frames", str(args.frames), "--sizes", args.sizes, "--prepare", args.prepare]
            same += ["--stage-timing-cost"] if args.stage_timing_cost else []
            subprocess.run([sys.executable, __file__, *same], env=env, check=True)
        return
    np.random.seed(0)
    with GLContext() as gl:
        print(f"{gl.renderer}; llvmpipe threads under SCHED_BATCH: {gl.batch_rasteriser_threads}")
        for mode in args.prepare.split(","):
            renderer = SurfaceRenderer(gl, stage_timings=False, prepare=mode)  # type: ignore[arg-type]
            for name in args.sizes.split(","):
                print(f"prepare={mode:6}", end=" ")
                measure(renderer, name, args.frames)
            renderer.release()
            if args.stage_timing_cost:
                stage_timing_cost(gl, mode, args.sizes.split(",")[0], max(args.frames, 5))


if __name__ == "__main__":
    main()
