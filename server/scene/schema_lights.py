"""The scene's direct lights (``[[lights]]``): directional, point and sphere (an arc), each
optionally casting shadows. Re-exported by `schema.py`; cross-field rules in `validate.py`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from sphrender.server.scene.fields import Vec3, spec

LightType = Literal["directional", "point", "sphere"]

#: Most lights a scene may have (uniform arrays in the shading shader are sized for it).
MAX_LIGHTS = 8

#: Shadow map side limits (texels per cube face, or of the directional map).
MIN_SHADOW_MAP = 16
MAX_SHADOW_MAP = 2048


@dataclass(frozen=True)
class LightConfig:
    """One direct light ([[lights]] array of tables). A scene without lights has none."""

    type: LightType = spec(
        "directional",
        "directional (parallel rays, like the sun), point (inverse square) or sphere (a "
        "glowing ball such as a welding arc: soft highlights and soft shadows)",
    )
    color: Vec3 = spec((1.0, 1.0, 1.0), "linear RGB tint multiplied with intensity", low=0.0)
    intensity: float = spec(
        1.0,
        "directional: irradiance on a surface facing the light (scene-linear radiance x sr); "
        "point and sphere: radiant intensity (per sr), divided by distance^2",
        low=0.0,
        high=1e12,
    )
    direction: Vec3 | None = spec(
        None, "directional only: the direction the light travels (from the light to the scene)"
    )
    position: Vec3 | None = spec(
        None, "point and sphere: world position (float64 precision)", unit="scene units"
    )
    radius: float = spec(
        0.0,
        "sphere only: radius of the glowing ball; 0 draws exactly a point light. No preset "
        "sets it; an arc is a few millimetres",
        low=0.0,
        high=1e6,
        unit="scene units",
    )
    angular_radius_deg: float = spec(
        0.0,
        "directional only: angular radius of the light's disc, for the penumbra of its shadows "
        "(the sun: 0.27); 0 = hard shadows. No preset sets it",
        low=0.0,
        high=10.0,
        unit="degrees",
    )
    temperature_k: float | None = spec(
        None,
        "colour of a blackbody at this temperature (luminance 1), multiplied with color; "
        "absent = color alone. No preset sets it; an arc is about 6000 K",
        low=1000.0,
        high=12000.0,
        unit="K",
    )
    shadows: bool = spec(
        False,
        "cast shadows of the particles from this light (shadow map; costs one map per light "
        "per frame). No preset sets it; turn on for the lights that should cast them",
    )
    shadow_map_size: int = spec(
        512,
        "shadow map side in texels (each cube face for point and sphere lights). No preset "
        "sets it; raise for crisper shadows of small particles",
        low=MIN_SHADOW_MAP,
        high=MAX_SHADOW_MAP,
        unit="px",
    )
