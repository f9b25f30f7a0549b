"""Heat tint: the oxide film a peak temperature leaves on steel, as thin-film interference.

Optics (Airy summation over wavelength, baked into a small table per material). An absorbing
film of complex index ``n_film`` and thickness d on a conductor substrate; s and p amplitude
reflectances r = (r01 + r12 e^{2i delta}) / (1 + r01 r12 e^{2i delta}), delta = 2 pi n_film d
cos(theta_film) / lambda, averaged over polarisation; the spectrum R(lambda) is integrated
against the CIE 1931 2-degree observer (equal-energy light, 380-780 nm at 5 nm) into XYZ and
converted to linear Rec.709, normalised so that a perfect reflector is (1, 1, 1). The table is
RGB over (film thickness 0..FILM_MAX_NM, cos theta 0..1); the shader reads it with bilinear
filtering (`shaders/lighting/thin_film.glsl`). A spectral table rather than Belcour & Barla's
analytic RGB approximation: the table is exact to interpolation (< 1e-3 at these sizes), costs
two texture reads a light, and is built once per material in ~0.5 s of CPU; the analytic form trades
accuracy (a few 1e-2 near the first-order colours, where temper colours live) for no table.

Thickness spread. A real film is not uniform: the oxidation rate differs from grain to grain
with crystal orientation (the basis of colour (heat-tint) etching, where neighbouring grains of
one specimen show different temper colours), the oxide/metal interface roughens as the film
grows, and a pixel's footprint spans many grains. Its reflectance is the intensity average over
the thickness distribution (incoherent across grains). The rate varies multiplicatively, so ln d
is normal about the calibrated median d with sigma THICKNESS_SPREAD = 0.2 (sigma_d / d ~ 0.2).
A chosen value, not a measured one: 0.15 leaves 304's films past 150 nm at CIELAB C* 16, 0.25
pulls carbon steel's purple towards blue (hue 287 deg, uniform 316); the calibration below,
fitted without the spread, still puts every chart colour in its family at 0.2. The spread
multiplies the interference term by ~exp(-(4 pi n sigma_d cos / lambda)^2 / 2): the charts'
films (<= 72 nm) keep most of their chroma, while past ~150 nm the higher orders average out to
the incoherent sum, a low-chroma grey (C* 3.6 carbon steel, 8.0 for 304; uniform films there
reach 27 and 77). The film's k keeps that grey dark: past ~300 nm (carbon steel; 304's
k = 0.1 lets more through) the film is opaque and reflects the oxide's own
|(n - 1) / (n + 1)|^2 ~ 0.20 against the bare metal's ~0.5 (carbon steel: L* 52 against 77),
consistent with oxidised steel's emissivity ~0.8. The spread is baked into the table (a few
times the build time of the uniform table); the shader does not change.

Substrate. The renderer describes a metal by its measured RGB F0; the substrate's spectral n, k
come from it by Gulbrandsen's (2014, JCGT 3(4)) inversion with edge tint = F0 at 650, 550 and
450 nm (the red, green, blue channels), linear in between and constant outside.

Film optical constants (constant over the visible). Carbon steel's temper film is magnetite
Fe3O4 under a thin hematite Fe2O3 skin: n ~ 2.4-3.0, k ~ 0.1-0.5 over the visible (Schlegel,
Alvarado, Bianchi & Zeller 1979, Querry 1985 for Fe2O3, both via refractiveindex.info); we take
2.6 + 0.3i. Stainless steel's is Cr2O3-rich (Cr2O3: n ~ 2.5, k ~ 0.05-0.1 in the visible,
Hones et al. 1999 / Palik); we take 2.5 + 0.1i.

Calibration (peak temperature -> film thickness). Oxide grows parabolically with an Arrhenius
rate, so for one exposure time d = d_ref exp(E (1 / T_ref - 1 / T)), d_ref = OXIDE_REFERENCE_NM.
(T_ref, E) per material were fitted to the published temper colour charts: the film thickness
whose colour through this table matches each chart colour (straw, brown, purple, blue, light
blue) against its temperature (carbon steel: light straw 205 C, straw 230, brown 260, purple
280, blue 300, light blue 340; 304: light yellow 290, brown 390, magenta 450, blue 540, dark
blue 600 C). Chart colour -> thickness through this table at normal incidence (nm): carbon
steel 16, 22, 30, 37, 48, 72 (least squares in ln d over 1/T: T_ref 578 K, E 3240 K); 304 22,
33, 40, 50, 57 (fitted to magenta and blue, the narrowest windows: T_ref 813 K, E 1500 K).
Films past FILM_MAX_NM read the table's last column: the spread and absorption have damped
the interference there and the film reads as a dark grey scale. The scene may override both
(`material.oxide_reference_k`, `oxide_activation_k`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from sphrender.server.engine.lighting.blackbody import XYZ_TO_REC709
from sphrender.server.engine.lighting.cie_cmf import CIE_1931_2DEG_5NM

F64 = npt.NDArray[np.float64]
C128 = npt.NDArray[np.complex128]

#: Table size: film thickness 0..FILM_MAX_NM in FILM_SAMPLES steps, cos theta 0..1 in
#: COS_SAMPLES; 0.59 nm and 1/63 between samples keep bilinear reads within 3e-4 of the exact
#: integral (tests/test_heat_tint.py).
FILM_MAX_NM = 300.0
FILM_SAMPLES = 512
COS_SAMPLES = 64

#: Relative spread of the film thickness within a pixel: ln d is normal with this standard
#: deviation about the calibrated (median) thickness (module docstring); the average runs over
#: +-SPREAD_Z deviations (5.7e-7 of the mass outside) in SPREAD_NODES steps.
THICKNESS_SPREAD = 0.2
SPREAD_Z = 5.0
SPREAD_NODES = 51

#: Film thickness (nm) at the calibration's reference temperature.
OXIDE_REFERENCE_NM = 50.0

#: Oxide film index per preset (module docstring); presets not listed use carbon steel's.
FILM_INDEX: dict[str, complex] = {"iron": 2.6 + 0.3j, "stainless_steel": 2.5 + 0.1j}

#: (T_ref K, E K) per preset: the film is OXIDE_REFERENCE_NM thick at T_ref; E = Q / 2R.
OXIDE_CALIBRATION: dict[str, tuple[float, float]] = {
    "iron": (578.0, 3240.0),
    "stainless_steel": (813.0, 1500.0),
}

_CHANNEL_NM = (650.0, 550.0, 450.0)  # wavelengths standing for the R, G, B of F0


@dataclass(frozen=True)
class FilmSpec:
    """Everything the table depends on: the substrate's RGB F0 and the film's complex index."""

    f0: tuple[float, float, float]
    film_index: complex


def film_spec(preset: str, f0: tuple[float, float, float]) -> FilmSpec:
    return FilmSpec(tuple(float(c) for c in f0), FILM_INDEX.get(preset, FILM_INDEX["iron"]))  # type: ignore[arg-type]


def oxide_thickness_nm(peak_k: F64 | float, reference_k: float, activation_k: float) -> F64:
    """Film thickness (nm) a peak temperature leaves: the Arrhenius calibration above."""
    t = np.maximum(np.asarray(peak_k, dtype=np.float64), 1.0)
    return OXIDE_REFERENCE_NM * np.exp(activation_k * (1.0 / reference_k - 1.0 / t))


def gulbrandsen_index(reflectivity: F64) -> C128:
    """Complex index n + ik whose normal reflectance is `reflectivity`, edge tint = reflectivity
    (Gulbrandsen 2014, eq 9 and 11)."""
    r = np.clip(reflectivity, 1e-4, 0.999)
    g = r
    sr = np.sqrt(r)
    n = g * (1.0 - r) / (1.0 + r) + (1.0 - g) * (1.0 + sr) / (1.0 - sr)
    k2 = (r * (n + 1.0) ** 2 - (n - 1.0) ** 2) / (1.0 - r)
    result: C128 = n + 1j * np.sqrt(np.maximum(k2, 0.0))
    return result


def substrate_index(f0: tuple[float, float, float], wavelengths_nm: F64) -> C128:
    """The substrate's n + ik per wavelength, from the RGB F0 (module docstring)."""
    at = gulbrandsen_index(np.asarray(f0, dtype=np.float64))
    order = np.argsort(_CHANNEL_NM)
    xs = np.asarray(_CHANNEL_NM)[order]
    n = np.interp(wavelengths_nm, xs, at.real[order])
    k = np.interp(wavelengths_nm, xs, at.imag[order])
    result: C128 = n + 1j * k
    return result


