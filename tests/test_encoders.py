"""Real PNG/EXR encoders on synthetic frames with analytic content (no mocks).

PNGs are decoded with OpenImageIO with ``oiio:UnassociatedAlpha = 1`` in the read config, so the
test sees the code values exactly as stored in the file (by default OIIO's PNG reader multiplies
RGB by alpha on read, which would hide an un-premultiply on write).
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any, Literal

import numpy as np
import numpy.typing as npt
import OpenEXR
import OpenImageIO as oiio
import pytest

from sphrender.server.engine.frame_output import RenderedFrame
from sphrender.server.output import display, encoders
from sphrender.server.output.encoders import ExrOptions, PngOptions

H, W = 24, 32
RADIUS = 9.0
SPHERE_DEPTH = 5.0  # eye-space depth of the sphere centre's silhouette plane
HALF_REL = 2.0**-11  # half: 10 stored mantissa bits, round to nearest
HALF_MIN_NORMAL_ABS = 2.0**-25  # absolute rounding bound in half's subnormal range


# ------------------------------------------------------------------------------------------
# Helpers


def f32(values: npt.ArrayLike) -> npt.NDArray[np.float32]:
    return np.asarray(values, dtype=np.float32)


def srgb_reference(linear: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """sRGB OETF in float64, straight from the IEC 61966-2-1 formula."""
    lin = np.asarray(linear, dtype=np.float64)
    return np.where(
        lin <= 0.0031308, 12.92 * lin, 1.055 * np.power(np.maximum(lin, 0.0), 1 / 2.4) - 0.055
    )


def srgb_inverse(encoded: npt.ArrayLike) -> npt.NDArray[np.float64]:
    enc = np.asarray(encoded, dtype=np.float64)
    return np.where(enc <= 0.04045, enc / 12.92, ((enc + 0.055) / 1.055) ** 2.4)


def disk_frame() -> RenderedFrame:
    """Gradients in RGB, a disk of coverage with a sphere's depth and normals.

    R ramps left→right over [0, 1.25] (the top end exercises the clamp), G ramps top→bottom over
    [-0.1, 1] (negative values clamp to 0), B sweeps the OETF's linear/power threshold.
    """
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    rgba = np.empty((H, W, 4), dtype=np.float32)
    rgba[..., 0] = x / (W - 1) * 1.25
    rgba[..., 1] = y / (H - 1) * 1.1 - 0.1
    rgba[..., 2] = 0.0031308 * (0.5 + (x + W * y) / (H * W))
    dx, dy = x + 0.5 - W / 2, y + 0.5 - H / 2
    dist = np.hypot(dx, dy)
    rgba[..., 3] = np.clip(RADIUS - dist + 0.5, 0.0, 1.0)
    inside = rgba[..., 3] > 0
    nz = np.sqrt(np.clip(1.0 - (dist / (RADIUS + 0.5)) ** 2, 0.0, 1.0))
    depth = np.where(inside, SPHERE_DEPTH - (RADIUS + 0.5) * nz, np.inf).astype(np.float32)
    normals = np.zeros((H, W, 3), dtype=np.float32)
    normals[..., 0] = np.where(inside, dx / (RADIUS + 0.5), 0.0)
    normals[..., 1] = np.where(inside, -dy / (RADIUS + 0.5), 0.0)  # world +Y is image up
    normals[..., 2] = np.where(inside, nz, 0.0)
    return RenderedFrame(rgba=rgba, depth=depth, normals=normals)


def top_red_frame() -> RenderedFrame:
    rgba = np.zeros((H, W, 4), dtype=np.float32)
    rgba[..., 3] = 1.0
    rgba[0, :, 0] = 1.0  # top row red
    rgba[-1, :, 2] = 1.0  # bottom row blue
    depth = np.full((H, W), np.inf, dtype=np.float32)
    depth[0] = 1.0
    normals = np.zeros((H, W, 3), dtype=np.float32)
    normals[0, :, 1] = 1.0
    return RenderedFrame(rgba=rgba, depth=depth, normals=normals)


def read_png(path: Path) -> tuple[np.ndarray, oiio.ImageSpec]:
    """Stored code values (H, W, C) in the file's own integer type, plus the file's spec."""
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)  # do not premultiply on read
    inp = oiio.ImageInput.open(str(path), config)
    assert inp is not None, oiio.geterror()
    try:
        spec = inp.spec()
        pixels = inp.read_image(spec.format)
        assert pixels is not None, inp.geterror()
    finally:
        inp.close()
    return np.asarray(pixels), spec


def png_bytes_to_pixels(data: bytes, tmp_path: Path) -> np.ndarray:
    path = tmp_path / "from_bytes.png"
    path.write_bytes(data)
    return read_png(path)[0]


def expected_codes(
    rgba: npt.NDArray[np.float32], bits: int, exposure: float = 0.0
) -> npt.NDArray[np.float64]:
    """Independent float64 reference: exposure, clip, OETF, scaled to code values (unrounded)."""
    max_code = 2**bits - 1
    ref = np.empty(rgba.shape, dtype=np.float64)
    ref[..., :3] = srgb_reference(np.clip(rgba[..., :3] * 2.0**exposure, 0.0, 1.0)) * max_code
    ref[..., 3] = np.clip(rgba[..., 3], 0.0, 1.0) * max_code
    return ref


def exr_channel_types(data: bytes) -> dict[str, object]:
    exr = OpenEXR.File(io.BytesIO(data), separate_channels=True)
    return {name: channel.type() for name, channel in exr.channels().items()}


def premultiplied(frame: RenderedFrame) -> npt.NDArray[np.float32]:
    """RGBA with RGB × A in float32, what the EXR encoder stores by default."""
    out = frame.rgba.copy()
    out[..., :3] *= frame.rgba[..., 3:4]
    return out


def assert_half_close(actual: np.ndarray, expected: np.ndarray) -> None:
    exp = expected.astype(np.float64)
    err = np.abs(actual.astype(np.float64) - exp)
    assert np.all(err <= HALF_REL * np.abs(exp) + HALF_MIN_NORMAL_ABS), float(err.max())


# ------------------------------------------------------------------------------------------
# Display transform


def test_srgb_oetf_matches_formula() -> None:
    lin = np.linspace(0.0, 1.0, 10001, dtype=np.float32)
    threshold = np.float32(0.0031308)
    lin = np.concatenate([lin, f32([threshold, np.nextafter(threshold, np.float32(1))])])
    got = encoders.srgb_oetf(lin)
    assert got.dtype == np.float32
    np.testing.assert_allclose(got, srgb_reference(lin), rtol=0, atol=2e-7)
    assert got[0] == 0.0
    assert abs(float(encoders.srgb_oetf(f32([1.0]))[0]) - 1.0) < 1e-7


def test_tone_map_exposure_is_a_power_of_two_scale() -> None:
    rgba = disk_frame().rgba * f32([0.5, 0.5, 0.5, 1.0])
    doubled = rgba * f32([2.0, 2.0, 2.0, 1.0])
    np.testing.assert_array_equal(
        encoders.tone_map_for_display(rgba, exposure=1.0),
        encoders.tone_map_for_display(doubled, exposure=0.0),
    )
    out = encoders.tone_map_for_display(rgba, exposure=-1.5)
    np.testing.assert_allclose(
        out[..., :3], srgb_reference(np.clip(rgba[..., :3] * 2.0**-1.5, 0, 1)), atol=1e-6
    )
    np.testing.assert_array_equal(out[..., 3], rgba[..., 3])  # alpha untouched by exposure


@pytest.mark.parametrize("tone_mapper", ["clamp", "aces"])
@pytest.mark.parametrize("exposure", [0.0, -200.0, 200.0, -5000.0, 5000.0])
def test_tone_map_never_emits_nan_or_inf(exposure: float, tone_mapper: str) -> None:
    rgba = f32(
        [[[np.nan, np.inf, -np.inf, np.nan], [3e38, -3e38, 0.5, np.inf], [0.5, 0.5, 0.5, -np.inf]]]
    )
    with np.errstate(all="raise"):  # no floating-point warnings leak out either
        out = encoders.tone_map_for_display(rgba, exposure=exposure, tone_mapper=tone_mapper)
    assert out.dtype == np.float32 and np.all(np.isfinite(out))
    assert np.all((out >= 0.0) & (out <= 1.0))
    assert out[0, 0, 0] == 0.0 and out[0, 0, 2] == 0.0 and out[0, 0, 3] == 0.0  # NaN, -inf → 0
    assert out[0, 0, 1] == pytest.approx(1.0, abs=1e-6)  # +inf → white whatever the exposure
    assert out[0, 1, 3] == 1.0 and out[0, 2, 3] == 0.0  # alpha: +inf → 1, -inf → 0
    if tone_mapper == "clamp":  # aces mixes channels: the 3e38 red whitens the pixel
        assert out[0, 1, 1] == 0.0  # huge negative → 0


def test_aces_is_filmic_monotone_and_saturates_to_white() -> None:
    """Hill's ACES fit: the documented anchor points (from its rational curve and matrices),
    monotone on grey, white only asymptotically, and very bright orange (molten metal) rolls
    off to white instead of clipping to a hue-shifted yellow."""
    grey = np.geomspace(1e-4, 1e6, 400, dtype=np.float32)
    mapped = encoders.tone_map_aces(np.repeat(grey[:, None], 3, axis=1))
    assert np.all(np.diff(mapped[:, 0]) >= 0.0)
    assert np.allclose(mapped[:, 0], mapped[:, 2], atol=2e-5)  # grey stays grey
    at = {float(g): float(m) for g, m in zip(grey, mapped[:, 0], strict=True)}
    assert at[min(at, key=lambda g: abs(g - 0.18))] == pytest.approx(0.1056, abs=2e-3)
    assert float(encoders.tone_map_aces(f32([[1.0, 1.0, 1.0]]))[0, 0]) == pytest.approx(
        0.619, abs=1e-3
    )
    assert float(encoders.tone_map_aces(f32([[10.0, 10.0, 10.0]]))[0, 0]) < 0.98
    hot = encoders.tone_map_aces(f32([[1e4, 3e3, 5e2]]))
    assert np.all(hot >= 0.999)
    assert encoders.TONE_MAPPERS["aces"] is encoders.tone_map_aces


def test_tone_map_rejects_unknown_mapper_and_bad_exposure() -> None:
    rgba = np.zeros((1, 1, 4), np.float32)
    with pytest.raises(ValueError, match="tone mapper"):
        encoders.tone_map_for_display(rgba, tone_mapper="aces-not-yet")
    with pytest.raises(ValueError, match="exposure"):
        encoders.tone_map_for_display(rgba, exposure=float("nan"))
    assert "clamp" in encoders.TONE_MAPPERS


# ------------------------------------------------------------------------------------------
# PNG


@pytest.mark.parametrize("bits", [8, 16])
def test_png_matches_srgb_reference(bits: int, tmp_path: Path) -> None:
    frame = disk_frame()
    path = tmp_path / "disk.png"
    encoders.write_png(frame, path, PngOptions(bits=8 if bits == 8 else 16))
    pixels, spec = read_png(path)
    assert (spec.width, spec.height, spec.nchannels) == (W, H, 4)
    assert pixels.dtype == (np.uint8 if bits == 8 else np.uint16)
    assert spec.getattribute("oiio:ColorSpace") in ("sRGB", "srgb_rec709_scene")
    # ±1 code value: rounding to the nearest code moves a value by at most 0.5; the other 0.5
    # covers the encoder computing the OETF in float32 against this float64 reference (a value
    # right at a rounding boundary may land on either side). OIIO does no conversion of its own:
    # the encoder hands it integer codes (rounding itself is checked exactly below).
    ref = expected_codes(frame.rgba, bits)
    max_code = 2**bits - 1
    assert np.max(np.abs(pixels.astype(np.float64) - ref)) <= 1.0
    # In fact it is the nearest code up to float32 noise (a few ulp of the OETF, ~1e-6 relative).
    assert np.max(np.abs(pixels.astype(np.float64) - ref)) <= 0.5 + 1e-6 * max_code


@pytest.mark.parametrize("bits", [8, 16])
def test_png_rounds_to_nearest_code(bits: int, tmp_path: Path) -> None:
    max_code = 2**bits - 1
    targets = np.array([10.4, 10.6, 100.45, 100.55, max_code - 0.6, max_code - 0.4, 0.45, 0.55])
    linear = srgb_inverse(targets / max_code).astype(np.float32)
    rgba = np.ones((1, targets.size, 4), np.float32)
    rgba[0, :, 0] = linear
    path = tmp_path / "round.png"
    encoders.write_png(RenderedFrame(rgba), path, PngOptions(bits=8 if bits == 8 else 16))
    codes = read_png(path)[0][0, :, 0].astype(np.int64)
    expected = [10, 11, 100, 101, max_code - 1, max_code, 0, 1]  # truncation would give 10, 10, …
    assert codes.tolist() == expected


@pytest.mark.parametrize("bits", [8, 16])
def test_png_alpha_is_straight_not_unpremultiplied(bits: int, tmp_path: Path) -> None:
    rgba = f32([[[0.5, 0.5, 0.5, 0.5], [0.25, 0.5, 0.75, 0.25], [0.2, 0.4, 0.6, 0.0]]])
    path = tmp_path / "alpha.png"
    encoders.write_png(RenderedFrame(rgba), path, PngOptions(bits=8 if bits == 8 else 16))
    stored = read_png(path)[0].astype(np.float64)
    max_code = 2**bits - 1
    # rgb 0.5 → sRGB 0.7354 (188 of 255); an un-premultiply on write would store 0.5/0.5 → 1.0.
    np.testing.assert_allclose(stored, expected_codes(rgba, bits), rtol=0, atol=1.0)
    assert stored[0, 0, 0] < 0.8 * max_code
    assert stored[0, 0, 3] == np.floor(0.5 * max_code + 0.5)  # 128 or 32768
    # Colour under zero coverage is kept (straight alpha), not zeroed.
    assert stored[0, 2, 2] == np.floor(srgb_reference(0.6) * max_code + 0.5)


def test_png_nonfinite_pixels_are_defined(tmp_path: Path) -> None:
    rgba = np.full((2, 3, 4), 0.5, np.float32)
    rgba[0, 0] = [np.nan, np.inf, -np.inf, np.nan]
    rgba[1, 2] = [np.inf, np.nan, 1e30, np.inf]
    pixels = png_bytes_to_pixels(encoders.encode_png(RenderedFrame(rgba)), tmp_path)
    assert pixels[0, 0].tolist() == [0, 255, 0, 0]
    assert pixels[1, 2].tolist() == [255, 0, 255, 255]
    assert pixels[0, 1].tolist() == [188, 188, 188, 128]  # untouched neighbour


def test_png_row_zero_is_top(tmp_path: Path) -> None:
    pixels = png_bytes_to_pixels(encoders.encode_png(top_red_frame()), tmp_path)
    assert np.all(pixels[0] == [255, 0, 0, 255])
    assert np.all(pixels[-1] == [0, 0, 255, 255])
    assert np.all(pixels[1:-1, :, :3] == 0)


@pytest.mark.parametrize("options", [PngOptions(), PngOptions(bits=16, exposure=-0.5)])
def test_encode_png_bytes_match_write_png(options: PngOptions, tmp_path: Path) -> None:
    frame = disk_frame()
    data = encoders.encode_png(frame, options)
    assert data.startswith(b"\x89PNG\r\n\x1a\n")
    path = tmp_path / "written.png"
    encoders.write_png(frame, path, options)
    np.testing.assert_array_equal(png_bytes_to_pixels(data, tmp_path), read_png(path)[0])
    assert encoders.encode(frame, "png", options) == data


def test_write_png_ignores_path_suffix(tmp_path: Path) -> None:
    path = tmp_path / "frame.bin"
    encoders.write_png(top_red_frame(), path)
    assert path.read_bytes().startswith(b"\x89PNG")


# ------------------------------------------------------------------------------------------
# EXR

ALL_CHANNELS = {"R", "G", "B", "A", "Z", "N.X", "N.Y", "N.Z"}


@pytest.mark.parametrize("pixel_type", ["half", "float"])
def test_exr_roundtrip_bytes_and_file(pixel_type: str, tmp_path: Path) -> None:
    frame = disk_frame()
    assert frame.depth is not None and frame.normals is not None
    options = ExrOptions(pixel_type="half" if pixel_type == "half" else "float")
    data = encoders.encode_exr(frame, options)
    path = tmp_path / "disk.exr"
    encoders.write_exr(frame, path, options)
    assert path.read_bytes() == data

    colour_type = OpenEXR.HALF if pixel_type == "half" else OpenEXR.FLOAT
    types = exr_channel_types(data)
    assert set(types) == ALL_CHANNELS
    assert types["Z"] == OpenEXR.FLOAT  # depth is float32 regardless of pixel_type
    for name in ALL_CHANNELS - {"Z"}:
        assert types[name] == colour_type, name

    for channels in (
        encoders.read_exr(data),
        encoders.read_exr(path),
        encoders.read_exr(str(path)),
    ):
        assert set(channels) == ALL_CHANNELS
        for array in channels.values():
            assert array.shape == (H, W)
        z = channels["Z"]
        assert z.dtype == np.float32
        np.testing.assert_array_equal(z, frame.depth)  # bit-exact, +inf outside the disk
        assert np.all(np.isposinf(z[frame.rgba[..., 3] == 0]))
        assert np.all(np.isfinite(z[frame.rgba[..., 3] > 0]))

        planes = {"R": 0, "G": 1, "B": 2, "A": 3}
        for name, index in planes.items():
            got, want = channels[name], premultiplied(frame)[..., index]
            if pixel_type == "half":
                assert got.dtype == np.float16
                assert_half_close(got, want)
            else:
                assert got.dtype == np.float32
                np.testing.assert_array_equal(got, want)  # scene-linear: no clamp, no curve
        assert np.all(channels["R"][frame.rgba[..., 3] == 0] == 0)  # associated alpha
        for index, name in enumerate(("N.X", "N.Y", "N.Z")):
            got, want = channels[name], frame.normals[..., index]
            if pixel_type == "half":
                assert_half_close(got, want)
            else:
                np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("aovs", [(), ("Z",), ("N",), ("N", "Z")])
def test_exr_writes_only_requested_aovs(aovs: tuple[str, ...]) -> None:
    channels = encoders.read_exr(encoders.encode_exr(disk_frame(), ExrOptions(aovs=aovs)))
    expected = {"R", "G", "B", "A"}
    if "Z" in aovs:
        expected.add("Z")
    if "N" in aovs:
        expected |= {"N.X", "N.Y", "N.Z"}
    assert set(channels) == expected


def test_exr_missing_aov_raises() -> None:
    bare = RenderedFrame(rgba=disk_frame().rgba)
    with pytest.raises(ValueError, match="'Z'"):
        encoders.encode_exr(bare, ExrOptions(aovs=("Z",)))
    with pytest.raises(ValueError, match="'N'"):
        encoders.encode_exr(bare, ExrOptions(aovs=("N",)))
    assert set(encoders.read_exr(encoders.encode_exr(bare, ExrOptions(aovs=())))) == set("RGBA")


def test_exr_half_clamps_above_half_max_float_keeps_it() -> None:
    rgba = f32([[[1e5, 65504.0, 70000.0, 1.0], [np.inf, np.nan, -1e6, 0.5]]])
    frame = RenderedFrame(rgba)
    half = encoders.read_exr(encoders.encode_exr(frame, ExrOptions(aovs=())))
    assert np.all(np.isfinite(half["R"])) and np.all(np.isfinite(half["B"]))
    assert half["R"].tolist() == [[65504.0, 65504.0]]
    assert half["G"].tolist() == [[65504.0, 0.0]]  # NaN → 0
    assert half["B"].tolist() == [[65504.0, -65504.0]]  # -1e6 · 0.5 clamps too
    full = encoders.read_exr(encoders.encode_exr(frame, ExrOptions("float", aovs=())))
    assert full["R"][0, 0] == np.float32(1e5)  # molten metal survives in float
    assert full["B"].tolist() == [[70000.0, -5e5]]  # premultiplied by alpha 0.5
    assert np.isfinite(full["R"][0, 1]) and full["G"][0, 1] == 0.0


@pytest.mark.parametrize("pixel_type", ["half", "float"])
def test_exr_alpha_association(pixel_type: str) -> None:
    rgba = f32([[[0.5, 0.25, 1.0, 0.5], [0.8, 0.6, 0.4, 0.0], [0.3, 0.2, 0.1, 1.0]]])
    frame = RenderedFrame(rgba)
    kind: Any = pixel_type
    assoc = encoders.read_exr(encoders.encode_exr(frame, ExrOptions(kind, aovs=())))
    straight = encoders.read_exr(
        encoders.encode_exr(frame, ExrOptions(kind, aovs=(), associated_alpha=False))
    )
    stored = np.float16 if pixel_type == "half" else np.float32
    for index, name in enumerate("RGB"):
        premult = rgba[0, :, index] * rgba[0, :, 3]
        np.testing.assert_array_equal(assoc[name][0], premult.astype(stored))
        np.testing.assert_array_equal(straight[name][0], rgba[0, :, index].astype(stored))
    np.testing.assert_array_equal(assoc["A"], straight["A"])
    np.testing.assert_array_equal(assoc["A"][0], rgba[0, :, 3].astype(stored))


def test_exr_top_row_first_also_for_other_readers(tmp_path: Path) -> None:
    frame = top_red_frame()
    data = encoders.encode_exr(frame)
    channels = encoders.read_exr(data)
    assert np.all(channels["R"][0] == 1.0) and np.all(channels["R"][1:] == 0.0)
    assert np.all(channels["Z"][0] == 1.0) and np.all(np.isposinf(channels["Z"][1:]))
    assert np.all(channels["N.Y"][0] == 1.0)
    header = OpenEXR.File(io.BytesIO(data), header_only=True).header()
    assert header["lineOrder"] == OpenEXR.INCREASING_Y
    # Cross-check with OpenImageIO: its row 0 must be the red one too.
    path = tmp_path / "top.exr"
    path.write_bytes(data)
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None
    try:
        names = list(inp.spec().channelnames)
        pixels = inp.read_image("float")
        assert pixels is not None
    finally:
        inp.close()
    red = np.asarray(pixels)[..., names.index("R")]
    assert np.all(red[0] == 1.0) and np.all(red[1:] == 0.0)


def test_exr_strided_frames_are_written_correctly() -> None:
    """A flipped GL read-back (negative strides) and a channel view must not scramble data."""
    base = disk_frame()
    assert base.depth is not None
    flipped = RenderedFrame(
        rgba=base.rgba[::-1], depth=base.depth[::-1], normals=np.asarray(base.normals)[::-1]
    )
    assert not flipped.rgba.flags["C_CONTIGUOUS"]
    options = ExrOptions("float", associated_alpha=False)
    channels = encoders.read_exr(encoders.encode_exr(flipped, options))
    np.testing.assert_array_equal(channels["R"], base.rgba[::-1, :, 0])
    np.testing.assert_array_equal(channels["A"], base.rgba[::-1, :, 3])
    np.testing.assert_array_equal(channels["Z"], base.depth[::-1])


@pytest.mark.parametrize("compression", ["none", "rle", "zips", "zip", "piz"])
def test_exr_lossless_compressions_roundtrip(compression: str) -> None:
    frame = disk_frame()
    options = ExrOptions("float", compression=compression)
    channels = encoders.read_exr(encoders.encode(frame, "exr", options))
    np.testing.assert_array_equal(channels["G"], premultiplied(frame)[..., 1])
    np.testing.assert_array_equal(channels["Z"], frame.depth)


# ------------------------------------------------------------------------------------------
# Options, dispatch, frame validation


def test_options_validate() -> None:
    bad: Any = 12  # deliberately outside the Literal types
    with pytest.raises(ValueError, match="bits"):
        PngOptions(bits=bad)
    with pytest.raises(ValueError, match="exposure"):
        PngOptions(exposure=float("inf"))
    bad = "double"
    with pytest.raises(ValueError, match="pixel_type"):
        ExrOptions(pixel_type=bad)
    with pytest.raises(ValueError, match="unknown AOV"):
        ExrOptions(aovs=("Z", "P"))
    with pytest.raises(ValueError, match="duplicates"):
        ExrOptions(aovs=("Z", "Z"))
    with pytest.raises(ValueError, match="compression"):
        ExrOptions(compression="lzma")


def test_dispatch_and_suffix() -> None:
    frame = top_red_frame()
    assert encoders.file_suffix("png") == ".png"
    assert encoders.file_suffix("exr") == ".exr"
    bad: Any = "jpg"
    with pytest.raises(ValueError):
        encoders.file_suffix(bad)
    assert encoders.encode(frame, "png").startswith(b"\x89PNG")
    assert encoders.encode(frame, "exr")[:4] == b"\x76\x2f\x31\x01"  # EXR magic
    with pytest.raises(TypeError):
        encoders.encode(frame, "png", ExrOptions())
    with pytest.raises(TypeError):
        encoders.encode(frame, "exr", PngOptions())


def test_rendered_frame_validates_shapes() -> None:
    frame = RenderedFrame(rgba=np.zeros((3, 5, 4), np.float64))
    assert frame.rgba.dtype == np.float32 and (frame.width, frame.height) == (5, 3)
    with pytest.raises(ValueError, match="rgba"):
        RenderedFrame(rgba=np.zeros((3, 5, 3), np.float32))
    with pytest.raises(ValueError, match="depth"):
        RenderedFrame(rgba=np.zeros((3, 5, 4), np.float32), depth=np.zeros((5, 3), np.float32))
    with pytest.raises(ValueError, match="normals"):
        RenderedFrame(rgba=np.zeros((3, 5, 4), np.float32), normals=np.zeros((3, 5, 4), np.float32))


@pytest.mark.parametrize("tone_mapper", ["aces", "clamp"])
@pytest.mark.parametrize("bits", [8, 16])
def test_background_shortcut_gives_the_per_pixel_result(
    tone_mapper: str, bits: Literal[8, 16]
) -> None:
    """The PNG path maps only pixels with RGB and gives the background the code of one zero
    pixel; it must equal mapping every pixel, including NaN/inf, -0.0 and alpha-only pixels."""
    rng = np.random.default_rng(7)
    rgba = np.zeros((40, 60, 4), np.float32)
    rgba[10:25, 15:40] = rng.uniform(0.0, 8.0, (15, 25, 4)).astype(np.float32)
    rgba[0, 0] = np.nan
    rgba[0, 1] = np.inf
    rgba[1, 1, :3] = -np.inf
    rgba[1, 2, :3] = -0.0
    rgba[0, 2, 3] = 0.5  # alpha without colour: a black surface pixel
    rgba[2, 2, 3] = np.nan
    rgba[2, 3, 3] = np.inf
    options = encoders.PngOptions(bits=bits, exposure=1.5, tone_mapper=tone_mapper)
    frame = RenderedFrame(rgba=rgba)
    mapper = encoders.TONE_MAPPERS[tone_mapper]
    every_pixel = display._tone_map_pixels(rgba, 1.5, mapper)
    assert np.array_equal(encoders.tone_map_for_display(rgba, 1.5, tone_mapper), every_pixel)
    assert np.array_equal(
        encoders._png_pixels(frame, options), display._quantise(every_pixel, bits)
    )
