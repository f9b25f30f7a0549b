"""The live-frontend encodings (JPEG, raw) and the 8-bit display table, on a real render.

JPEG is decoded with OpenImageIO (its own libjpeg, not the encoder's binding) and compared with
the PNG of the same frame composited over the same background: the PNG is the lossless truth of
what the JPEG should show. PSNR floors per quality were measured on this frame (160x120, 2000
particles, transparent background over (0.2, 0.4, 0.6); 4:2:0): q 50 -> 25.5 dB, 75 -> 28.1,
90 -> 31.6, 95 -> 33.4. Each floor is the measurement minus 1.5 dB: libjpeg-turbo is
deterministic for one version, the margin covers other versions of it and small changes of the
rendered frame (the engine evolves); a real defect (wrong background, channels swapped, alpha
ignored, a tone-map mismatch) costs far more than 1.5 dB, as the control case checks.

raw carries the arrays themselves, so it is compared bit for bit: rgba8 with the PNG's codes,
float16/float32 with the RenderedFrame (float16: numpy's IEEE round to nearest even).
"""

from __future__ import annotations

import itertools
import os
import tempfile
from typing import Any

import numpy as np
import numpy.typing as npt
import OpenImageIO as oiio
import pytest

from sphrender.client.api import decode_raw
from sphrender.core.errors import InputError
from sphrender.core.frame import make_frame
from sphrender.server.engine.frame_output import RenderedFrame
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.output import display, encoders, frame_formats
from sphrender.server.output.local import encode_for_scene, raw_layout, render_for_output
from sphrender.server.scene import scene_from_dict

SCENE: dict[str, Any] = {
    "image": {"width": 160, "height": 120},
    "camera": {"eye": [0.6, 0.5, 0.9], "target": [0.0, 0.0, 0.0], "fov_y": 40.0},
    "particles": {"radius": 0.02},
}
BACKGROUND = (0.2, 0.4, 0.6)
PSNR_FLOOR_DB = {50: 24.0, 75: 26.5, 90: 30.0, 95: 31.8}


def decode(data: bytes, suffix: str) -> npt.NDArray[np.float64]:
    """8-bit pixels as stored (straight alpha: OpenImageIO must not premultiply on read)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "image" + suffix)
        with open(path, "wb") as handle:
            handle.write(data)
        config = oiio.ImageSpec()
        config.attribute("oiio:UnassociatedAlpha", 1)
        buf = oiio.ImageBuf(path, 0, 0, config)
        pixels = buf.get_pixels(oiio.UINT8)
        assert pixels is not None, buf.geterror()
        return np.asarray(pixels, dtype=np.float64)


def psnr(a: npt.NDArray[np.float64], b: npt.NDArray[np.float64]) -> float:
    return float(10 * np.log10(255.0**2 / np.mean((a - b) ** 2)))


@pytest.fixture(scope="module")
def frame(renderer: SurfaceRenderer) -> RenderedFrame:
    positions = np.random.default_rng(0).normal(size=(2000, 3)) * 0.15
    scene = scene_from_dict(SCENE)
    rendered, _ = renderer.render(make_frame(positions), scene, depth=True, normals=True)
    alpha = rendered.rgba[..., 3]
    assert 0.1 < float(np.mean(alpha > 0)) < 0.9  # a surface and a background, with edges
    assert np.any((alpha > 0) & (alpha < 1))
    return rendered


def over(png: npt.NDArray[np.float64], background: tuple[float, ...]) -> npt.NDArray[np.float64]:
    alpha = png[..., 3:4] / 255.0
    return png[..., :3] * alpha + np.asarray(background) * 255.0 * (1.0 - alpha)


def test_jpeg_matches_the_png_over_its_background(frame: RenderedFrame) -> None:
    png = decode(encoders.encode_png(frame, encoders.PngOptions(tone_mapper="aces")), ".png")
    truth = over(png, BACKGROUND)
    measured = {}
    for quality, floor in PSNR_FLOOR_DB.items():
        options = encoders.JpegOptions(quality=quality, background=BACKGROUND, tone_mapper="aces")
        data = encoders.encode_jpeg(frame, options)
        assert data[:3] == b"\xff\xd8\xff" and data[-2:] == b"\xff\xd9"
        jpeg = decode(data, ".jpg")
        assert jpeg.shape == (120, 160, 3)
        measured[quality] = psnr(jpeg, truth)
        assert measured[quality] >= floor, (quality, measured[quality])
    qualities = sorted(measured)
    assert all(measured[a] < measured[b] for a, b in itertools.pairwise(qualities))
    # Control: the same JPEG judged against the wrong background or with alpha ignored misses
    # the lowest floor by far, so these floors do catch such defects.
    jpeg90 = decode(
        encoders.encode_jpeg(
            frame, encoders.JpegOptions(quality=90, background=BACKGROUND, tone_mapper="aces")
        ),
        ".jpg",
    )
    assert psnr(jpeg90, over(png, (0.0, 0.0, 0.0))) < PSNR_FLOOR_DB[50] - 5
    assert psnr(jpeg90, png[..., :3]) < PSNR_FLOOR_DB[50] - 5


def test_jpeg_composite_before_compression(frame: RenderedFrame) -> None:
    """Before compression: uncovered pixels are the background's code exactly, fully covered
    ones the PNG's."""
    codes = display.display_codes(frame.rgba, 8, 0.0, "aces")
    rgb = frame_formats.composite_codes(codes.astype(np.uint8), (1.0, 0.5, 0.0))
    empty = codes[..., 3] == 0
    assert np.all(rgb[empty] == [255, 128, 0])
    full = codes[..., 3] == 255
    assert np.array_equal(rgb[full], codes[..., :3][full])


