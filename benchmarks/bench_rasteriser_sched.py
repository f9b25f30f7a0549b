"""llvmpipe's rasteriser threads under SCHED_BATCH (what `GLContext` does) against the default
policy, side by side (issue 13's "no contention"; `server/engine/gpu/rasteriser_threads.py`).

Not a test. Run:  .venv/bin/python benchmarks/bench_rasteriser_sched.py [--cycles 20]

A thread's scheduling policy can change at any moment, so both policies are measured in one
process on one renderer per prepare mode, alternating frame by frame: they share every moment of
this VM's drift. Renders the bench's jittered-lattice ball (~100k particles) at 1280x720 with
the default preset, no stage timings, with the host prepare (llvmpipe's default) and the device
prepare (a GPU server's path), and prints per mode and policy the median frame time, the median
of the per-cycle frame ratios (batch / default) and the median host work (`RenderStats.host_ms`,
the render thread's time outside GL calls), plus one cProfile host figure per policy (the
issue's method: `benchmarks/studies/host_time.py`).
"""

from __future__ import annotations

import argparse
import os
import statistics

import repo_path  # noqa: F401

from benchmarks.studies.host_time import profiled
from sphrender.core.frame import make_frame
from sphrender.server.content.lattice import jittered_lattice_ball
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.gpu.rasteriser_threads import rasteriser_threads
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import scene_from_dict

SCENE = scene_from_dict(
    {
        "image": {"width": 1280, "height": 720},
        "camera": {"eye": [1.3, 1.0, 1.7], "fov_y": 40.0},
        "particles": {"radius": 0.01},
    }
)
POLICIES = {"default": os.SCHED_OTHER, "batch": os.SCHED_BATCH}


def set_policy(policy: int) -> None:
    for tid in rasteriser_threads():
        os.sched_setscheduler(tid, policy, os.sched_param(0))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=20)
    args = parser.parse_args()
    frame = make_frame(jittered_lattice_ball(0.58, 0.01, seed=0))
    with GLContext() as gl:
        if not rasteriser_threads():
            print(f"{gl.renderer}: no llvmpipe worker threads, nothing to compare")
            return
        renderers = {
            mode: SurfaceRenderer(gl, stage_timings=False, prepare=mode)  # type: ignore[arg-type]
            for mode in ("host", "device")
        }
        as_made = os.sched_getscheduler(rasteriser_threads()[0])  # what GLContext chose
        try:
            for renderer in renderers.values():
                renderer.render(frame, SCENE)  # warm-up: programs, targets, IBL caches
            frames: dict[tuple[str, str], list[float]] = {}
            hosts: dict[tuple[str, str], list[float]] = {}
            profiled_host: dict[tuple[str, str], list[float]] = {}
            for _ in range(args.cycles):
                for name, policy in POLICIES.items():
                    set_policy(policy)
                    for mode, renderer in renderers.items():
                        _, stats = renderer.render(frame, SCENE)
                        frames.setdefault((mode, name), []).append(stats.total_ms)
                        hosts.setdefault((mode, name), []).append(stats.host_ms)
                        _, split = profiled(lambda r=renderer: r.render(frame, SCENE))
                        profiled_host.setdefault((mode, name), []).append(split.host_ms)
            print(
                f"{gl.renderer}, {len(rasteriser_threads())} llvmpipe threads, {args.cycles} cycles"
            )
            median = statistics.median
            for mode in renderers:
                base, batch = frames[(mode, "default")], frames[(mode, "batch")]
                ratio = median(b / a for a, b in zip(base, batch, strict=True))
                print(
                    f"prepare={mode:6} frame {median(base):6.1f} -> {median(batch):6.1f} ms "
                    f"(per-cycle ratio {ratio:.3f})  host {median(hosts[(mode, 'default')]):6.2f} "
                    f"-> {median(hosts[(mode, 'batch')]):6.2f} ms  cProfile host "
                    f"{median(profiled_host[(mode, 'default')]):6.2f} -> "
                    f"{median(profiled_host[(mode, 'batch')]):6.2f} ms"
                )
        finally:
            set_policy(as_made)
            for renderer in renderers.values():
                renderer.release()


if __name__ == "__main__":
    main()
