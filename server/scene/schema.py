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

from dataclasses import MISSING, dataclass, field, replace
from typing import Any, Literal

#: Largest image side accepted by the configuration; the GL context may lower it further.
MAX_IMAGE_SIDE = 16384
#: Largest image area accepted (pixels).
MAX_IMAGE_PIXELS = 8192 * 8192
#: Longest string value (characters); strings must not contain NUL either.
MAX_STRING_LENGTH = 4096

Vec3 = tuple[float, float, float]


def spec(
    default: Any = MISSING,
    doc: str = "",
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
    unit: str | None = None,
) -> Any:
    """A dataclass field with its documentation, numeric range (closed unless *_open; for a
    vector, the range of each component) and unit. The validator (`validate.py`) and the JSON
    Schema (`json_schema.py`) both read this metadata, so a field's rules are written once."""
    meta = {
        "doc": doc,
        "low": low,
        "high": high,
        "low_open": low_open,
        "high_open": high_open,
        "unit": unit,
    }
    if isinstance(default, list | tuple) or default is MISSING:
        if default is MISSING:
            return field(metadata=meta)
        return field(default=tuple(default), metadata=meta)
    return field(default=default, metadata=meta)


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


@dataclass(frozen=True)
class ParticlesConfig:
    """Defaults for the particles of a frame."""

    radius: float = spec(
        0.015,
        "particle radius in scene units, used when a frame has no radii",
        low=0.0,
        low_open=True,
        unit="scene units",
    )


FilterName = Literal["narrow_range", "bilateral", "gaussian", "none"]


