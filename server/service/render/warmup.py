"""Warming a scene in the render process, so that a session's first frame costs what its tenth does.

What a first frame would otherwise pay, once per process or per scene (bench_first_frame.py,
STUDIES.md "First frames of a session"): GL programs compiled on first use (each pass builds the
variants a frame's arrays select: temperatures, droplets from the frame's own densities or from
computed ones), the OpenCL context and its kernel builds, the blackbody table of the shade pass,
the read-back of the output's AOVs and display codes, and the encoder's first call. The warm-up
renders a few tiny frames (a ball of a few dozen particles at the camera's target, the scene's
radius) through exactly the path a frame takes, `render_for_output` then the encoder, once per
kind of frame a client sends: positions alone, with densities in the scene's units and
temperatures, and with densities the renderer must replace (computed on OpenCL). Their images are
thrown away; nothing a frame reads is left behind but the caches.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np

from sphrender.server.content.lattice import jittered_lattice_ball

if TYPE_CHECKING:
    from sphrender.core.frame import ParticleFrame
    from sphrender.server.engine.renderer import SurfaceRenderer
    from sphrender.server.scene import Scene

#: Ball radius of the warm-up frames, in particle radii (about 30 particles).
WARM_BALL_RADII = 4.0


def warm_frames(scene: Scene) -> Iterator[ParticleFrame]:
    """The frames that warm `scene` (module docstring)."""
    from sphrender.core.frame import make_frame

    radius = scene.particles.radius
    positions = jittered_lattice_ball(WARM_BALL_RADII * radius, radius, center=scene.camera.target)
    n = len(positions)
    rest = scene.sph.rest_density
    # Densities from a lone droplet's (0.35 rest) to rest: in the scene's units, so used as given.
    fit = np.linspace(0.35 * rest, rest, n, dtype=np.float32)
    kelvin = np.linspace(300.0, 2500.0, n, dtype=np.float32)
    yield make_frame(positions)
    yield make_frame(positions, densities=fit, temperatures=kelvin)


def warm_scene(renderer: SurfaceRenderer, scene: Scene) -> None:
    """Render and encode the warm-up frames of `scene` (on the renderer's owner thread); raises
    what rendering the scene raises (an `InputError` names the scene's bad field)."""
    from sphrender.server.output.local import encode_for_scene, render_for_output

    fmt = scene.output.format
    for frame in warm_frames(scene):
        rendered, _stats = render_for_output(renderer, frame, scene, fmt)
        encode_for_scene(rendered, scene, fmt)
