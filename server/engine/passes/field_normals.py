"""Field normals (`[quality] field_normals`): the normals near a rim from the SPH field's
gradient, computed inside the normals pass (its FIELD_NORMALS variant).

A screen-space surface is the union of the particle spheres, smoothed. Near a rim (background,
or a depth step: a sheet over the bulk, a hole in a sheet) its depth-differenced normal follows
the spheres' beads and stays flat up to a hole's edge, where the surface a reconstruction
draws (splashsurf's iso-surface of the SPH field) turns smoothly towards the rim. The normal of
that iso-surface is -grad phi / |grad phi| of phi(x) = sum_j W(|x - x_j|, h), which the normals
shader evaluates at each pixel's own surface point within `field_normals` projected particle
radii (at most 7 pixels) of a rim and blends in by the distance to it (full next to the rim,
none beyond the reach). Droplets (lone particles) get their exact sphere normal from it.
Depth, coverage and the rim's place are unchanged. The rule in full:
`shaders/field/field_normals.glsl`.

Inside the normals pass, not after it: on llvmpipe a full-screen pass that only copies the
normal + depth target costs ~8 ms at 1280x720, more than the field's own work.

This module owns the field grid (`field_grid.py`, built on the device every frame the feature
runs) and sets what the shader variant reads from it.
"""

from __future__ import annotations

import moderngl

from sphrender.server.engine.gpu.uniforms import set_if_used
from sphrender.server.engine.passes.context import PassContext
from sphrender.server.engine.passes.field_grid import FieldGrid, FieldParticles

#: Texture unit of the rim tiles in the normals pass's field variant.
TILES_UNIT = 1
DEFINES = {"FIELD_NORMALS": 1}


class FieldNormals:
    def __init__(self, context: PassContext) -> None:
        self._grid = FieldGrid(context)

    def prepare(
        self,
        program: moderngl.Program,
        particles: FieldParticles,
        *,
        support: float,
        reach_radii: float,
    ) -> None:
        """Build the grid of `particles` (SPH support `support`) and set the field variant's
        uniforms and storage bindings; the caller binds the rim tiles to TILES_UNIT."""
        built = self._grid.build(particles, support)
        self._grid.bind_for_reading()
        set_if_used(program, "u_support", built.support)
        set_if_used(program, "u_bucket_mask", built.bucket_mask)
        set_if_used(program, "u_reach_radii", float(reach_radii))

    def release(self) -> None:
        self._grid.release()
