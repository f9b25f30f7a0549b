"""Encoder benchmark: png vs jpeg vs raw vs exr on real rendered frames, side by side, one run.

Not a test. Run:  .venv/bin/python benchmarks/bench_encoders.py [--size 1280x720] [--repeat 8]

Renders two frames with the real engine (a ~100k-particle ball on a transparent background, the
service benchmark's frame; the weld-bead demo over its environment, every pixel covered), then
times each encoding of the same RenderedFrame ``--repeat`` times (median) and reports bytes per
frame, and for the 8-bit encodings the display transform (tone map + sRGB codes) apart from the
compression. Also measures Pillow's JPEG encoder against simplejpeg's (both libjpeg-turbo) when
Pillow is installed (the [bench] extra).

Then the same encodings of frames that carry the engine's display codes (passes/display.py: the
display transform on the GPU, read back as bytes), which is how `render`, `submit` and the
service encode PNG, JPEG and raw rgba8: the encoder then only compresses. The display pass's own
cost is reported as the read-back stage with and without it (here llvmpipe: the CPU again).
"""

from __future__ import annotations

import argparse
import io
import statistics
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from sphrender.core.frame import make_frame
from sphrender.server.content.demo import demo_frame, demo_scene
from sphrender.server.content.lattice import jittered_lattice_ball
from sphrender.server.engine.frame_output import RenderedFrame
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.output import display, encoders, frame_formats
from sphrender.server.output.local import display_request, encoder_options
from sphrender.server.scene import Scene, merge_scene_dicts, scene_from_dict, scene_to_dict

FrameSet = tuple[str, RenderedFrame, dict[str, RenderedFrame], float, Scene]


def timed(function: Callable[[], Any], repeat: int) -> tuple[float, Any]:
    function()  # warm (first-call allocations, the sRGB table is built at import)
    times, out = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        out = function()
        times.append((time.perf_counter() - start) * 1e3)
    return statistics.median(times), out


def with_codes(
    renderer: SurfaceRenderer, frame: Any, scene: Scene
) -> tuple[RenderedFrame, dict[str, RenderedFrame], float, Scene]:
    """The frame plain (Z, N read back), per 8-bit format the frame with the engine's codes
    (aces, as the encodings below), and the display pass's median cost in ms."""
    aces = scene_from_dict(
        merge_scene_dicts(scene_to_dict(scene), {"output": {"tone_mapper": "aces"}})
    )
    plain, _ = renderer.render(frame, aces, depth=True, normals=True)
    made: dict[str, RenderedFrame] = {}
    for fmt in ("png", "jpeg", "raw"):
        request = display_request(aces, fmt)  # type: ignore[arg-type]
        made[fmt], _ = renderer.render(frame, aces, depth=True, normals=True, display=request)
    request = display_request(aces, "jpeg")  # type: ignore[arg-type]
    without = [renderer.render(frame, aces)[1].stage_ms["readback"] for _ in range(5)]
    with_pass = [
        renderer.render(frame, aces, display=request)[1].stage_ms["readback"] for _ in range(5)
    ]
    return plain, made, statistics.median(with_pass) - statistics.median(without), aces


def frames(width: int, height: int) -> list[FrameSet]:
    size = {"image": {"width": width, "height": height}}
    ball_scene = scene_from_dict(
        {
            **size,
            "camera": {"eye": [1.3, 1.0, 1.7], "target": [0.0, 0.0, 0.0], "fov_y": 40.0},
            "particles": {"radius": 0.01},
        }
    )
    demo: Scene = scene_from_dict(merge_scene_dicts(scene_to_dict(demo_scene()), size))
    out = []
    with GLContext() as gl:
        renderer = SurfaceRenderer(gl)
        try:
            ball = make_frame(jittered_lattice_ball(0.58, 0.01))
            out.append(
                (
                    f"ball {ball.count} particles, transparent",
                    *with_codes(renderer, ball, ball_scene),
                )
            )
            out.append(
                ("weld demo, environment background", *with_codes(renderer, demo_frame(), demo))
            )
        finally:
            renderer.release()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--size", default="1280x720")
    parser.add_argument("--repeat", type=int, default=8)
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    try:
        import PIL.Image
    except ImportError:
        PIL = None
    for name, frame, made, display_ms, scene in frames(width, height):
        png = bench_frame(name, frame, args.repeat, PIL)
        bench_engine_codes(made, display_ms, png, scene, args.repeat)


