"""The frame's outputs from its shaded colour: glare when the scene asks (passes/glare.py), the
read-back of colour and AOVs (passes/readback.py) and the 8-bit display codes
(passes/display.py). Glare goes into the display codes always and into the colour read back
unless that colour feeds a scene-linear output (EXR, raw float) whose `[glare] exr` is off; Z and
N never see it.

Owns: the glare, read-back and display passes; released with the renderer.
"""

from __future__ import annotations

from dataclasses import replace

from sphrender.server.engine.frame_output import DisplayCodes, DisplayRequest, RenderedFrame
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.geometry.screen_box import ScreenBox
from sphrender.server.engine.gpu.draw import Target
from sphrender.server.engine.passes.context import PassContext
from sphrender.server.engine.passes.display import DisplayPass
from sphrender.server.engine.passes.glare import GlarePass
from sphrender.server.engine.passes.readback import ReadbackPass
from sphrender.server.scene import Scene


class OutputStage:
    def __init__(self, context: PassContext) -> None:
        self._glare = GlarePass(context)
        self._readback = ReadbackPass(context)
        self._display = DisplayPass(context)

    def glare(self, color: Target, camera: Camera, scene: Scene) -> Target:
        """The glared colour (its own target), or `color` when the scene has no glare."""
        if not scene.glare.enabled:
            return color
        return self._glare.run(color, camera, scene.glare, scene.output.exposure)

    def read(
        self,
        color: Target,
        glared: Target,
        normal_depth: Target,
        scene: Scene,
        box: ScreenBox | None,
        *,
        whole: bool,
        depth: bool,
        normals: bool,
        display: DisplayRequest | None,
        linear: bool,
    ) -> RenderedFrame:
        """The frame's images on the host. `box`: where the colour can be non-zero on a
        transparent background (None: anywhere); `whole`: read whole images (device prepare:
        the driver copies whole images, the host zeroes nothing)."""
        transparent = scene.shading.background == "transparent"
        read_box = None if whole else box
        rendered = self._readback.run(
            color if linear and not scene.glare.exr else glared,
            normal_depth,
            want_depth=depth,
            want_normals=normals,
            color_box=read_box if transparent else None,
            surface_box=read_box,
        )
        if display is None:
            return rendered
        codes = self._display.run(glared.texture, display, box if transparent else None)
        return replace(rendered, display=DisplayCodes(codes, display))

    def release(self) -> None:
        for gpu_pass in (self._glare, self._readback, self._display):
            gpu_pass.release()