def _cos_inside(index: C128 | complex, sin2: F64) -> C128:
    """cos theta inside a medium of `index` (Snell from air), the decaying branch."""
    result: C128 = np.sqrt(1.0 - sin2 / np.asarray(index) ** 2 + 0j)
    return result


def film_reflectance_spectrum(
    thickness_nm: F64, cos_theta: F64, wavelengths_nm: F64, film: complex, substrate: C128
) -> F64:
    """Unpolarised reflectance of air / film / substrate; arrays broadcast together."""
    c0 = np.asarray(cos_theta, dtype=np.float64)
    sin2 = 1.0 - c0**2
    c1 = _cos_inside(film, sin2)
    c2 = _cos_inside(substrate, sin2)
    n1, n2 = film, substrate
    delta = 2.0 * np.pi * n1 * thickness_nm * c1 / wavelengths_nm
    phase = np.exp(2j * delta)
    total = np.zeros(np.broadcast(c0, phase, c2).shape)
    for polarisation in ("s", "p"):
        if polarisation == "s":
            r01 = (c0 - n1 * c1) / (c0 + n1 * c1)
            r12 = (n1 * c1 - n2 * c2) / (n1 * c1 + n2 * c2)
        else:
            r01 = (n1 * c0 - c1) / (n1 * c0 + c1)
            r12 = (n2 * c1 - n1 * c2) / (n2 * c1 + n1 * c2)
        r = (r01 + r12 * phase) / (1.0 + r01 * r12 * phase)
        total = total + 0.5 * np.abs(r) ** 2
    return total


