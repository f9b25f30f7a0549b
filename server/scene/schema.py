"""Scene configuration: every field typed and documented in one place.

A scene is loaded from TOML (``configs/*.toml``) or from a JSON-like dict (the wire format uses the
same schema). Validation is strict: unknown keys, wrong types and out-of-range values raise
`InputError` naming the dotted key and the allowed range, e.g. ``camera.fov_y: must be in
(0, 180), got 190``.

Each section is a frozen dataclass; each field carries its documentation and range in
``metadata`` (see `spec`), which is what the validator reads and what ``sphrender render --help``
could list. Adding a field means adding one line here. Validation lives in `validate.py`
(dict -> dataclasses, cross-field rules), files and merging in `files.py`; the package's
`__init__` is the public surface (`from sphrender.server.scene import Scene, scene_from_dict`).
"""

from __future__ import annotations

from dataclasses import Field, dataclass, field, fields, replace
from typing import Any, Literal

from sphrender.core.protocol import ImageFormat
from sphrender.server.scene.fields import (
    MAX_IMAGE_PIXELS,
    MAX_IMAGE_SIDE,
    MAX_LENGTH,
    MAX_STRING_LENGTH,
    MIN_LENGTH,
    SceneNote,
    Vec3,
    spec,
)
from sphrender.server.scene.schema_finish import FinishConfig
from sphrender.server.scene.schema_lights import MAX_LIGHTS, LightConfig, LightType
from sphrender.server.scene.schema_post import GlareConfig
from sphrender.server.scene.schema_quality import FilterName, QualityConfig, SphConfig
from sphrender.server.scene.schema_solids import SolidsConfig

__all__ = [
    "MAX_IMAGE_PIXELS",
    "MAX_IMAGE_SIDE",
    "MAX_LIGHTS",
    "MAX_STRING_LENGTH",
    "FilterName",
    "FinishConfig",
    "GlareConfig",
    "LightConfig",
    "LightType",
    "QualityConfig",
    "SceneNote",
    "SolidsConfig",
    "SphConfig",
    "Vec3",
    "spec",
]


@dataclass(frozen=True)
class ImageConfig:
    """The rendered image's size."""

    width: int = spec(640, "image width in pixels", low=1, high=MAX_IMAGE_SIDE, unit="px")
    height: int = spec(360, "image height in pixels", low=1, high=MAX_IMAGE_SIDE, unit="px")


@dataclass(frozen=True)
class CameraConfig:
    """A perspective pinhole camera looking from eye at target."""

    eye: Vec3 = spec(
        (0.0, 1.0, 3.0), "camera position, scene units (float64 precision)", unit="scene units"
    )
    target: Vec3 = spec((0.0, 0.0, 0.0), "point the camera looks at", unit="scene units")
    up: Vec3 = spec((0.0, 1.0, 0.0), "up direction; must not be parallel to target - eye")
    fov_y: float = spec(
        45.0,
        "vertical field of view in degrees",
        low=0.0,
        high=180.0,
        low_open=True,
        high_open=True,
        unit="degrees",
    )
    near: float = spec(
        0.01,
        "near clipping distance along the view axis",
        low=0.0,
        low_open=True,
        unit="scene units",
    )
    far: float | None = spec(
        None,
        "far clipping distance; absent = just beyond the farthest particle",
        low=0.0,
        low_open=True,
        unit="scene units",
    )
    shutter: float = spec(
        0.0,
        "exposure time: particles of a frame with velocities blur over [-shutter/2, +shutter/2] "
        "around the frame's time; 0 = a still. No preset sets it; for streaks of fast spatter",
        low=0.0,
        high=1.0,
        unit="seconds",
    )


@dataclass(frozen=True)
class ParticlesConfig:
    """Defaults for the particles of a frame."""

    radius: float = spec(
        0.015,
        "particle radius in scene units, used when a frame has no radii",
        low=MIN_LENGTH,
        high=MAX_LENGTH,
        unit="scene units",
    )