@dataclass(frozen=True)
class QualityConfig:
    """Depth smoothing, anti-aliasing and the speed/error trade-offs of the surface."""

    filter: FilterName = spec(
        "narrow_range",
        "depth smoothing filter: narrow_range (Truong & Yuksel 2018), bilateral (eq 22-24), "
        "gaussian (eq 17-21) or none",
    )
    separable: bool = spec(True, "filter rows then columns (1-D kernels) instead of one 2-D kernel")
    iterations: int = spec(2, "how many times the whole filter is applied", low=1, high=16)
    kernel_size: Literal["projected_radius", "eq25"] = spec(
        "projected_radius",
        "how the kernel follows depth: projected_radius (sigma = kernel_scale * r_px(z)) or "
        "eq25 (the thesis's linear decline: eq25_sigma_px up to eq25_threshold, then minus "
        "eq25_decline px per unit)",
    )
    kernel_scale: float = spec(
        2.0,
        "Gaussian sigma in projected particle radii (sigma_px = kernel_scale * r_px(z)); the "
        "kernel reaches 3 sigma",
        low=0.0,
        high=16.0,
        low_open=True,
        unit="projected particle radii",
    )
    kernel_max_px: int = spec(
        32,
        "cap on the kernel radius in pixels (sigma shrinks to keep 3 sigma inside)",
        low=1,
        high=128,
        unit="px",
    )
    kernel_min_px: int = spec(
        1, "smallest kernel radius in pixels (eq 25's ks_min)", low=0, high=64, unit="px"
    )
    eq25_sigma_px: float = spec(
        6.0,
        "eq 25: sigma in pixels up to the threshold distance",
        low=0.0,
        low_open=True,
        unit="px",
    )
    eq25_threshold: float = spec(
        1.0,
        "eq 25: eye depth (scene units) beyond which the kernel shrinks",
        low=0.0,
        unit="scene units",
    )
    eq25_decline: float = spec(
        2.0,
        "eq 25: k, kernel radius lost per scene unit beyond the threshold (px)",
        low=0.0,
        unit="px per scene unit",
    )
    bilateral_depth_sigma: float = spec(
        6.0,
        "bilateral range sigma in particle radii (eq 24); smaller keeps the per-particle bumps",
        low=0.0,
        low_open=True,
        unit="particle radii",
    )
    narrow_range_threshold: float = spec(
        10.0,
        "narrow-range lambda: samples farther than lambda*r from the centre are dropped",
        low=0.0,
        low_open=True,
        unit="particle radii",
    )
    narrow_range_clamp: float = spec(
        1.0,
        "narrow-range mu: nearer samples are clamped to z - mu*r",
        low=0.0,
        low_open=True,
        unit="particle radii",
    )
    keep_features: Literal["none", "truncate", "blend", "both"] = spec(
        "none",
        "keep features smaller than the kernel (droplets, thin edges; separable narrow_range "
        "only): truncate (the kernel ends at the first sample pair it rejects, so it never "
        "reaches across a discontinuity), blend (the result moves back towards the unfiltered "
        "depth by the weight share of rejected samples, as NVIDIA FleX does), both, or none. "
        "Experimental: on the reference scenes neither beat none (exact_droplets is what keeps "
        "droplets round)",
    )
    antialias: bool = spec(
        True,
        "silhouette anti-aliasing: alpha is each edge pixel's sub-pixel coverage (analytic, from "
        "the ray's angular distance to the sphere's silhouette) and the pixels just outside a "
        "silhouette show the surface next to them; off: alpha is 1 where a pixel centre hits",
    )
    exact_droplets: bool = spec(
        True,
        "droplets (particles whose kernel density is below droplet_density * sph.rest_density: "
        "isolated particles and pairs) are not smoothed: they are splatted "
        "as exact spheres over the smoothed surface, so a kernel wider than a droplet neither "
        "flattens it nor blends it into the pool behind. Uses the frame's densities (the "
        "client's, or those an [sph] feature computed); frames without them are split only "
        "with droplet_density_pass",
    )
    droplet_density_pass: bool = spec(
        False,
        "exact_droplets on frames that carry no densities: compute them with an SPH density "
        "pass (OpenCL; measured ~100 ms at 100k particles on a 2-core CPU); off: such frames "
        "render without the droplet split",
    )
    droplet_density: float = spec(
        0.45,
        "exact_droplets: the density, as a fraction of sph.rest_density, below which a "
        "particle is a droplet (cubic spline, support 4 r, measured: a lone particle 0.32, a "
        "pair 0.40, the inside of a one-particle filament 0.48, the outer particles of a "
        "jittered lattice ball >= 0.47, a slab's corner 0.61, edge 0.72, face 0.85)",
        low=0.0,
        high=1.0,
        unit="fraction of sph.rest_density",
    )
    occlusion_culling: bool = spec(
        True,
        "splat the front layer first and skip particles hidden behind it (exact: the depth "
        "image is unchanged; off only to measure it)",
    )


