"""The render process's warm-up (server/service/render/warmup.py): after a scene is warmed, the
frames a client sends build no GL program and no OpenCL program of their own (real EGL, PoCL)."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from sphrender.core.frame import ParticleFrame, make_frame
from sphrender.server.content.lattice import jittered_lattice_ball
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.output.local import encode_for_scene, render_for_output
from sphrender.server.scene import Scene, scene_from_dict
from sphrender.server.service.render.warmup import warm_scene


def built(renderer: SurfaceRenderer) -> tuple[int, int]:
    """GL programs and OpenCL programs the renderer holds."""
    return renderer.programs.built, renderer.sph_engine().cl.built


def client_frames(scene: Scene) -> list[ParticleFrame]:
    """What simulators send: ~2000 particles, positions alone, with their densities (a spread
    around rest) and temperatures, with one density for all (replaced), with per-particle radii."""
    r = scene.particles.radius
    positions = jittered_lattice_ball(16 * r, r, center=scene.camera.target, seed=3)
    n = len(positions)
    rest = scene.sph.rest_density
    rng = np.random.default_rng(1)
    densities = rng.uniform(0.3, 1.05, n).astype(np.float32) * rest
    kelvin = rng.uniform(400.0, 2400.0, n).astype(np.float32)
    return [
        make_frame(positions),
        make_frame(positions, densities=densities, temperatures=kelvin),
        make_frame(positions, densities=np.full(n, rest, np.float32)),
        make_frame(positions, radii=np.full(n, r, np.float32), temperatures=kelvin),
    ]


@pytest.mark.parametrize(
    "fmt, size",
    [("png", (96, 64)), ("jpeg", (80, 72)), ("exr", (64, 48))],
)
def test_first_frames_after_warm_build_nothing(
    gl_context: GLContext, fmt: str, size: tuple[int, int], caplog: pytest.LogCaptureFixture
) -> None:
    renderer = SurfaceRenderer(gl_context)
    try:
        with caplog.at_level(logging.WARNING):
            warm_scene(renderer, Scene())  # what the process does at start
        # No note on the warm-up frames: the first client frame that earns one logs it.
        assert [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING] == []
        scene = scene_from_dict(
            {
                "image": {"width": size[0], "height": size[1]},
                "particles": {"radius": 0.02},
                "output": {"format": fmt},
                "camera": {"eye": [0.0, 0.2, 1.5], "target": [0.0, 0.0, 0.0]},
            }
        )
        warm_scene(renderer, scene)  # what HELLO / POST /v1/sessions does
        before = built(renderer)
        assert before[0] > 0 and before[1] > 0  # the warm-up built GL and OpenCL programs
        for frame in client_frames(scene):
            rendered, stats = render_for_output(renderer, frame, scene, fmt)  # type: ignore[arg-type]
            assert stats.particles_drawn > 0
            assert encode_for_scene(rendered, scene, fmt)  # type: ignore[arg-type]
            assert built(renderer) == before, f"a {fmt} frame built a program of its own"
    finally:
        renderer.release()