MaterialPreset = Literal[
    "iron",
    "stainless_steel",
    "silver",
    "gold",
    "copper",
    "aluminium",
    "titanium",
    "chromium",
    "nickel",
    "zinc",
]


@dataclass(frozen=True)
class MaterialConfig:
    """The surface material. A preset supplies measured F0 (linear sRGB, see
    `sphrender.server.engine.lighting.materials`), metallic = 1 and a default roughness; explicit
    keys override the preset's values one by one."""

    preset: MaterialPreset = spec(
        "stainless_steel",
        "metal whose measured normal-incidence reflectance F0 is used: iron, stainless_steel, "
        "silver, gold, copper, aluminium, titanium, chromium, nickel, zinc",
    )
    f0: Vec3 | None = spec(
        None,
        "override: linear RGB reflectance at normal incidence of the metal (the base colour of "
        "the metallic workflow); gold's measured red is 1.059, hence the upper limit",
        low=0.0,
        high=1.2,
    )
    roughness: float | None = spec(
        None,
        "override: perceptual roughness; GGX alpha = roughness^2, clamped below at "
        "roughness 0.045 (alpha 0.002) so fp32 D stays finite",
        low=0.0,
        high=1.0,
    )
    metallic: float | None = spec(
        None,
        "override: 1 = metal (F0 = f0, no diffuse); 0 = dielectric (F0 = 0.04, diffuse albedo "
        "= f0); in between blends linearly",
        low=0.0,
        high=1.0,
    )
    emissivity: Vec3 | None = spec(
        None,
        "normal-incidence emissivity of hot metal for the glow; absent = 1 - F0 (Kirchhoff, "
        "consistent with the Fresnel term); liquid iron near 0.8 um is about 0.28",
        low=0.0,
        high=1.0,
    )
    solidus_k: float | None = spec(
        None,
        "override: temperature (K) below which a particle is solid; the preset gives its "
        "metal's (mild steel for iron, 304 for stainless). No preset sets it; for an alloy",
        low=0.0,
        high=1e4,
    )
    liquidus_k: float | None = spec(
        None,
        "override: temperature (K) above which a particle is liquid; between solidus and "
        "liquidus it is mushy. No preset sets it; for an alloy",
        low=0.0,
        high=1e4,
    )
    heat_tint: bool = spec(
        False,
        "frames with temperatures: solid metal shows the oxide film (temper colours) its peak "
        "temperature left, by thin-film interference. The demo sets it; no quality preset does",
    )
    oxide_reference_k: float | None = spec(
        None,
        "override: peak temperature (K) that leaves a 50 nm oxide film (heat_tint's calibration). "
        "Presets: iron 578, stainless_steel 813, others use iron's; for another alloy",
        low=300.0,
        high=3000.0,
    )
    oxide_activation_k: float | None = spec(
        None,
        "override: E = Q / 2R (K) of film growth, d = 50 nm exp(E (1/oxide_reference_k - 1/T)); "
        "more: colours crowd closer in temperature. Presets: iron 3240, stainless_steel 1500",
        low=100.0,
        high=1e5,
    )
    molten: bool = spec(
        False,
        "frames with temperatures: liquid metal (smooth, no oxide) above liquidus_k, the "
        "material's own below solidus_k, blended between. The demo sets it; no quality preset does",
    )


EnvironmentPreset = Literal["workshop", "overcast", "studio"]


