"""The glare pass (passes/glare.py): light conserved, hostile radiance kept finite, the shape
against a numpy convolution with Spencer et al.'s PSF, and off means untouched.

Tolerances: the pass is linear in the spread light, so its L1 distance to a true convolution is
at most ||pyramid kernel - PSF||_1 (+ the pyramid's alignment spread) per unit of spread light;
`PyramidFit.l1_bound` computes that bound in numpy from the same operations the shaders run.
Conservation is exact up to float32 sums (~1e-6 relative) when no light leaves the frame: the
source sits at the centre of an image wider than the halo (8 deg at 0.28 deg/px = 29 px).
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest
from scipy.signal import fftconvolve

from sphrender.core.frame import make_frame
from sphrender.server.content.lattice import jittered_lattice_ball
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.gpu.draw import FullscreenTriangle, Target, image_bytes
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.gpu.programs import ProgramCache
from sphrender.server.engine.passes.context import PassContext
from sphrender.server.engine.passes.glare import GlarePass
from sphrender.server.engine.passes.glare_psf import (
    degrees_per_pixel,
    fit_pyramid,
    level_count,
    psf_kernel,
)
from sphrender.server.engine.passes.readback import read_region
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.output.local import render_for_output
from sphrender.server.scene import Scene, scene_from_dict

SIZE = 160
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def glare_scene(**glare: object) -> Scene:
    return scene_from_dict(
        {"image": {"width": SIZE, "height": SIZE}, "glare": {"enabled": True, **glare}}
    )


@pytest.fixture(scope="module")
def glare_pass(gl_context: GLContext) -> Iterator[GlarePass]:
    context = PassContext(gl_context, ProgramCache(gl_context), FullscreenTriangle(gl_context))
    glare = GlarePass(context)
    yield glare
    glare.release()
    context.fullscreen.release()
    context.programs.release()


def run_glare(
    gl: GLContext, glare: GlarePass, image: np.ndarray, scene: Scene, exposure: float = 0.0
) -> np.ndarray:
    height, width = image.shape[:2]
    source = Target.float(gl.ctx, (width, height), 4)
    try:
        source.texture.write(image_bytes(image))
        camera = Camera.from_config(scene.camera, width, height)
        out = glare.run(source, camera, scene.glare, exposure)
        return np.array(read_region(out.fbo, (width, height), None, gl.clock), np.float64)
    finally:
        source.release()


def black(size: int = SIZE) -> np.ndarray:
    image = np.zeros((size, size, 4), np.float32)
    image[..., 3] = 1.0
    return image


def spread_light(image: np.ndarray, threshold: float) -> np.ndarray:
    """The light the pass spreads: premultiplied RGB above threshold by luminance."""
    rgb = np.maximum(image[..., :3].astype(np.float64) * image[..., 3:], 0.0)
    y = rgb @ LUMINANCE
    kept = np.where(y > threshold, threshold / np.maximum(y, 1e-300), 1.0)
    return rgb * (1.0 - kept)[..., None]


def test_light_is_conserved(gl_context: GLContext, glare_pass: GlarePass) -> None:
    image = black()
    image[80, 80, :3] = (4000.0, 2500.0, 900.0)
    image[70, 90, :3] = (30.0, 20.0, 10.0)
    image[40:120, 40:120, :3] += 0.2  # below threshold: stays where it is
    out = run_glare(gl_context, glare_pass, image, glare_scene())
    before = image[..., :3].astype(np.float64).sum(axis=(0, 1))
    after = out[..., :3].sum(axis=(0, 1))
    assert np.all(np.abs(after / before - 1.0) < 0.01), (before, after)
    assert np.all(np.abs(after / before - 1.0) < 1e-4)  # in fact to float32 sums
    assert out[80, 60, 0] > 1e-6 * 4000  # the halo reaches 20 px (5.6 deg) away


def test_shape_matches_a_convolution_with_the_psf(
    gl_context: GLContext, glare_pass: GlarePass
) -> None:
    image = black()
    image[80, 80, :3] = 1000.0
    image[76, 85, :3] = (200.0, 50.0, 0.0)
    scene = glare_scene()
    out = run_glare(gl_context, glare_pass, image, scene)
    deg_per_px = degrees_per_pixel(scene.camera.fov_y, SIZE)
    fit = fit_pyramid(round(deg_per_px, 9), level_count(deg_per_px, SIZE, SIZE))
    spread = spread_light(image, scene.glare.threshold)
    kernel = psf_kernel(deg_per_px)
    reference = image[..., :3] - spread
    reference += np.stack([fftconvolve(spread[..., c], kernel, mode="same") for c in range(3)], -1)
    error = np.abs(out[..., :3] - reference).sum() / spread.sum()
    assert error <= fit.l1_bound, (error, fit)
    assert fit.l1_bound < 0.2  # the pyramid is a fair PSF, not just any blur


def test_hostile_radiance_stays_finite_and_conserved(
    gl_context: GLContext, glare_pass: GlarePass
) -> None:
    image = black()
    image[80, 80, :3] = 1e30
    image[60, 60, 0] = np.inf  # clipped to 1e30
    image[100, 100, 1] = np.nan  # counted as 0
    image[90, 90, 3] = np.nan
    out = run_glare(gl_context, glare_pass, image, glare_scene())
    assert np.isfinite(out).all()
    assert out[..., 1].sum() == pytest.approx(1e30, rel=0.01)
    assert out[..., 0].sum() == pytest.approx(2e30, rel=0.01)


def test_threshold_follows_exposure(gl_context: GLContext, glare_pass: GlarePass) -> None:
    """Exposure +3 stops: a pixel of 0.5 is exposed to 4, above the threshold of 1."""
    image = black()
    image[80, 80, :3] = 0.5
    still = run_glare(gl_context, glare_pass, image, glare_scene(), exposure=0.0)
    assert np.array_equal(still[..., :3], image[..., :3])
    glared = run_glare(gl_context, glare_pass, image, glare_scene(), exposure=3.0)
    assert glared[80, 80, 0] < 0.5 and glared[80, 84, 0] > 0.0
    assert glared[..., 0].sum() == pytest.approx(0.5, rel=1e-4)


def test_renderer_glares_display_outputs_and_exr_only_when_asked(
    renderer: SurfaceRenderer,
) -> None:
    ball = jittered_lattice_ball(0.05, 0.01, seed=3)
    frame = make_frame(ball, temperatures=np.full(len(ball), 2400.0, np.float32))
    base = {"image": {"width": 96, "height": 96}, "camera": {"eye": [0.0, 0.0, 0.4]}}
    plain = scene_from_dict(base)
    glare = scene_from_dict({**base, "glare": {"enabled": True}})
    glare_exr = scene_from_dict({**base, "glare": {"enabled": True, "exr": True}})
    still, _ = render_for_output(renderer, frame, plain, "exr")
    exr, _ = render_for_output(renderer, frame, glare, "exr")
    assert np.array_equal(exr.rgba, still.rgba)  # exr colour untouched unless asked
    assert exr.depth is not None and still.depth is not None
    assert np.array_equal(exr.depth, still.depth)
    glared_exr, _ = render_for_output(renderer, frame, glare_exr, "exr")
    assert not np.array_equal(glared_exr.rgba, still.rgba)
    assert glared_exr.depth is not None and glared_exr.normals is not None
    assert still.normals is not None
    assert np.array_equal(glared_exr.depth, still.depth)  # AOVs never
    assert np.array_equal(glared_exr.normals, still.normals)
    png_still, _ = render_for_output(renderer, frame, plain, "png")
    png, _ = render_for_output(renderer, frame, glare, "png")
    assert png.display is not None and png_still.display is not None
    assert not np.array_equal(png.display.codes, png_still.display.codes)
    premultiplied = np.asarray(glared_exr.rgba, np.float64)
    before = np.asarray(still.rgba, np.float64)
    total = (premultiplied[..., :3] * premultiplied[..., 3:]).sum()
    assert total == pytest.approx((before[..., :3] * before[..., 3:]).sum(), rel=0.01)


def test_scene_fields_are_checked() -> None:
    with pytest.raises(Exception, match=r"glare\.threshold"):
        scene_from_dict({"glare": {"threshold": -1}})
    with pytest.raises(Exception, match=r"camera\.shutter"):
        scene_from_dict({"camera": {"shutter": -0.1}})
