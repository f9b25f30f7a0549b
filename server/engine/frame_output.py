"""What the render engine hands back for one frame, before any encoding.

Rendering and encoding are separate steps: the engine fills a `RenderedFrame` with float arrays
and `sphrender.server.output.encoders` turns it into PNG or EXR bytes (or files) afterwards, so
the service can render once and encode on demand.

Conventions every producer must follow (the encoders rely on them):

* ``rgba`` is (H, W, 4) float32. RGB is scene-linear and *straight* (not premultiplied by alpha);
  alpha is coverage in [0, 1].
* Row 0 is the TOP of the image. OpenGL read-backs are bottom-first and must be flipped
  (``array[::-1]``) before they are stored here.
* ``depth`` is (H, W) float32 eye-space depth along the view axis, positive, ``+inf`` where no
  surface was hit.
* ``normals`` is (H, W, 3) float32 world-space unit normals, 0 where no surface was hit.

`RenderStats` says what the frame cost (milliseconds per stage that ran) and did (counts).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

Float32Array = npt.NDArray[np.float32]


def _as_float32(name: str, value: object, ndim: int, channels: int | None) -> Float32Array:
    array = np.asarray(value, dtype=np.float32)  # no copy when it already is float32
    if array.ndim != ndim or (channels is not None and array.shape[-1] != channels):
        expected = "(H, W)" if channels is None else f"(H, W, {channels})"
        raise ValueError(f"{name} must have shape {expected}, got {array.shape}")
    return array


@dataclass(frozen=True)
class RenderedFrame:
    """One rendered frame: colour plus optional depth and normal AOVs (see module docstring).

    Arrays are converted to float32 on construction (no copy when they already are float32);
    shapes are checked so a mismatch fails here rather than deep inside an encoder.
    """

    rgba: Float32Array
    depth: Float32Array | None = None
    normals: Float32Array | None = None
    #: The engine's display codes, when the render was asked for them (`DisplayRequest`).
    display: DisplayCodes | None = None

    def __post_init__(self) -> None:
        rgba = _as_float32("rgba", self.rgba, 3, 4)
        height, width = int(rgba.shape[0]), int(rgba.shape[1])
        if height < 1 or width < 1:
            raise ValueError(f"rgba must be at least 1x1, got {width}x{height}")
        object.__setattr__(self, "rgba", rgba)
        if self.depth is not None:
            depth = _as_float32("depth", self.depth, 2, None)
            if depth.shape != (height, width):
                raise ValueError(f"depth shape {depth.shape} does not match rgba {(height, width)}")
            object.__setattr__(self, "depth", depth)
        if self.normals is not None:
            normals = _as_float32("normals", self.normals, 3, 3)
            if normals.shape[:2] != (height, width):
                raise ValueError(
                    f"normals shape {normals.shape} does not match rgba {(height, width)}"
                )
            object.__setattr__(self, "normals", normals)

    @property
    def width(self) -> int:
        return int(self.rgba.shape[1])

    @property
    def height(self) -> int:
        return int(self.rgba.shape[0])


@dataclass(frozen=True)
class DisplayRequest:
    """Ask the engine for 8-bit display codes too (passes/display.py), so PNG, JPEG and raw
    rgba8 encoders skip the CPU display transform: the scene's exposure (stops) and tone mapper,
    the OETF thresholds that define the codes (`server/output/display.py` owns them: per code
    k = 1..255 the first float32 bit pattern of display-linear value with code >= k), and for
    JPEG the opaque background (0-1 per channel) the codes are composited over."""

    exposure: float
    tone_mapper: str
    thresholds: npt.NDArray[np.uint64]
    background: tuple[float, float, float] | None = None

    def matches(
        self, exposure: float, tone_mapper: str, background: tuple[float, float, float] | None
    ) -> bool:
        """Whether codes made for this request are the ones an encoder with these settings
        computes."""

        def floats(v: tuple[float, float, float] | None) -> tuple[float, ...] | None:
            return None if v is None else tuple(float(c) for c in v)

        return (
            self.exposure == exposure
            and self.tone_mapper == tone_mapper
            and floats(self.background) == floats(background)
        )


@dataclass(frozen=True)
class DisplayCodes:
    """8-bit sRGB codes of a frame, (H, W, 4) uint8 rows top first (alpha 255 when
    composited over `request.background`), made by the engine for `request`."""

    codes: npt.NDArray[np.uint8]
    request: DisplayRequest


@dataclass(frozen=True)
class InputNote:
    """Something the renderer changed about a frame's input to render it, said to the client
    (IMAGE `notes`, PROTOCOL.md 4.3): the input field, and what was done, in words."""

    field: str
    message: str


@dataclass
class RenderStats:
    """What one frame cost and did: milliseconds per stage (only stages that ran), counts,
    and notes on its input."""

    stage_ms: dict[str, float] = field(default_factory=dict)
    particles_in: int = 0
    particles_drawn: int = 0  # visible: in front of the camera and inside the image
    particles_splatted: int = 0  # rasterised: the visible ones less those found hidden
    far: float = 0.0
    #: What the render thread did outside GL calls (Python, numpy): the frame time's floor on a
    #: GPU. Wall time of the render less the time inside the GL calls that do the device's work
    #: (gpu/gl_clock.py) and less the SPH stage (OpenCL, its own stage time).
    host_ms: float = 0.0
    notes: list[InputNote] = field(default_factory=list)

    @property
    def total_ms(self) -> float:
        return sum(self.stage_ms.values())
