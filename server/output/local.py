"""Rendering + encoding with the embedded engine, for `sphrender render` and `submit --local`.

`render_encoded` is the one place that decides, from the scene and the output format, which AOVs
to read back and which encoder options to use; the service's encoder pool uses the same choices.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Literal

from sphrender.client.frame import ParticleFrame
from sphrender.server.engine.frame_output import RenderedFrame, RenderStats
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.output import encoders
from sphrender.server.scene import Scene

ImageFormat = Literal["png", "exr"]


def render_for_output(
    renderer: SurfaceRenderer, frame: ParticleFrame, scene: Scene, fmt: ImageFormat
) -> tuple[RenderedFrame, RenderStats]:
    """Render, reading back Z / N only when the output format will carry them."""
    aovs = scene.output.aovs if fmt == "exr" else ()
    return renderer.render(frame, scene, depth="Z" in aovs, normals="N" in aovs)


def encode_for_scene(rendered: RenderedFrame, scene: Scene, fmt: ImageFormat) -> bytes:
    if fmt == "png":
        png = encoders.PngOptions(
            bits=scene.output.png_bits,
            exposure=scene.output.exposure,
            tone_mapper=scene.output.tone_mapper,
        )
        return encoders.encode_png(rendered, png)
    exr = encoders.ExrOptions(pixel_type=scene.output.exr_pixel_type, aovs=scene.output.aovs)
    return encoders.encode_exr(rendered, exr)


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
