"""What the passes of one renderer share, owned by the `SurfaceRenderer` and released after them:
the GL context, the compiled-program cache and the full-screen triangle."""

from __future__ import annotations

from dataclasses import dataclass

from sphrender.server.engine.gpu.draw import FullscreenTriangle
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.gpu.programs import ProgramCache

#: The vertex stage of every full-screen pass.
FULLSCREEN_VERT = "common/fullscreen.vert.glsl"


@dataclass(frozen=True)
class PassContext:
    gl: GLContext
    programs: ProgramCache
    fullscreen: FullscreenTriangle
