"""The display pass (issue "Live frontends": 8-bit codes without CPU work): the GPU's codes are
the CPU display transform's (server/output/display.py), and the encoders give the same bytes
from either.

The shader repeats the CPU's float32 operations in the same order with `precise` (no fused
multiply-add), and finds each code in the CPU's own OETF thresholds, so on llvmpipe (IEEE
float32 division and multiplication) the codes are identical: the tests ask for equality. A GPU
may divide to 2.5 ulps (GLSL's allowance), which can move a value across a code threshold; there
the bound is one code on a few pixels in a thousand.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from sphrender.core.frame import make_frame
from sphrender.server.content.lattice import jittered_lattice_ball
from sphrender.server.engine.frame_output import DisplayRequest, RenderedFrame
from sphrender.server.engine.gpu.draw import FullscreenTriangle, image_bytes
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.gpu.programs import ProgramCache
from sphrender.server.engine.passes.context import PassContext
from sphrender.server.engine.passes.display import DisplayPass
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.output import encoders
from sphrender.server.output.display import OETF8_THRESHOLDS, display_codes, engine_codes
from sphrender.server.output.frame_formats import JpegOptions, composite_codes, encode_jpeg
from sphrender.server.output.local import display_request, encoder_options
from sphrender.server.scene import scene_from_dict


def assert_codes_agree(gl: GLContext, gpu: np.ndarray, cpu: np.ndarray) -> None:
    difference = np.abs(gpu.astype(np.int16) - cpu.astype(np.int16))
    if gl.is_software:
        assert difference.max() == 0, f"{np.count_nonzero(difference)} codes differ"
    else:
        assert difference.max() <= 1 and np.count_nonzero(difference) <= 1e-3 * difference.size


def scene(**shading: Any) -> Any:
    return scene_from_dict(
        {
            "image": {"width": 192, "height": 108},
            "camera": {"eye": [0.5, 0.4, 0.6]},
            "particles": {"radius": 0.01},
            "shading": shading,
        }
    )


@pytest.mark.parametrize("tone_mapper", ["clamp", "aces"])
@pytest.mark.parametrize("background", ["transparent", "environment"])
def test_rendered_frames_get_the_cpu_codes(
    renderer: SurfaceRenderer, gl_context: GLContext, tone_mapper: str, background: str
) -> None:
    """Hot and cold particles (emission up to 2500 K: values far above 1) at three exposures,
    with and without the JPEG background composite."""
    positions = jittered_lattice_ball(0.2, 0.01, seed=4)
    kelvin = np.linspace(300.0, 2500.0, len(positions)).astype(np.float32)
    frame = make_frame(positions, temperatures=kelvin)
    for exposure in (0.0, 1.5, -2.0):
        for over in (None, (0.2, 0.5, 1.0)):
            request = DisplayRequest(exposure, tone_mapper, OETF8_THRESHOLDS, over)
            out, _ = renderer.render(frame, scene(background=background), display=request)
            assert out.display is not None and out.display.codes.flags.c_contiguous
            cpu = display_codes(out.rgba, 8, exposure, tone_mapper).astype(np.uint8)
            if over is None:
                assert_codes_agree(gl_context, out.display.codes, cpu)
            else:
                assert (out.display.codes[..., 3] == 255).all()
                assert_codes_agree(
                    gl_context, out.display.codes[..., :3], composite_codes(cpu, over)
                )


def hard_image(width: int = 64, height: int = 48) -> np.ndarray:
    """NaN, +-inf, -0.0, negatives, huge values, and float32 patterns on both sides of every
    OETF threshold (undoing the clamp tone mapper: display-linear = the value itself)."""
    rng = np.random.default_rng(3)
    values = rng.uniform(-0.1, 1.2, size=(height, width, 4)).astype(np.float32)
    thresholds = OETF8_THRESHOLDS[:255].astype(np.uint32)
    near = np.concatenate([thresholds - 1, thresholds, thresholds + 1]).view(np.float32)
    flat = values.reshape(-1)
    flat[: near.size] = near
    specials = [np.nan, np.inf, -np.inf, -0.0, -5.0, 3e38, 1e-40, 65504.0]
    flat[near.size : near.size + len(specials)] = specials
    flat[-4 * width :] = np.tile(np.array(specials, np.float32), width // 2)
    return values


@pytest.mark.parametrize("tone_mapper", ["clamp", "aces"])
def test_hard_values_get_the_cpu_codes(gl_context: GLContext, tone_mapper: str) -> None:
    """The pass alone on an image of hard values: the same codes, never a wrong NaN/inf rule."""
    image = hard_image()
    height, width = image.shape[:2]
    context = PassContext(gl_context, ProgramCache(gl_context), FullscreenTriangle(gl_context))
    display = DisplayPass(context)
    texture = gl_context.ctx.texture((width, height), 4, image_bytes(image), dtype="f4")
    try:
        for exposure in (0.0, 3.0):
            request = DisplayRequest(exposure, tone_mapper, OETF8_THRESHOLDS)
            gpu = display.run(texture, request)
            cpu = display_codes(image, 8, exposure, tone_mapper).astype(np.uint8)
            assert_codes_agree(gl_context, gpu, cpu)
    finally:
        texture.release()
        display.release()
        context.fullscreen.release()
        context.programs.release()


def test_encoders_give_the_same_bytes_from_engine_codes(renderer: SurfaceRenderer) -> None:
    """PNG and raw rgba8 pixels and the JPEG bytes are those of the CPU path; codes made for
    other settings are not used."""
    frame = make_frame(jittered_lattice_ball(0.2, 0.01, seed=9))
    base = scene(background="environment")
    plain, _ = renderer.render(frame, base)
    for fmt in ("png", "jpeg", "raw"):
        request = display_request(base, fmt)
        assert request is not None
        made, _ = renderer.render(frame, base, display=request)
        np.testing.assert_array_equal(made.rgba, plain.rgba)
        options = encoder_options(base, fmt)
        assert encoders.encode(made, fmt, options) == encoders.encode(plain, fmt, options)
    jpeg = JpegOptions(exposure=1.0)  # not what the codes were made for
    made, _ = renderer.render(frame, base, display=display_request(base, "jpeg"))
    assert engine_codes(made, 1.0, "clamp", jpeg.background) is None
    assert encode_jpeg(made, jpeg) == encode_jpeg(RenderedFrame(plain.rgba), jpeg)
    assert display_request(base, "exr") is None