@functools.lru_cache(maxsize=1)
def _observer() -> tuple[F64, F64, F64]:
    """(wavelengths nm, CMF rows 380-780 nm, the per-channel white of a perfect reflector)."""
    table = np.asarray(CIE_1931_2DEG_5NM, dtype=np.float64)
    table = table[(table[:, 0] >= 380.0) & (table[:, 0] <= 780.0)]
    cmf = table[:, 1:] / table[:, 2].sum()
    white = XYZ_TO_REC709 @ cmf.sum(axis=0)
    return table[:, 0], cmf, white


def spectrum_to_rgb(spectrum: F64) -> F64:
    """Reflectance spectra (..., wavelengths) -> linear Rec.709, a perfect reflector = 1."""
    _, cmf, white = _observer()
    xyz = spectrum @ cmf
    result: F64 = (xyz @ XYZ_TO_REC709.T) / white
    return result


def film_rgb(spec: FilmSpec, thickness_nm: F64, cos_theta: F64) -> F64:
    """Linear RGB reflectance (..., 3) at these thicknesses and cosines (broadcast)."""
    wavelengths, _, _ = _observer()
    substrate = substrate_index(spec.f0, wavelengths)
    d = np.asarray(thickness_nm, dtype=np.float64)[..., None]
    c = np.asarray(cos_theta, dtype=np.float64)[..., None]
    spectrum = film_reflectance_spectrum(d, c, wavelengths, spec.film_index, substrate)
    return spectrum_to_rgb(spectrum)


def spread_rgb(spec: FilmSpec, thickness_nm: F64, cos_theta: F64) -> F64:
    """(cos, thickness, 3): film_rgb averaged over the lognormal thickness spread about each
    median thickness (module docstring): trapezoid in z = ln(d' / d) / THICKNESS_SPREAD over
    +-SPREAD_Z, the nodes read linearly from a uniform grid at the table's step."""
    z = np.linspace(-SPREAD_Z, SPREAD_Z, SPREAD_NODES)
    weights = np.exp(-0.5 * z * z)
    weights /= weights.sum()
    step = FILM_MAX_NM / (FILM_SAMPLES - 1)
    at = np.asarray(thickness_nm, dtype=np.float64)[:, None] * np.exp(THICKNESS_SPREAD * z) / step
    fine: F64 = np.arange(int(at.max()) + 2, dtype=np.float64) * step
    lower = np.minimum(at.astype(np.intp), len(fine) - 2)
    frac = (at - lower)[..., None]
    cos = np.asarray(cos_theta, dtype=np.float64)
    out = np.empty((len(cos), len(at), 3))
    for rows in np.array_split(np.arange(len(cos)), max(1, len(cos) // 8)):
        rgb = film_rgb(spec, fine[None, :], cos[rows, None])
        nodes = rgb[:, lower] * (1.0 - frac) + rgb[:, lower + 1] * frac  # (rows, d, z, 3)
        out[rows] = np.einsum("rdzc,z->rdc", nodes, weights)
    return out


@functools.lru_cache(maxsize=8)
def film_table(spec: FilmSpec) -> npt.NDArray[np.float32]:
    """(COS_SAMPLES, FILM_SAMPLES, 4) float32: RGB reflectance averaged over the thickness
    spread, texel centres at median thickness i / (FILM_SAMPLES - 1) * FILM_MAX_NM (x) and
    cos theta j / (COS_SAMPLES - 1) (y)."""
    d = np.linspace(0.0, FILM_MAX_NM, FILM_SAMPLES)
    c = np.linspace(0.0, 1.0, COS_SAMPLES)
    rgb = spread_rgb(spec, d, c)
    table = np.zeros((COS_SAMPLES, FILM_SAMPLES, 4), np.float32)
    table[..., :3] = rgb
    table[..., 3] = 1.0
    table.setflags(write=False)
    return table
