"""Direct lights on the host: each light's radiance (colour x intensity x blackbody tint) and the
kind the shading shader draws it as. A sphere light of radius 0 is drawn as a point light, so it
renders byte for byte like one."""

from __future__ import annotations

import functools

import numpy as np
import numpy.typing as npt

from sphrender.server.engine.lighting.blackbody import blackbody_rgb, to_gamut
from sphrender.server.scene import LightConfig

#: Light kinds of shade/shade_pbr.frag.glsl (LIGHT_*).
DIRECTIONAL, POINT, SPHERE = 0, 1, 2


def light_kind(light: LightConfig) -> int:
    if light.type == "directional":
        return DIRECTIONAL
    return SPHERE if light.type == "sphere" and light.radius > 0.0 else POINT


@functools.lru_cache(maxsize=64)
def blackbody_tint(kelvin: float) -> tuple[float, float, float]:
    """Linear Rec.709 colour of a blackbody at luminance 1 (clipped into the gamut)."""
    rgb, _ = blackbody_rgb(kelvin)
    r, g, b = (float(c) for c in to_gamut(rgb))
    return r, g, b


def light_radiance(light: LightConfig) -> npt.NDArray[np.float64]:
    """colour x intensity, x the blackbody tint of `temperature_k` when given."""
    radiance = np.asarray(light.color, dtype=np.float64) * light.intensity
    if light.temperature_k is not None:
        radiance = radiance * np.asarray(blackbody_tint(light.temperature_k))
    return radiance
