"""Blackbody radiance as linear Rec.709 RGB, for the glow of hot metal.

Planck's law integrated against the CIE 1931 2-degree observer (5 nm table in `cie_cmf`) gives
XYZ; luminance is 683 lm/W times the y-bar integral (cd/m^2 at emissivity 1), and the colour is
XYZ -> linear Rec.709 normalised to luminance 1. Both reproduce validation-data.md's table
(tested).

Gamut: below about 1900 K the colour lies outside Rec.709 (negative blue, -0.09 at 1000 K). The
negative channel is clipped to 0 and the colour rescaled to luminance 1 again. Of the simple
choices this moves the colour least: at 1000 K red changes by 0.7%, whereas desaturating towards
white until blue reaches 0 would change red by 6.5% and triple green. Absolute values reach
5.6e6 cd/m^2 at 2500 K, far above half float's 65504: the shader works in fp32, and EXR output
(exr_pixel_type = "auto") switches to float when values exceed half range.
"""

from __future__ import annotations

import functools

import numpy as np
import numpy.typing as npt

from sphrender.server.engine.lighting.cie_cmf import CIE_1931_2DEG_5NM

F64 = npt.NDArray[np.float64]

PLANCK = 6.62607015e-34  # J s
LIGHT_SPEED = 2.99792458e8  # m / s
BOLTZMANN = 1.380649e-23  # J / K
LUMINOUS_EFFICACY = 683.0  # lm / W at 555 nm

#: XYZ -> linear Rec.709 (sRGB primaries, D65 white).
XYZ_TO_REC709 = np.array(
    [
        [3.2404542, -1.5371385, -0.4985314],
        [-0.9692660, 1.8760108, 0.0415560],
        [0.0556434, -0.2040259, 1.0572252],
    ]
)
#: Luminance of linear Rec.709 RGB: the Y row of the inverse matrix (0.2126729, 0.7151522,
#: 0.0721750), so that a colour computed as XYZ / Y has luminance exactly 1.
REC709_LUMINANCE = np.linalg.inv(XYZ_TO_REC709)[1]

#: Temperature range of the shader's table: below 500 K nothing visible is emitted (luminance
#: ~1e-13 cd/m^2); above 12000 K the table clamps (welding arcs are not rendered as particles).
TABLE_MIN_K = 500.0
TABLE_MAX_K = 12000.0
TABLE_SIZE = 4096


def planck_spectral_radiance(wavelength_m: F64, kelvin: float) -> F64:
    """B_lambda(T) in W / (m^2 sr m)."""
    with np.errstate(over="ignore"):
        exponent = PLANCK * LIGHT_SPEED / (wavelength_m * BOLTZMANN * kelvin)
        result: F64 = (2.0 * PLANCK * LIGHT_SPEED**2 / wavelength_m**5) / np.expm1(exponent)
    return result


@functools.lru_cache(maxsize=1)
def _cmf_table() -> F64:
    """CIE_1931_2DEG_5NM as an array (converting the literal costs more than a table row)."""
    table = np.asarray(CIE_1931_2DEG_5NM, dtype=np.float64)
    table.setflags(write=False)
    return table


def blackbody_xyz(kelvin: float) -> F64:
    """CIE XYZ of a blackbody, scaled so Y is the luminance in cd/m^2 (emissivity 1)."""
    table = _cmf_table()
    wavelength = table[:, 0] * 1e-9
    radiance = planck_spectral_radiance(wavelength, kelvin)
    step = 5e-9
    result: F64 = LUMINOUS_EFFICACY * (radiance[:, None] * table[:, 1:]).sum(axis=0) * step
    return result


def to_gamut(rgb: F64) -> F64:
    """Clip negative channels of a luminance-1 colour and rescale it to luminance 1."""
    clipped = np.maximum(np.asarray(rgb, dtype=np.float64), 0.0)
    luminance = clipped @ REC709_LUMINANCE
    result: F64 = (
        clipped / np.maximum(luminance, 1e-30)[..., None]
        if clipped.ndim > 1
        else (clipped / max(float(luminance), 1e-30))
    )
    return result


def blackbody_rgb(kelvin: float) -> tuple[F64, float]:
    """(linear Rec.709 colour at luminance 1, un-gamut-mapped; luminance in cd/m^2)."""
    xyz = blackbody_xyz(kelvin)
    luminance = float(xyz[1])
    if luminance <= 0.0:
        return np.zeros(3), 0.0
    return XYZ_TO_REC709 @ (xyz / luminance), luminance


@functools.lru_cache(maxsize=1)
def blackbody_table() -> npt.NDArray[np.float32]:
    """(TABLE_SIZE, 4) float32 over TABLE_MIN_K..TABLE_MAX_K: in-gamut rgb at luminance 1 and
    log2(luminance in cd/m^2). Interpolating log-luminance linearly keeps the steep rise of
    B(T) (x 1e4 between 1000 and 1500 K) accurate between entries."""
    temps = np.linspace(TABLE_MIN_K, TABLE_MAX_K, TABLE_SIZE)
    table = np.zeros((TABLE_SIZE, 4), dtype=np.float64)
    for i, kelvin in enumerate(temps):
        rgb, luminance = blackbody_rgb(float(kelvin))
        table[i, :3] = to_gamut(rgb)
        table[i, 3] = np.log2(max(luminance, 1e-30))
    result = table.astype(np.float32)
    result.setflags(write=False)
    return result
