"""Fault injection for the service tests, loaded by the render process only when
``SPHRENDER_FAULT_INJECTION`` names this file (`render/process.py`'s test seam); the installed
package carries no fault code.

``SPHRENDER_TEST_FAULTS`` says which frames fail, by their 1-based number over the life of the
service (`FrameRequest.seq`, so a restarted render process keeps counting):
``gl_error_at_frames=2,5`` raises a GL error in the render step, ``crash_at_frames=3`` makes the
render process read address 0 (a real SIGSEGV), ``hang_at_frames=4`` sleeps for an hour in the
render step (until the watchdog kills the process at ``limits.render_timeout_s``). The same
faults keyed by the frame's particle count instead (``crash_with_particles=777``,
``hang_with_particles=777``) strike every time such a frame is sent, a resend included.
Several specs are separated by ``;``.
"""

from __future__ import annotations

import ctypes
import os
import time
from pathlib import Path

from sphrender.core.frame import ParticleFrame
from sphrender.server.engine.frame_output import RenderedFrame, RenderStats
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.service.render.messages import FrameRequest
from sphrender.server.service.render.process import FAULT_INJECTION_ENV, RenderStep

SPEC_ENV = "SPHRENDER_TEST_FAULTS"


def fault_env(spec: str) -> dict[str, str]:
    """The environment that makes a `sphrender serve` under test fail frames as `spec` says."""
    return {FAULT_INJECTION_ENV: str(Path(__file__).resolve()), SPEC_ENV: spec}


_KINDS = {
    "gl_error_at_frames": "gl_error",
    "crash_at_frames": "crash",
    "hang_at_frames": "hang",
    "crash_with_particles": "crash",
    "hang_with_particles": "hang",
}


def fault_frames(spec: str, by: str = "_at_frames") -> dict[int, str]:
    """{frame number (or particle count, `by`="_with_particles"): "gl_error" | "crash" |
    "hang"} from a spec (module docstring)."""
    faults: dict[int, str] = {}
    for part in spec.split(";"):
        key, _, values = part.strip().partition("=")
        kind = _KINDS.get(key) if key.endswith(by) else None
        if kind is not None:
            faults.update((int(v), kind) for v in values.split(",") if v.strip().isdigit())
    return faults


def wrap_render_step(step: RenderStep) -> RenderStep:
    """`step`, failing the frames `SPEC_ENV` names (called by the render process at start)."""
    spec = os.environ.get(SPEC_ENV, "")
    faults, by_count = fault_frames(spec), fault_frames(spec, "_with_particles")

    def faulty_step(
        request: FrameRequest, renderer: SurfaceRenderer, particles: ParticleFrame
    ) -> tuple[RenderedFrame, RenderStats]:
        fault = faults.get(request.seq) or by_count.get(len(particles.positions))
        if fault == "hang":
            time.sleep(3600)  # a render that never ends: the watchdog kills the process
        if fault == "crash":
            ctypes.string_at(0)  # a native fault: faulthandler prints the stacks, the process dies
        if fault == "gl_error":
            import moderngl

            raise moderngl.Error("injected GL fault")
        return step(request, renderer, particles)

    return faulty_step
