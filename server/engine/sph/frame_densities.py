"""Whether a frame's own densities can be used: they must be in the scene's units and tell the
particles apart.

The droplet split compares densities with `quality.droplet_density` x `sph.rest_density`, and
the colour field weighs neighbours by m / rho_j with m = rest_density (2 r)^3: both take the
frame's densities to be in the units of `sph.rest_density` (1000 by default: water in
kg/m^3). A simulator of molten steel writes ~7000 kg/m^3, an aluminium one ~2400, a
normalised one rho / rho_0 ~ 1, a CGS one ~1 g/cm^3. Taken as they come, steel's densities
make no particle a droplet (spatter flattened into the pool: the dam break's frame 13 at
960x540, tolerant band 9.06 -> 9.98 deg with its densities x 7), normalised ones make every
particle a droplet (nothing smoothed: mean normal error 10.1 -> 35.0 deg with x 1e-3).

Two tests, on the host, one pass over the array each (~6 us per 100k particles), no copy:
* **units**: the frame's largest density lies within FIT_RANGE x rest density. A frame with any
  fluid at rest peaks near rest density (incompressible solvers hold it within a few per cent,
  weakly compressible ones within ~10 %; splashes compress briefly by some tens of per cent);
  other units or another fluid's rest density peak far outside. A frame of spray alone (a lone
  particle reads 0.32 rest, a pair 0.40) fails the test too, harmlessly (below);
* **not constant**: an exporter that writes one value for every particle (its rest density,
  say) tells a droplet from the bulk no better than no densities at all (the dam break's frame
  5 with every density 1000: no droplet split, tolerant band 8.10 -> 8.39 deg).
A frame that fails either gets the densities of the positions themselves (eq 2 on OpenCL, with
the scene's mass), which are in the scene's units by construction, for the cost of that pass,
and the frame's answer carries a note saying so (`unfit_note`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from sphrender.core.frame import ParticleFrame
from sphrender.server.engine.frame_output import InputNote
from sphrender.server.scene import Scene

#: The frame's largest density over sph.rest_density within which its densities are used.
FIT_RANGE = (0.5, 1.5)


def density_range(frame: ParticleFrame) -> tuple[float, float] | None:
    """The frame's smallest and largest density (None: no densities, or no particle)."""
    if frame.densities is None or not frame.count:
        return None
    return float(np.min(frame.densities)), float(np.max(frame.densities))


def largest_density_ratio(frame: ParticleFrame, scene: Scene) -> float | None:
    """The frame's largest density over `sph.rest_density` (None: no densities, or none to
    read)."""
    extremes = density_range(frame)
    return None if extremes is None else extremes[1] / scene.sph.rest_density


def unfit_reason(frame: ParticleFrame, scene: Scene) -> str | None:
    """Why the frame's densities cannot be used, in words for the client; None when they can
    (or there are none: nothing to distrust)."""
    extremes = density_range(frame)
    if extremes is None:
        return None
    smallest, largest = extremes
    rest = scene.sph.rest_density
    ratio = largest / rest
    if not FIT_RANGE[0] <= ratio <= FIT_RANGE[1]:
        return (
            f"the frame's densities peak at {ratio:.3g} x sph.rest_density ({rest:g}), outside "
            f"{FIT_RANGE[0]:g}-{FIT_RANGE[1]:g} x: taken as other units or another fluid; set "
            "sph.rest_density to the simulation's rest density (e.g. ~7000 for molten steel in "
            "kg/m^3) to use them"
        )
    if smallest == largest and frame.count > 1:
        return (
            f"every particle of the frame has the same density ({largest:g}): it cannot tell "
            "droplets from the bulk"
        )
    return None


def densities_fit(frame: ParticleFrame, scene: Scene) -> bool:
    """Whether the frame's densities can be used (True without any)."""
    return unfit_reason(frame, scene) is None


def without_unfit_densities(frame: ParticleFrame, scene: Scene) -> tuple[ParticleFrame, Scene]:
    """The frame and scene the SPH stage should work on: as they are when the frame's densities
    fit the scene; else the frame without its densities (the colour field computes its own)
    and the scene with the droplet split on computed ones (so the split still happens, on
    densities the pass computes from the positions)."""
    if densities_fit(frame, scene):
        return frame, scene
    quality = replace(scene.quality, droplet_densities="computed")
    return replace(frame, densities=None), replace(scene, quality=quality)


def unfit_note(frame: ParticleFrame, scene: Scene, *, computed: bool = True) -> InputNote:
    """What the client is told about a frame whose densities were not used: replaced by
    computed ones, or (`computed` False: no OpenCL device) no droplet split at all."""
    reason = unfit_reason(frame, scene) or "the frame's densities could not be used"
    if computed:
        return InputNote(
            "densities", f"{reason}; replaced by densities computed from the positions"
        )
    return InputNote("densities", f"{reason}; no OpenCL device to compute others: no droplet split")