def bench_engine_codes(
    made: dict[str, RenderedFrame], display_ms: float, png_cpu: float, scene: Scene, repeat: int
) -> None:
    """The 8-bit encodings from the engine's codes (the scene's encoder options, which the codes
    were made for), against the CPU-path PNG of the same frame."""
    cases: list[tuple[str, Callable[[], bytes]]] = [
        (label, lambda fmt=fmt: encoders.encode(made[fmt], fmt, encoder_options(scene, fmt)))  # type: ignore[misc]
        for label, fmt in (("png 8-bit", "png"), ("jpeg q90", "jpeg"), ("raw rgba8", "raw"))
    ]
    print(f"  with the engine's display codes (display pass {display_ms:.1f} ms on this GL):")
    results = {}
    for label, function in cases:
        ms, data = timed(function, repeat)
        results[label] = ms
        print(f"  {label:<20} {ms:8.1f} ms  {len(data) / 1e3:9.1f} kB", flush=True)
    for label in ("jpeg q90", "raw rgba8"):
        print(
            f"  {label} / png (CPU path) = {results[label] / png_cpu:.3f}; "
            f"/ png (engine codes) = {results[label] / results['png 8-bit']:.3f}"
        )


def bench_frame(name: str, frame: RenderedFrame, repeat: int, PIL: Any) -> float:
    """The encodings of `frame` on the CPU path; returns the PNG's median ms."""
    covered = float(np.mean(frame.rgba[..., 3] > 0))
    print(f"\n{frame.width}x{frame.height}, {name} ({covered:.0%} of pixels covered)", flush=True)
    aces = {"tone_mapper": "aces"}
    cases: list[tuple[str, Callable[[], bytes]]] = [
        ("png 8-bit", lambda: encoders.encode_png(frame, encoders.PngOptions(**aces))),
        ("jpeg q90", lambda: encoders.encode_jpeg(frame, encoders.JpegOptions(**aces))),
        (
            "jpeg q75",
            lambda: encoders.encode_jpeg(frame, encoders.JpegOptions(quality=75, **aces)),
        ),
        ("raw rgba8", lambda: encoders.encode_raw(frame, encoders.RawOptions(**aces))),
        (
            "raw float16 + Z,N",
            lambda: encoders.encode_raw(frame, encoders.RawOptions(type="float16")),
        ),
        (
            "raw float32",
            lambda: encoders.encode_raw(frame, encoders.RawOptions(type="float32", aovs=())),
        ),
        ("exr auto + Z,N", lambda: encoders.encode_exr(frame, encoders.ExrOptions("auto"))),
    ]
    results = {}
    for label, function in cases:
        ms, data = timed(function, repeat)
        results[label] = ms
        print(f"  {label:<20} {ms:8.1f} ms  {len(data) / 1e3:9.1f} kB", flush=True)
    png = results["png 8-bit"]
    for label in ("jpeg q90", "raw rgba8", "raw float32"):
        print(f"  {label} / png = {results[label] / png:.2f}")
    codes_ms, codes = timed(lambda: display.display_codes(frame.rgba, 8, 0.0, "aces"), repeat)
    rgb = frame_formats.composite_codes(codes, (0.0, 0.0, 0.0))
    import simplejpeg

    jpeg_ms, _ = timed(lambda: simplejpeg.encode_jpeg(rgb, quality=90, colorspace="RGB"), repeat)
    print(
        f"  display transform (tone map + 8-bit codes) {codes_ms:.1f} ms; of the rest: "
        f"png deflate ~{png - codes_ms:.1f} ms, simplejpeg {jpeg_ms:.1f} ms"
    )
    if PIL is not None:

        def pillow() -> bytes:
            out = io.BytesIO()
            PIL.Image.fromarray(rgb).save(out, "JPEG", quality=90)
            return out.getvalue()

        pil_ms, _ = timed(pillow, repeat)
        print(f"  Pillow JPEG q90 on the same codes: {pil_ms:.1f} ms")
    return png


if __name__ == "__main__":
    main()