def test_raw_rgba8_is_the_png_codes(frame: RenderedFrame) -> None:
    png = decode(encoders.encode_png(frame, encoders.PngOptions(tone_mapper="aces")), ".png")
    options = encoders.RawOptions(type="rgba8", tone_mapper="aces")
    data = encoders.encode_raw(frame, options)
    arrays = decode_raw(encoders.raw_arrays(options, 160, 120), data)
    assert list(arrays) == ["rgba"]
    assert arrays["rgba"].dtype == np.uint8 and arrays["rgba"].shape == (120, 160, 4)
    assert np.array_equal(arrays["rgba"], png.astype(np.uint8))


@pytest.mark.parametrize("kind", ["float32", "float16"])
@pytest.mark.parametrize("aovs", [("Z", "N"), ("N",), ()])
def test_raw_float_is_the_rendered_arrays(
    frame: RenderedFrame, kind: str, aovs: tuple[str, ...]
) -> None:
    options = encoders.RawOptions(type=kind, aovs=aovs)
    data = encoders.encode_raw(frame, options)
    layout = encoders.raw_arrays(options, 160, 120)
    assert [a["name"] for a in layout] == ["rgba", *[a for a in ("Z", "N") if a in aovs]]
    arrays = decode_raw(layout, data)
    pixel = np.float32 if kind == "float32" else np.float16
    assert arrays["rgba"].tobytes() == frame.rgba.astype(pixel).tobytes()
    if "Z" in aovs:
        assert frame.depth is not None
        assert arrays["Z"].dtype == np.float32  # depth stays float32 in float16 mode too
        assert arrays["Z"].tobytes() == frame.depth.tobytes()
        assert np.isposinf(arrays["Z"][frame.rgba[..., 3] == 0]).all()
    if "N" in aovs:
        assert frame.normals is not None
        assert arrays["N"].tobytes() == frame.normals.astype(pixel).tobytes()
    # the payload is exactly the arrays, little-endian, nothing else
    assert len(data) == sum(int(np.prod(a["shape"])) * int(a["dtype"][-1]) for a in layout)


