"""Host work of a frame: wall time of `SurfaceRenderer.render` minus the time inside GL and CL.

On a GPU the GL work of a frame takes a few milliseconds and runs beside the CPU; what the render
thread does outside the driver (Python, numpy) is then the frame time. Here, on llvmpipe, the GL
calls are most of the wall time, so the host share is measured the way issue 13 defines it:
profile the call with cProfile and subtract the cumulative time of every call that enters
moderngl or pyopencl from a caller outside them. The profiler's own overhead lands in the host
share, so the number is an upper bound.

`RenderStats.host_ms` is the engine's cheaper, always-on estimate (`gpu/gl_clock.py`: only the
calls the passes time); `host_ms_profiled` checks it.
"""

from __future__ import annotations

import cProfile
import pstats
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

#: Call sites whose file or builtin name starts with one of these are device (driver) calls.
DEVICE_MODULES = ("moderngl", "pyopencl", "_moderngl", "mgl")


@dataclass(frozen=True)
class HostTime:
    wall_ms: float
    device_ms: float  # inside moderngl / pyopencl, entered from outside them

    @property
    def host_ms(self) -> float:
        return self.wall_ms - self.device_ms


def _is_device(func: tuple[str, int, str]) -> bool:
    filename, _, name = func
    if filename == "~":  # a builtin: "<method 'render' of 'moderngl.mgl.VertexArray' objects>"
        return any(f"'{m}" in name or f" {m}." in name for m in DEVICE_MODULES)
    return any(f"/{m}/" in filename or f"/{m}." in filename for m in DEVICE_MODULES)


def profiled(call: Callable[[], Any]) -> tuple[Any, HostTime]:
    """Run `call` under cProfile; its result and the wall / device split of its time."""
    profile = cProfile.Profile()
    start = time.perf_counter()
    result = profile.runcall(call)
    wall = time.perf_counter() - start
    stats: dict[Any, Any] = pstats.Stats(profile).stats  # type: ignore[attr-defined]
    device = 0.0
    for func, (_, _, _, _, callers) in stats.items():
        if not _is_device(func):
            continue
        for caller, edge in callers.items():
            if not _is_device(caller):
                device += edge[3]  # cumulative time of the calls along this edge
    return result, HostTime(wall * 1e3, device * 1e3)