@dataclass(frozen=True)
class EnvironmentConfig:
    """Image-based lighting. Give at most one of preset, uniform, file; none = the default
    preset. Radiance is scene-linear with 1.0 = `shading.emission_scale`^-1 cd/m^2 (1000 cd/m^2
    by default), so the presets and the hot-metal glow share one scale."""

    preset: EnvironmentPreset | None = spec(
        None,
        "built-in procedural environment: workshop (dim hall, bright window, ceiling lamps), "
        "overcast (CIE overcast sky over grey ground) or studio (soft boxes on dark grey); "
        "default workshop",
    )
    uniform: Vec3 | None = spec(
        None, "constant radiance from every direction (linear RGB)", low=0.0
    )
    file: str | None = spec(
        None,
        "equirectangular HDR/EXR (2:1, +y up) read with OpenImageIO, relative to one of the "
        "server's configured environment directories",
    )
    intensity: float = spec(1.0, "radiance multiplier", low=0.0, high=1e9)
    rotation_deg: float = spec(
        0.0,
        "rotation of the environment about the world +y axis, degrees",
        low=-360,
        high=360,
        unit="degrees",
    )


@dataclass(frozen=True)
class ShadingConfig:
    """How the surface is lit: BRDF terms, image-based light, emission, background."""

    g_term: Literal["smith_height_correlated", "cook_torrance"] = spec(
        "smith_height_correlated",
        "microfacet shadowing: smith_height_correlated GGX (validated against Mitsuba) or "
        "cook_torrance (Cook-Torrance / Blinn, roughness independent; thesis eq 37). No preset "
        "sets it; cook_torrance reproduces the thesis's images",
    )
    ibl_mode: Literal["prefiltered", "sampled", "none"] = spec(
        "prefiltered",
        "specular image-based light: prefiltered (mip chain + split-sum table), sampled "
        "(per-pixel GGX importance sampling, ibl_samples; thesis 4.2.2) or none (no environment "
        "light at all). Presets: fast and balanced prefiltered, best sampled",
    )
    ibl_samples: int = spec(
        64,
        "samples per pixel for ibl_mode = sampled. Presets: fast and balanced 64 (unused), "
        "best 256",
        low=1,
        high=4096,
        unit="samples per pixel",
    )
    prefilter_samples: int = spec(
        512,
        "GGX samples per texel when prefiltering an environment (once per environment). No "
        "preset sets it; raise it if a sharp environment leaves noise on rough metal",
        low=16,
        high=16384,
        unit="samples per texel",
    )
    multiple_scattering: bool = spec(
        False,
        "compensate the energy single-scattering GGX loses at high roughness (Fdez-Aguera 2019, "
        "as Filament); off matches single-scatter references. No preset sets it; turn it on "
        "when rough metal looks too dark",
    )
    combine: Literal["add", "weighted"] = spec(
        "add",
        "how direct and image-based light combine: add (physically correct) or weighted: "
        "direct_weight x direct + (1 - direct_weight) x indirect (thesis eq 55). No preset sets "
        "it; weighted reproduces the thesis's images",
    )
    direct_weight: float = spec(
        0.5,
        "combine = weighted: the direct light's weight (thesis eq 55's k). No preset sets it; "
        "set it with combine = weighted",
        low=0.0,
        high=1.0,
    )
    background: Literal["transparent", "environment"] = spec(
        "transparent",
        "where no surface: transparent (alpha = coverage) or the environment (alpha 1). No "
        "preset sets it; environment for a finished picture, transparent for compositing",
    )
    emission_scale: float = spec(
        1e-3,
        "scene-linear value of 1 cd/m^2 of blackbody luminance (hot-metal glow); the built-in "
        "environments use the same scale. No preset sets it; change it to light scenes of "
        "another brightness",
        low=0.0,
        low_open=True,
        high=1e6,
        unit="scene-linear value per cd/m^2",
    )
    debug_view: Literal[
        "none", "direct", "diffuse_ibl", "specular_ibl", "emission", "irradiance"
    ] = spec(
        "none",
        "show one term instead of the beauty: direct light, diffuse IBL, specular IBL, "
        "emission, or the SH irradiance E(n). No preset sets it; for checking the lighting",
    )


