"""Which particles of a frame are solid workpiece: the frame's `solid` flags, or its temperatures
against the material's solidus (`[solids] source`). The solid part goes to the solid pass, the
rest renders as fluid; a frame with no solid particle is returned as it came (nothing copied).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import numpy.typing as npt

from sphrender.core.frame import ParticleFrame
from sphrender.server.engine.lighting.materials import resolve_material
from sphrender.server.engine.passes.solid_surface import SolidParticles
from sphrender.server.scene import Scene


def solid_mask(frame: ParticleFrame, scene: Scene) -> npt.NDArray[np.bool_] | None:
    """True where a particle is solid, None when the scene and frame say nothing is."""
    source = scene.solids.source
    if source == "flag":
        return frame.solid
    if source == "temperature" and frame.temperatures is not None:
        solidus = resolve_material(scene.material).solidus_k
        return frame.temperatures < np.float32(solidus)
    return None


def split_solid(frame: ParticleFrame, scene: Scene) -> tuple[ParticleFrame, SolidParticles | None]:
    """The fluid part of `frame` and its solid part (None: no particle is solid)."""
    mask = solid_mask(frame, scene)
    if mask is None or not mask.any():
        return frame, None
    keep = ~mask
    radius = scene.particles.radius
    if frame.radii is not None:
        radius = float(np.median(frame.radii[mask]))

    def part(array: np.ndarray | None) -> np.ndarray | None:
        return None if array is None else np.ascontiguousarray(array[keep])

    fluid = replace(
        frame,
        positions=np.ascontiguousarray(frame.positions[keep]),
        densities=part(frame.densities),
        radii=part(frame.radii),
        temperatures=part(frame.temperatures),
        velocities=part(frame.velocities),
        ids=part(frame.ids),
        solid=None,
    )
    temperatures = None if frame.temperatures is None else frame.temperatures[mask]
    return fluid, SolidParticles(np.ascontiguousarray(frame.positions[mask]), radius, temperatures)
