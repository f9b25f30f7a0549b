"""Metal presets and the resolved material the shading pass consumes.

F0 values are linear sRGB (Rec.709 primaries) reflectance at normal incidence, from
physicallybased.info (computed there from refractiveindex.info n, k data); see
`../shared/reference/validation-data.md`. Gold's red exceeds 1 (out of gamut) and is kept as is:
the shader works in float, Schlick's F stays finite and tends to 1 at grazing angles either way.

The metallic workflow (Filament, Burley 2012): ``F0 = mix(0.04, f0, metallic)`` and the diffuse
albedo is ``f0 * (1 - metallic)``, so a pure metal has no diffuse term and a dielectric reflects
4% at normal incidence. Emission of hot metal uses the normal-incidence emissivity
``1 - F0`` unless the scene gives one (Kirchhoff's law: what is not reflected is absorbed, and
a body emits as much as it absorbs).
"""

from __future__ import annotations

from dataclasses import dataclass

from sphrender.server.engine.lighting.thin_film import OXIDE_CALIBRATION
from sphrender.server.scene import MaterialConfig, Vec3

#: Measured linear-sRGB F0 per preset name (validation-data.md, "Metal F0").
METAL_F0: dict[str, Vec3] = {
    "iron": (0.530, 0.513, 0.494),
    "stainless_steel": (0.669, 0.639, 0.598),
    "silver": (0.991, 0.985, 0.974),
    "gold": (1.059, 0.773, 0.307),
    "copper": (0.932, 0.623, 0.522),
    "aluminium": (0.916, 0.923, 0.924),
    "titanium": (0.441, 0.400, 0.361),
    "chromium": (0.654, 0.685, 0.701),
    "nickel": (0.697, 0.641, 0.563),
    "zinc": (0.808, 0.844, 0.865),
}

#: Solidus and liquidus per preset, kelvin: the temperatures where melting begins and ends. Pure
#: metals melt at one temperature (both equal); iron is taken as mild steel, stainless as 304
#: (ASM Handbook vol. 2 and 1 melting ranges).
MELTING_RANGE_K: dict[str, tuple[float, float]] = {
    "iron": (1700.0, 1790.0),
    "stainless_steel": (1673.0, 1727.0),
    "silver": (1234.9, 1234.9),
    "gold": (1337.3, 1337.3),
    "copper": (1357.8, 1357.8),
    "aluminium": (933.5, 933.5),
    "titanium": (1941.0, 1941.0),
    "chromium": (2180.0, 2180.0),
    "nickel": (1728.0, 1728.0),
    "zinc": (692.7, 692.7),
}

#: Roughness a preset uses when the scene does not set one: a lightly worked metal surface.
PRESET_ROUGHNESS = 0.35

#: Smallest perceptual roughness the shader uses (Frostbite / Filament clamp): alpha = 0.045^2
#: = 0.002025 keeps D's peak 1 / (pi alpha^2) ~ 7.8e4 and alpha^4 ~ 1.7e-11 inside fp32's
#: normal range, so a mirror-like surface under a 1e5 light stays finite.
MIN_ROUGHNESS = 0.045

#: F0 of the dielectric end of the metallic workflow (4%, most non-metals).
DIELECTRIC_F0 = 0.04

#: Liquid metal (`material.molten`): the normal spectral emissivity of liquid iron and steels
#: near 0.65 um is 0.35-0.38 (Watanabe, Susa, Fukuyama & Nagata 2003, Int. J. Thermophys. 24;
#: Krishnan et al. 1991 for liquid Fe), so F0 = 1 - 0.37, taken grey. A free liquid surface is a
#: mirror at the pixel's scale; its ripples are the SPH surface's own: roughness 0.1.
LIQUID_F0: Vec3 = (0.63, 0.63, 0.63)
LIQUID_ROUGHNESS = 0.1


@dataclass(frozen=True)
class Material:
    """A material resolved from the scene: every value the shader needs."""

    f0: Vec3  # metal F0 / base colour
    roughness: float  # perceptual, as given (the shader clamps to MIN_ROUGHNESS)
    metallic: float
    emissivity: Vec3 | None  # None = 1 - F0 (per channel)
    solidus_k: float  # below: solid
    liquidus_k: float  # above: liquid; between: the mushy range
    preset: str = "iron"  # the film's optical constants (thin_film.FILM_INDEX)
    heat_tint: bool = False
    oxide_calibration: tuple[float, float] = OXIDE_CALIBRATION["iron"]  # (T_ref K, E K)
    molten: bool = False

    @property
    def specular_f0(self) -> Vec3:
        """Effective F0 after the metallic blend."""
        m = self.metallic
        r, g, b = (DIELECTRIC_F0 * (1.0 - m) + c * m for c in self.f0)
        return (r, g, b)

    @property
    def diffuse_albedo(self) -> Vec3:
        r, g, b = (c * (1.0 - self.metallic) for c in self.f0)
        return (r, g, b)

    @property
    def normal_emissivity(self) -> Vec3:
        """Emissivity at normal incidence: the scene's value or 1 - F0 (clamped to [0, 1])."""
        if self.emissivity is not None:
            return self.emissivity
        r, g, b = (min(max(1.0 - c, 0.0), 1.0) for c in self.specular_f0)
        return (r, g, b)


def resolve_material(config: MaterialConfig) -> Material:
    """The preset's values, each overridden by the explicit key when the scene gives one."""
    f0 = config.f0 if config.f0 is not None else METAL_F0[config.preset]
    roughness = config.roughness if config.roughness is not None else PRESET_ROUGHNESS
    metallic = config.metallic if config.metallic is not None else 1.0
    solidus, liquidus = MELTING_RANGE_K[config.preset]
    if config.solidus_k is not None:
        solidus = config.solidus_k
    if config.liquidus_k is not None:
        liquidus = config.liquidus_k
    reference_k, activation_k = OXIDE_CALIBRATION.get(config.preset, OXIDE_CALIBRATION["iron"])
    if config.oxide_reference_k is not None:
        reference_k = config.oxide_reference_k
    if config.oxide_activation_k is not None:
        activation_k = config.oxide_activation_k
    return Material(
        f0=f0,
        roughness=roughness,
        metallic=metallic,
        emissivity=config.emissivity,
        solidus_k=min(solidus, liquidus),
        liquidus_k=max(solidus, liquidus),
        preset=config.preset,
        heat_tint=config.heat_tint,
        oxide_calibration=(reference_k, activation_k),
        molten=config.molten,
    )
