"""Rendering + encoding with the embedded engine, for `sphrender render` and `submit --local`.

`render_encoded` is the one place that decides, from the scene and the output format, which AOVs
to read back and which encoder options to use; the service's encoder pool uses the same choices.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sphrender.core.frame import ParticleFrame
from sphrender.core.protocol import ImageFormat
from sphrender.server.engine.frame_output import DisplayRequest, RenderedFrame, RenderStats
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.output import encoders
from sphrender.server.output.display import OETF8_THRESHOLDS
from sphrender.server.scene import Scene

__all__ = [
    "ImageFormat",
    "LocalFrameRenderer",
    "aovs_for_output",
    "encode_for_scene",
    "encoder_options",
    "raw_layout",
    "render_for_output",
]


def aovs_for_output(scene: Scene, fmt: ImageFormat) -> tuple[str, ...]:
    """The AOVs the output carries: the scene's for EXR and float raw, none otherwise."""
    if fmt == "exr" or (fmt == "raw" and scene.output.raw_type != "rgba8"):
        return tuple(scene.output.aovs)
    return ()


def display_request(scene: Scene, fmt: ImageFormat) -> DisplayRequest | None:
    """For the 8-bit display-referred outputs (PNG at 8 bits, JPEG, raw rgba8), what the engine
    needs to make their codes on the GPU (passes/display.py); None for the others."""
    out = scene.output
    if fmt == "jpeg":
        background = tuple(float(c) for c in out.jpeg_background)
        return DisplayRequest(
            out.exposure,
            out.tone_mapper,
            OETF8_THRESHOLDS,
            background,  # type: ignore[arg-type]
        )
    if (fmt == "png" and out.png_bits == 8) or (fmt == "raw" and out.raw_type == "rgba8"):
        return DisplayRequest(out.exposure, out.tone_mapper, OETF8_THRESHOLDS)
    return None


def render_for_output(
    renderer: SurfaceRenderer, frame: ParticleFrame, scene: Scene, fmt: ImageFormat
) -> tuple[RenderedFrame, RenderStats]:
    """Render, reading back Z / N only when the output format will carry them, and the 8-bit
    display codes when it is display-referred."""
    aovs = aovs_for_output(scene, fmt)
    return renderer.render(
        frame,
        scene,
        depth="Z" in aovs,
        normals="N" in aovs,
        display=display_request(scene, fmt),
        linear=fmt == "exr" or (fmt == "raw" and scene.output.raw_type != "rgba8"),
    )


def encoder_options(scene: Scene, fmt: ImageFormat) -> encoders.Options:
    """The encoder options the scene's ``[output]`` asks for, for one format."""
    out = scene.output
    if fmt == "png":
        return encoders.PngOptions(
            bits=out.png_bits, exposure=out.exposure, tone_mapper=out.tone_mapper
        )
    if fmt == "jpeg":
        return encoders.JpegOptions(
            quality=out.jpeg_quality,
            background=out.jpeg_background,
            exposure=out.exposure,
            tone_mapper=out.tone_mapper,
        )
    if fmt == "raw":
        return encoders.RawOptions(
            type=out.raw_type, aovs=out.aovs, exposure=out.exposure, tone_mapper=out.tone_mapper
        )
    return encoders.ExrOptions(pixel_type=out.exr_pixel_type, aovs=out.aovs)


def encode_for_scene(rendered: RenderedFrame, scene: Scene, fmt: ImageFormat) -> bytes:
    return encoders.encode(rendered, fmt, encoder_options(scene, fmt))


def raw_layout(scene: Scene, fmt: ImageFormat) -> list[dict[str, Any]] | None:
    """For raw output, the payload's array descriptors (PROTOCOL.md §4.3); else None."""
    if fmt != "raw":
        return None
    options = encoder_options(scene, fmt)
    assert isinstance(options, encoders.RawOptions)
    return encoders.raw_arrays(options, scene.image.width, scene.image.height)


class LocalFrameRenderer:
    """A `FrameRenderer` (see `sphrender.client.submit`) backed by the embedded engine.

    Creates its GL context on construction (on EGL device `device_index`); must be used and
    closed on that same thread."""

    def __init__(
        self,
        scene: Scene,
        fmt: ImageFormat,
        environment_dirs: Sequence[str | Path] = (),
        *,
        device_index: int = 0,
    ) -> None:
        self.scene = scene
        self.format = fmt
        self._gl = GLContext(device_index=device_index)
        self._renderer = SurfaceRenderer(self._gl, environment_dirs=environment_dirs)
        self._renderer.check_image_size(scene)

    @property
    def gl_renderer(self) -> str:
        return self._gl.renderer

    def render(self, frame: ParticleFrame) -> bytes:
        rendered, _ = render_for_output(self._renderer, frame, self.scene, self.format)
        return encode_for_scene(rendered, self.scene, self.format)

    def close(self) -> None:
        self._renderer.release()
        self._gl.release()