AovName = Literal["Z", "N"]
ImageFormatName = ImageFormat  # png | exr | jpeg | raw, from the wire codec


@dataclass(frozen=True)
class OutputConfig:
    """The image the client gets back: format, layers, bit depth, tone mapping."""

    format: ImageFormatName = spec(
        "png",
        "image format: png (8/16-bit sRGB, alpha), exr (scene-linear + AOVs), jpeg (8-bit sRGB "
        "over jpeg_background, no alpha) or raw (uncompressed arrays, see raw_type)",
    )
    aovs: tuple[AovName, ...] = spec(
        ("Z", "N"),
        "extra layers: Z (eye depth) and N (world normal); for exr and raw float16/float32, "
        "ignored otherwise",
    )
    exr_pixel_type: Literal["half", "float", "auto"] = spec(
        "auto",
        "EXR colour/normal precision (Z is always float32): half, float, or auto = half unless "
        "a colour exceeds half's 65504 (molten metal does), then float",
    )
    png_bits: Literal[8, 16] = spec(8, "PNG bit depth", unit="bits per channel")
    jpeg_quality: int = spec(
        90,
        "JPEG quality (libjpeg scale, 4:2:0 chroma)",
        low=1,
        high=100,
        unit="libjpeg quality",
    )
    jpeg_background: Vec3 = spec(
        (0.0, 0.0, 0.0),
        "display sRGB colour (0..1 per channel) the JPEG is composited over by coverage (JPEG "
        "has no alpha)",
        low=0.0,
        high=1.0,
    )
    raw_type: Literal["rgba8", "float16", "float32"] = spec(
        "rgba8",
        "raw pixels: rgba8 (the PNG's 8-bit sRGB codes, straight alpha) or float16/float32 "
        "(scene-linear straight RGBA plus the aovs; Z is always float32)",
    )
    exposure: float = spec(
        0.0,
        "exposure in stops for png, jpeg and raw rgba8 (scene-linear outputs keep none)",
        low=-32,
        high=32,
        unit="stops",
    )
    tone_mapper: Literal["aces", "clamp"] = spec(
        "aces",
        "tone mapper of png, jpeg and raw rgba8: aces (Hill's fit of the ACES RRT + sRGB ODT: "
        "filmic toe and shoulder, highlights desaturate to white) or clamp (hard clip at 1); "
        "exr and raw float are never tone mapped",
    )


@dataclass(frozen=True)
class Scene:
    """A scene: what to render and how (TOML file or JSON over the wire)."""

    image: ImageConfig = field(default_factory=ImageConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    particles: ParticlesConfig = field(default_factory=ParticlesConfig)
    quality: QualityConfig = field(default_factory=QualityConfig)
    sph: SphConfig = field(default_factory=SphConfig)
    output: OutputConfig = field(default_factory=OutputConfig)
    glare: GlareConfig = field(default_factory=GlareConfig)
    material: MaterialConfig = field(default_factory=MaterialConfig)
    finish: FinishConfig = field(default_factory=FinishConfig)
    lights: tuple[LightConfig, ...] = field(default=(), metadata={"max_items": MAX_LIGHTS})
    environment: EnvironmentConfig = field(default_factory=EnvironmentConfig)
    shading: ShadingConfig = field(default_factory=ShadingConfig)
    solids: SolidsConfig = field(default_factory=SolidsConfig)
    #: What reading the scene changed (old key names, `renames.py`): reported with each frame's
    #: notes. Not a section: no file or JSON scene sets it, and it takes no part in equality.
    notes: tuple[SceneNote, ...] = field(default=(), compare=False, metadata={"section": False})

    def with_overrides(self, **sections: Any) -> Scene:
        return replace(self, **sections)


def scene_sections() -> tuple[Field[Any], ...]:
    """The fields of `Scene` that are sections of a scene file (all but `notes`)."""
    return tuple(f for f in fields(Scene) if f.metadata.get("section", True))
