"""Display pass: the shaded frame's 8-bit sRGB codes, made on the GPU and read back as bytes.

PNG (8-bit), JPEG and raw rgba8 all start from the display transform (exposure, tone mapper,
sRGB OETF, quantisation), which costs the CPU far more than the compression itself (~100-400 ms
per 1280x720 frame against ~10 ms for libjpeg-turbo). `shaders/display/display_codes.frag.glsl`
computes the same codes as `server/output/display.py` (the CPU's own OETF thresholds, the same
float32 operation order; tests/test_display_pass.py compares them) and writes them top row first
into an RGBA8 target, so the read-back is the encoder's input as it is: 4 bytes a pixel, no
per-pixel work on the host. With a JPEG background the codes are composited over it there too.

Owns: the program variants (through the ProgramCache), the RGBA8 target per image size and the
threshold buffer; released with the renderer.
"""

from __future__ import annotations

import moderngl
import numpy as np
import numpy.typing as npt

from sphrender.server.engine.frame_output import DisplayRequest
from sphrender.server.engine.geometry.screen_box import ScreenBox
from sphrender.server.engine.gpu.draw import PerSize, set_scissor
from sphrender.server.engine.gpu.uniforms import set_if_used
from sphrender.server.engine.passes.context import FULLSCREEN_VERT, PassContext

FRAGMENT_SHADER = "display/display_codes.frag.glsl"
TONE_MAPPER_DEFINES = {"clamp": 0, "aces": 1}


class _Target:
    def __init__(self, ctx: moderngl.Context, size: tuple[int, int]) -> None:
        self.texture = ctx.texture(size, 4, dtype="f1")
        self.fbo = ctx.framebuffer([self.texture])

    def release(self) -> None:
        self.fbo.release()
        self.texture.release()


class DisplayPass:
    def __init__(self, context: PassContext) -> None:
        self._context = context
        self._thresholds = context.gl.ctx.buffer(reserve=256 * 4)
        self._uploaded: npt.NDArray[np.integer] | None = None  # the table now in the buffer
        self._targets = PerSize(lambda size: _Target(context.gl.ctx, size))

    def run(
        self, color: moderngl.Texture, request: DisplayRequest, box: ScreenBox | None = None
    ) -> npt.NDArray[np.uint8]:
        """(H, W, 4) uint8 codes of the straight linear RGBA `color`, rows top first. `box`:
        where `color` can be non-zero (a transparent background); outside it every pixel gets
        the code of a zero pixel (0, or the opaque background), written by a clear."""
        if request.tone_mapper not in TONE_MAPPER_DEFINES:
            raise ValueError(f"tone mapper must be one of {', '.join(TONE_MAPPER_DEFINES)}")
        width, height = color.size
        target = self._targets.get((width, height))
        defines = {
            "TONE_MAPPER": TONE_MAPPER_DEFINES[request.tone_mapper],
            "COMPOSITE": request.background is not None,
        }
        program = self._context.programs.get(
            FULLSCREEN_VERT, FRAGMENT_SHADER, defines, {"u_color": 0}
        )
        set_if_used(program, "u_scale", float(np.float32(np.exp2(np.float64(request.exposure)))))
        set_if_used(program, "u_height", height)
        if request.background is not None:
            codes = tuple(int(np.floor(c * 255.0 + 0.5)) for c in request.background)
            set_if_used(program, "u_background", codes)
        color.use(0)
        if request.thresholds is not self._uploaded:  # the output layer's one table: once
            self._thresholds.write(_threshold_table(request.thresholds))
            self._uploaded = request.thresholds
        if self._context.gl.claim_storage_bindings(self):
            self._thresholds.bind_to_storage_buffer(0)
        target.fbo.use()
        if box is not None:
            x, y, w, h = box
            red = green = blue = alpha = 0.0
            if request.background is not None:  # what the shader composites a zero pixel to
                red, green, blue = (c / 255.0 for c in codes)
                alpha = 1.0
            set_scissor(target.fbo, None)
            with self._context.gl.clock:
                target.fbo.clear(red, green, blue, alpha)
            set_scissor(target.fbo, (x, height - y - h, w, h))  # the image is written top first
        self._context.fullscreen.draw(program)
        set_scissor(target.fbo, None)
        out = np.empty((height, width, 4), np.uint8)
        with self._context.gl.clock:
            target.fbo.read_into(out, components=4, dtype="f1")
        return out

    def release(self) -> None:
        self._targets.release()
        self._thresholds.release()


def _threshold_table(thresholds: npt.NDArray[np.integer]) -> bytes:
    """The 255 thresholds as the shader's uint[256] (the last entry never reached)."""
    table = np.full(256, 0xFFFFFFFF, np.uint32)
    table[:255] = np.minimum(np.asarray(thresholds)[:255], 0xFFFFFFFF).astype(np.uint32)
    return table.tobytes()