@dataclass(frozen=True)
class SphConfig:
    """SPH quantities computed on OpenCL (thesis section 3.3.4). The pass runs only when a
    feature below asks for it; kernel, support and mass are pinned so results compare with
    other SPH tools (cubic spline, support 4 r, m = rest_density (2 r)^3, as splashsurf)."""

    rest_density: float = spec(
        1000.0,
        "rest density rho_0 (kg/m^3 in SI scenes)",
        low=0.0,
        low_open=True,
        unit="mass per scene unit^3",
    )
    support_radius: float | None = spec(
        None,
        "kernel support h (W = 0 beyond); absent = 4 * particles.radius",
        low=0.0,
        low_open=True,
        unit="scene units",
    )
    mass: float | None = spec(
        None,
        "particle mass m; absent = rest_density * (2 * particles.radius)^3",
        low=0.0,
        low_open=True,
        unit="mass units",
    )
    surface_threshold: float = spec(
        0.5,
        "eq 28 (corrected): a particle is on the surface where |n| > t, with t = "
        "surface_threshold / support_radius (|n| h is about 1 on a flat surface, 0 inside)",
        low=0.0,
        low_open=True,
        unit="1 / support_radius",
    )
    adaptive_radius: bool = spec(
        False,
        "eq 29: particles less dense than the surface average shrink toward min_radius "
        "(thins splashes and droplets)",
    )
    min_radius: float = spec(
        0.5,
        "eq 29 r_min as a fraction of the particle's radius",
        low=0.0,
        high=1.0,
        low_open=True,
        unit="fraction of the particle radius",
    )
    radius_decline: float = spec(
        0.25,
        "eq 29 k, dimensionless: r = r_body (1 - ((d_surface - d) / d_surface)^2 / "
        "radius_decline), i.e. the thesis's k = radius_decline * d_surface^2 / r_body",
        low=0.0,
        low_open=True,
    )
    surface_only: bool = spec(
        False,
        "splat only surface particles, sparse ones and a safety layer; hidden interior "
        "particles are skipped",
    )
    safety_layer: float = spec(
        0.9,
        "surface_only: also splat particles within safety_layer * support_radius of a "
        "surface or sparse particle (0.9 reaches all 26 lattice neighbours at spacing 2 r = "
        "h / 2, at sqrt(3) h / 2; less opens holes between the outer particles)",
        low=0.0,
        high=1.0,
        unit="support radii",
    )
    sparse_density: float = spec(
        0.75,
        "surface_only: a particle whose kernel density (eq 2 from positions) is below "
        "sparse_density * rest_density is sparse (droplet, thin sheet) and always splatted",
        low=0.0,
        high=1.0,
        unit="fraction of sph.rest_density",
    )
    anisotropy: bool = spec(
        False,
        "anisotropic particles (Yu & Turk 2013): each particle becomes an ellipsoid of its "
        "sphere's volume, stretched along its neighbourhood's principal axes (flat on flat "
        "surfaces, long along filaments), at a smoothed centre; particles with few neighbours "
        "stay spheres of their radius at their position",
    )
    anisotropy_radius: float = spec(
        1.5,
        "anisotropy: neighbourhood radius R as a multiple of support_radius (weights 1 - "
        "(d/R)^3); 1.5 = 6 r gives ~107 neighbours inside a jittered lattice of spacing 2 r "
        "and ~63 on its surface (1.0 gives ~29 and ~19: at or below min_neighbours)",
        low=0.25,
        high=4.0,
        unit="support radii",
    )
    anisotropy_max_ratio: float = spec(
        4.0,
        "anisotropy: k_r, largest ratio of the longest to the shortest axis (the covariance's "
        "eigenvalues are clamped to >= largest / k_r; axes follow the eigenvalues, as Yu & Turk)",
        low=1.0,
        high=32.0,
    )
    anisotropy_min_neighbours: int = spec(
        25,
        "anisotropy: N_eps, particles with fewer neighbours within R stay exact spheres "
        "(droplets do not shrink or move); above it anisotropy and smoothing ramp in over "
        "N_eps / 2 more neighbours, so shapes change continuously between frames",
        low=1,
        high=10000,
        unit="particles",
    )
    anisotropy_smoothing: float = spec(
        0.5,
        "anisotropy: lambda, centres move to (1 - lambda) x + lambda (weighted neighbourhood "
        "mean), ramped like the shape; Yu & Turk use 0.9-1, which also pulls the surface "
        "inwards by lambda * ~0.25 R (up to 0.4 R)",
        low=0.0,
        high=1.0,
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


LightType = Literal["directional", "point"]

#: Most lights a scene may have (uniform arrays in the shading shader are sized for it).
MAX_LIGHTS = 8


@dataclass(frozen=True)
class LightConfig:
    """One direct light ([[lights]] array of tables). A scene without lights has none."""

    type: LightType = spec(
        "directional", "directional (parallel rays, like the sun) or point (inverse square)"
    )
    color: Vec3 = spec((1.0, 1.0, 1.0), "linear RGB tint multiplied with intensity", low=0.0)
    intensity: float = spec(
        1.0,
        "directional: irradiance on a surface facing the light (scene-linear radiance x sr); "
        "point: radiant intensity (per sr), divided by distance^2",
        low=0.0,
        high=1e12,
    )
    direction: Vec3 | None = spec(
        None, "directional only: the direction the light travels (from the light to the scene)"
    )
    position: Vec3 | None = spec(
        None, "point only: world position (float64 precision)", unit="scene units"
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

    g_term: Literal["smith_height_correlated", "eq37"] = spec(
        "smith_height_correlated",
        "microfacet shadowing: Smith height-correlated GGX (validates against the furnace table "
        "and Mitsuba) or the thesis's eq 37 (Cook-Torrance / Blinn, roughness independent)",
    )
    ibl_mode: Literal["prefiltered", "sampled", "none"] = spec(
        "prefiltered",
        "specular image-based light: prefiltered mip chain + split-sum BRDF table, per-pixel "
        "GGX importance sampling with ibl_samples Hammersley points (thesis §4.2.2), or none "
        "(no environment light at all, diffuse included)",
    )
    ibl_samples: int = spec(
        64, "samples per pixel for ibl_mode = sampled", low=1, high=4096, unit="samples per pixel"
    )
    prefilter_samples: int = spec(
        512,
        "GGX samples per texel when prefiltering an environment (once per environment)",
        low=16,
        high=16384,
        unit="samples per texel",
    )
    multiple_scattering: bool = spec(
        False,
        "compensate the energy single-scattering GGX loses at high roughness: specular x "
        "(1 + F0 (1 / E_ss - 1)), E_ss from the split-sum table (Fdez-Aguera 2019, as Filament); "
        "off matches single-scatter references (Mitsuba roughconductor, validation-data.md)",
    )
    combine: Literal["add", "eq55"] = spec(
        "add",
        "add: direct + indirect (physically correct); eq55: the thesis's blend "
        "k * direct + (1 - k) * indirect",
    )
    eq55_k: float = spec(0.5, "k of eq 55 (combine = eq55)", low=0.0, high=1.0)
    background: Literal["transparent", "environment"] = spec(
        "transparent",
        "where no surface: transparent (alpha 0, alpha = coverage) or the environment (alpha 1)",
    )
    emission_scale: float = spec(
        1e-3,
        "scene-linear value of 1 cd/m^2 of blackbody luminance (hot-metal glow); the built-in "
        "environments use the same scale",
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
        "emission, or the SH irradiance E(n) itself",
    )


AovName = Literal["Z", "N"]


@dataclass(frozen=True)
class OutputConfig:
    """The image the client gets back: format, layers, bit depth, tone mapping."""

    format: Literal["png", "exr"] = spec("png", "image format")
    aovs: tuple[AovName, ...] = spec(
        ("Z", "N"), "extra EXR layers: Z (eye depth) and N (world normal); ignored for PNG"
    )
    exr_pixel_type: Literal["half", "float", "auto"] = spec(
        "auto",
        "EXR colour/normal precision (Z is always float32): half, float, or auto = half unless "
        "a colour exceeds half's 65504 (molten metal does), then float",
    )
    png_bits: Literal[8, 16] = spec(8, "PNG bit depth", unit="bits per channel")
    exposure: float = spec(
        0.0, "PNG exposure in stops (EXR stays scene-linear)", low=-32, high=32, unit="stops"
    )
    tone_mapper: Literal["aces", "clamp"] = spec(
        "aces",
        "PNG tone mapper: aces (Hill's fit of the ACES RRT + sRGB ODT: filmic toe and "
        "shoulder, highlights desaturate to white) or clamp (hard clip at 1); EXR is never "
        "tone mapped",
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
    material: MaterialConfig = field(default_factory=MaterialConfig)
    lights: tuple[LightConfig, ...] = field(default=(), metadata={"max_items": MAX_LIGHTS})
    environment: EnvironmentConfig = field(default_factory=EnvironmentConfig)
    shading: ShadingConfig = field(default_factory=ShadingConfig)

    def with_overrides(self, **sections: Any) -> Scene:
        return replace(self, **sections)