def test_oetf_table_equals_the_float_path() -> None:
    """Every threshold of the 8-bit table, +-64 float32 steps around it, and random values."""
    table = display._OETF8
    thresholds = table.threshold[:-1].astype(np.int64)
    near = (thresholds[:, None] + np.arange(-64, 65)[None, :]).ravel()
    near = near[(near >= 0) & (near <= table.ONE)].astype(np.uint32).view(np.float32)
    rng = np.random.default_rng(3)
    values = np.concatenate(
        [
            near,
            rng.uniform(0.0, 1.0, 500_000).astype(np.float32),
            (rng.uniform(0.0, 1.0, 100_000) ** 8).astype(np.float32),  # the linear toe
            np.array([0.0, -0.0, 1.0, 0.0031308, 1e-30], np.float32),
        ]
    )
    reference = display._quantise(display.srgb_oetf(values), 8)
    assert np.array_equal(table.codes(values), reference)


@pytest.mark.parametrize("tone_mapper", ["aces", "clamp"])
def test_display_codes_equal_the_reference_transform(tone_mapper: str) -> None:
    rng = np.random.default_rng(5)
    rgba = np.zeros((30, 50, 4), np.float32)
    rgba[5:25, 10:40] = rng.uniform(0.0, 30.0, (20, 30, 4)).astype(np.float32)
    rgba[0, 0] = np.nan
    rgba[0, 1, :3] = np.inf
    rgba[0, 2, 3] = 0.25
    every = display._tone_map_pixels(rgba, 0.7, display.TONE_MAPPERS[tone_mapper])
    for bits in (8, 16):
        got = display.display_codes(rgba, bits, 0.7, tone_mapper)
        assert np.array_equal(got, display._quantise(every, bits))


def test_scene_selects_the_encoding(renderer: SurfaceRenderer) -> None:
    positions = np.random.default_rng(1).normal(size=(500, 3)) * 0.15
    for fmt, magic in (
        ("jpeg", b"\xff\xd8\xff"),
        ("png", b"\x89PNG"),
        ("exr", b"\x76\x2f\x31\x01"),
    ):
        scene = scene_from_dict({**SCENE, "output": {"format": fmt}})
        rendered, _ = render_for_output(renderer, make_frame(positions), scene, scene.output.format)
        assert encode_for_scene(rendered, scene, scene.output.format)[:4].startswith(magic)
    scene = scene_from_dict({**SCENE, "output": {"format": "raw", "raw_type": "float16"}})
    rendered, _ = render_for_output(renderer, make_frame(positions), scene, "raw")
    assert rendered.depth is not None and rendered.normals is not None  # AOVs read back
    layout = raw_layout(scene, "raw")
    assert layout is not None
    arrays = decode_raw(layout, encode_for_scene(rendered, scene, "raw"))
    assert arrays["N"].dtype == np.float16 and arrays["Z"].shape == (120, 160)


@pytest.mark.parametrize(
    ("output", "field", "words"),
    [
        ({"format": "gif"}, "output.format", '"png", "exr", "jpeg", "raw", got "gif"'),
        ({"jpeg_quality": 0}, "output.jpeg_quality", "[1, 100], got 0"),
        ({"jpeg_background": [0, 2, 0]}, "output.jpeg_background[1]", "[0, 1], got 2"),
        ({"raw_type": "f32"}, "output.raw_type", '"rgba8", "float16", "float32", got "f32"'),
    ],
)
def test_bad_output_settings_name_the_field_and_the_allowed_values(
    output: dict[str, Any], field: str, words: str
) -> None:
    with pytest.raises(InputError) as caught:
        scene_from_dict({"output": output})
    assert caught.value.field == field
    assert words in caught.value.message


def test_encode_rejects_unknown_formats(frame: RenderedFrame) -> None:
    with pytest.raises(ValueError, match="known: png, exr, jpeg, raw"):
        encoders.encode(frame, "gif")  # type: ignore[arg-type]
    assert encoders.file_suffix("jpeg") == ".jpg" and encoders.file_suffix("raw") == ".raw"
