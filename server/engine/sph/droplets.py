"""The droplet classifier: which of a frame's particles skip the smoothing
(`quality.exact_droplets`), from the frame's densities or the positions' own, plus the particles
alone in the frame.

`frame.py`'s `SphStage` asks it once per frame after the [sph] features; it reads densities the
stage already computed, else asks the engine (`SphEngine.density_below`) through `engine`, a
callable that creates the engine only when a pass is needed.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from sphrender.core.frame import ParticleFrame
from sphrender.server.engine.sph.engine import SphEngine, SphParameters, SphResult
from sphrender.server.engine.sph.radii import frame_particle_radius
from sphrender.server.scene import Scene


def wants_exact_droplets(scene: Scene) -> bool:
    """Whether droplets are split off the smoothed surface (`quality.exact_droplets`; only
    when there is smoothing to keep them out of)."""
    return scene.quality.exact_droplets and scene.quality.filter != "none"


def splits_droplets(scene: Scene, frame: ParticleFrame) -> bool:
    """Whether this frame's droplets are split off: exact droplets wanted, and densities at hand
    (the frame's) or leave to compute them (`quality.droplet_density_pass`, or
    `quality.droplet_densities = "computed"`, which always does)."""
    quality = scene.quality
    has_densities = (
        frame.densities is not None
        or quality.droplet_density_pass
        or quality.droplet_densities == "computed"
    )
    return wants_exact_droplets(scene) and has_densities


def computes_droplet_densities(scene: Scene, frame: ParticleFrame) -> bool:
    """Whether the droplet split needs the positions' own densities: the frame has none, the
    scene asks for them (`quality.droplet_densities = "computed"`), or it finds the lone
    particles the frame's densities miss (`quality.droplet_lone_density`). They come from the
    SPH stage's pass when an [sph] feature computed them, else from a pass of the split's own."""
    quality = scene.quality
    own = frame.densities is None or quality.droplet_densities == "computed"
    return (own or quality.droplet_lone_density > 0.0) and splits_droplets(scene, frame)


def droplet_mask(
    frame: ParticleFrame,
    scene: Scene,
    engine: Callable[[], SphEngine],
    computed: SphResult | None = None,
) -> npt.NDArray[np.bool_]:
    """Which of the INPUT frame's particles are droplets: kernel density below
    `quality.droplet_density` x `sph.rest_density`. The densities are the frame's when it has
    them and the scene trusts them (`quality.droplet_densities = "frame"`); else the positions'
    own (`own_below`). Always over the whole input frame: a surface-only subset would
    undercount every neighbourhood (its caller subsets the mask). The frame's densities alone:
    see `lone_particles`, which the caller adds."""
    below = scene.quality.droplet_density * scene.sph.rest_density
    if frame.densities is not None and scene.quality.droplet_densities == "frame":
        return np.asarray(frame.densities) < below
    return own_below(frame, scene, engine, computed, below)


def lone_particles(
    frame: ParticleFrame,
    scene: Scene,
    engine: Callable[[], SphEngine],
    computed: SphResult | None = None,
) -> npt.NDArray[np.bool_] | None:
    """The particles alone in the frame (`quality.droplet_lone_density`), which `droplet_mask`
    misses when the frame's densities count what the frame does not hold (a simulator's walls);
    None when the rule does not apply (off, or the split already uses the positions' own
    densities); `own_below` answers it."""
    quality = scene.quality
    if quality.droplet_lone_density <= 0.0 or frame.densities is None:
        return None
    if quality.droplet_densities != "frame":
        return None
    below = quality.droplet_lone_density * scene.sph.rest_density
    return own_below(frame, scene, engine, computed, below)


def own_below(
    frame: ParticleFrame,
    scene: Scene,
    engine: Callable[[], SphEngine],
    computed: SphResult | None,
    below: float,
) -> npt.NDArray[np.bool_]:
    """Which particles' own eq 2 density (from the positions) is below `below`: the densities
    the SPH stage computed (`computed`, when they are its own: no second pass), else
    `SphEngine.density_below`, which stops each particle's sum once it passes the limit."""
    if computed is not None and computed.density_computed:
        return np.asarray(computed.density) < below
    params = SphParameters.from_scene(scene, frame_particle_radius(frame, scene))
    return engine().density_below(frame.positions, params, below)
