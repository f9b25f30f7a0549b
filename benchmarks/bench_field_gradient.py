"""The field normals' gradient two ways, timed side by side: per invocation, as the blend pass
computes it (field_gradient: each pixel gathers the centres of the rows of grid cells around its
own point; here dispatched over the image, the engine dispatches over its list of pixels), and
by tiles (a work group loads the centres around all its points into shared memory once, every
invocation reads them there), the usual GPU remedy for a gather per invocation.

Not a test. Run:  .venv/bin/python benchmarks/bench_field_gradient.py [--repeats 7]

The points are the pixels the field normals evaluate on the bench's ~100k-particle ball at
1280x720 (the default, balanced; within the reach of a rim, by the numpy reference's rim
rule, tests/reference_field_normals.py), the grid the engine's own (passes/field_grid.py).
Prints the median dispatch time of each kernel (a finish after each), their ratio, and the
largest angle between their gradients. On llvmpipe (this project's CI machines) the tiles were
3x slower (54-72 ms against 18-25 ms: barriers and shared memory cost more than the gathers
save), so the engine gathers; benchmarks/gpu_check.sh runs this on a GPU.
Kernels: benchmarks/studies/shaders/field_gradient_gather.comp.glsl, field_gradient_tiled.comp.glsl.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import moderngl
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import repo_path  # noqa: F401
from bench_frame_ratio import SETTINGS
from reference_field_normals import MAX_REACH_PX, rim_distances

from benchmarks.studies.study_shaders import shader_root
from sphrender.core.frame import make_frame
from sphrender.server.content.lattice import jittered_lattice_ball
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.gpu.draw import FullscreenTriangle
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.gpu.programs import ProgramCache
from sphrender.server.engine.gpu.shader_loader import ShaderLoader
from sphrender.server.engine.passes.context import PassContext
from sphrender.server.engine.passes.field_grid import FieldGrid, FieldParticles
from sphrender.server.engine.passes.gaps import EDGE_JUMP_RADII
from sphrender.server.engine.passes.normals import EDGE_JUMP_FOOTPRINTS
from sphrender.server.engine.renderer import SurfaceRenderer

KERNELS = {
    "per invocation (field_gradient)": ("studies/field_gradient_gather.comp.glsl", 8),
    "tiles in shared memory": ("studies/field_gradient_tiled.comp.glsl", 8),
}
RADIUS = 0.01


def needed_points(gl: GLContext) -> tuple[np.ndarray, np.ndarray]:
    """The view points (H, W, 4; w = 1 where the field normals evaluate the gradient) and the
    particles' view-space centres."""
    positions = jittered_lattice_ball(0.58, RADIUS, seed=0)
    scene = SETTINGS["balanced (default)"]
    renderer = SurfaceRenderer(gl)
    try:
        out, _ = renderer.render(make_frame(positions), scene, depth=True)
    finally:
        renderer.release()
    assert out.depth is not None
    width, height = scene.image.width, scene.image.height
    camera = Camera.from_config(scene.camera, width, height)
    depth = np.where(np.isfinite(out.depth), out.depth, 0.0).astype(np.float64)
    focal = camera.pixels_per_unit_at_unit_depth
    with np.errstate(divide="ignore"):
        radius_px = np.where(depth > 0, RADIUS * focal / depth, 0.0)
    reach_radii = scene.quality.field_normals
    reach = np.clip(np.floor(reach_radii * radius_px + 0.5), 1, MAX_REACH_PX)
    edge_jump = EDGE_JUMP_RADII * RADIUS
    dist = rim_distances(depth, edge_jump, EDGE_JUMP_FOOTPRINTS * depth / focal, MAX_REACH_PX + 1)
    needed = (depth > 0) & (dist <= reach + 1)
    tan_y = camera.tan_half_fov_y
    ys, xs = np.mgrid[0:height, 0:width] + 0.5
    points = np.stack(
        [
            (xs / width * 2 - 1) * tan_y * camera.aspect * depth,
            (ys / height * 2 - 1) * tan_y * depth,
            -depth,
            needed.astype(np.float64),
        ],
        axis=-1,
    )
    return points.astype(np.float32), camera.to_view(positions)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    with GLContext() as gl, shader_root() as root:
        points, centres = needed_points(gl)
        height, width = points.shape[:2]
        ctx = gl.ctx
        context = PassContext(gl, ProgramCache(gl, ShaderLoader(root)), FullscreenTriangle(gl))
        grid = FieldGrid(context)
        spheres = np.zeros((len(centres), 4), np.float32)
        spheres[:, :3], spheres[:, 3] = centres, RADIUS
        support = SETTINGS["balanced (default)"].quality.field_normals_support * RADIUS
        built = grid.build(FieldParticles(arrays=(spheres,)), support)
        grid.bind_for_reading()
        point_image = ctx.texture((width, height), 4, points.tobytes(), dtype="f4")
        gradient_image = ctx.texture((width, height), 4, dtype="f4")
        point_image.bind_to_image(0, read=True, write=False)
        gradient_image.bind_to_image(1, read=False, write=True)
        results: dict[str, tuple[float, np.ndarray]] = {}
        try:
            for name, (shader_name, group) in KERNELS.items():
                shader = context.programs.compute(shader_name)
                shader["u_support"] = built.support
                shader["u_bucket_mask"] = built.bucket_mask
                groups = (-(-width // group), -(-height // group))
                times = []
                for repeat in range(args.repeats + 1):  # the first: compile and warm up
                    start = time.perf_counter()
                    shader.run(*groups)
                    ctx.memory_barrier(moderngl.ALL_BARRIER_BITS)
                    ctx.finish()
                    if repeat:
                        times.append((time.perf_counter() - start) * 1e3)
                gradient = np.frombuffer(gradient_image.read(), np.float32).reshape(points.shape)
                results[name] = (statistics.median(times), gradient)
        finally:
            point_image.release()
            gradient_image.release()
            grid.release()
            context.fullscreen.release()
            context.programs.release()
    needed = points[..., 3] != 0
    (base_name, (base_ms, base)), *others = results.items()
    print(f"{gl.renderer}; {len(centres)} particles, {width}x{height}, {needed.sum()} points")
    print(f"{base_name:36} {base_ms:7.1f} ms")
    for name, (ms, gradient) in others:
        a, b = base[needed][:, :3], gradient[needed][:, :3]
        cos = np.sum(a * b, -1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
        worst = np.degrees(np.arccos(np.clip(np.nanmin(cos), -1.0, 1.0)))
        print(f"{name:36} {ms:7.1f} ms  ratio {ms / base_ms:.2f}  largest angle {worst:.4f} deg")


if __name__ == "__main__":
    main()
