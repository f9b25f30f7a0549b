"""Offline reference surface for real SPH data: pysplashsurf reconstruction, rasterised with the
renderer's camera into per-pixel eye depth and world normals (the `Truth` of `scenes.py`).

Parameters follow splashsurf's recommended setup and the renderer's SPH conventions: cubic
spline kernel with support 4 r (pysplashsurf's smoothing length is half the support, in radii:
2.0), iso-surface threshold 0.6, marching-cubes cubes of 0.5 r, 25 iterations of weighted
Laplacian mesh smoothing, vertex normals smoothed 10 times.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import moderngl
import numpy as np
import numpy.typing as npt

from sphrender.server.bench.scenes import Truth
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.gpu.programs import ProgramCache

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class ReferenceMesh:
    vertices: F64  # (V, 3) world
    triangles: npt.NDArray[np.uint32]  # (T, 3)
    normals: F64  # (V, 3) unit
    seconds: float  # reconstruction wall time


def reconstruct(positions: F64, radius: float) -> ReferenceMesh:
    """pysplashsurf's pipeline (ImportError when the package is missing)."""
    import pysplashsurf

    start = time.perf_counter()
    result = pysplashsurf.reconstruction_pipeline(
        np.ascontiguousarray(positions, dtype=np.float64),
        particle_radius=radius,
        rest_density=1000.0,
        smoothing_length=2.0,
        cube_size=0.5,
        iso_surface_threshold=0.6,
        mesh_smoothing_iters=25,
        mesh_smoothing_weights=True,
        compute_normals=True,
        normals_smoothing_iters=10,
    )
    seconds = time.perf_counter() - start
    mesh_data = result[0] if isinstance(result, tuple) else result
    mesh: Any = mesh_data.mesh  # TriMesh3d: the pipeline makes triangles unless asked for quads
    normals = np.asarray(mesh_data.point_attributes["normals"], dtype=np.float64)
    return ReferenceMesh(
        np.asarray(mesh.vertices, dtype=np.float64),
        np.asarray(mesh.triangles, dtype=np.uint32),
        normals,
        seconds,
    )


def rasterise(gl: GLContext, programs: ProgramCache, mesh: ReferenceMesh, camera: Camera) -> Truth:
    """Depth-tested rasterisation of the mesh; returns depth + normals per pixel, rows top first.

    The vertex normal's sign is made to face the camera where the mesh's orientation would
    otherwise flip it (the screen-space surface always faces the eye)."""
    ctx = gl.ctx
    view = camera.to_view(mesh.vertices)
    far = float(np.max(-view[:, 2])) * 1.01 + camera.near if len(view) else 1.0
    program = programs.get("truth/mesh_reference.vert.glsl", "truth/mesh_reference.frag.glsl")
    vertices = ctx.buffer(np.ascontiguousarray(view, dtype=np.float32).tobytes())
    normals = ctx.buffer(np.ascontiguousarray(mesh.normals, dtype=np.float32).tobytes())
    indices = ctx.buffer(np.ascontiguousarray(mesh.triangles, dtype=np.uint32).tobytes())
    size = (camera.width, camera.height)
    target = ctx.texture(size, 4, dtype="f4")
    depth = ctx.depth_renderbuffer(size)
    fbo = ctx.framebuffer([target], depth)
    vao = ctx.vertex_array(
        program,
        [(vertices, "3f", "in_view_position"), (normals, "3f", "in_world_normal")],
        index_buffer=indices,
        index_element_size=4,
    )
    try:
        program["u_projection"].write(camera.projection_matrix(far).T.copy().tobytes())  # type: ignore[union-attr]
        fbo.use()
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        ctx.enable(moderngl.DEPTH_TEST)
        try:
            vao.render(moderngl.TRIANGLES)
        finally:
            ctx.disable(moderngl.DEPTH_TEST)
        pixels = np.frombuffer(target.read(), dtype=np.float32)
        pixels = pixels.reshape(camera.height, camera.width, 4)[::-1].astype(np.float64)
    finally:
        for obj in (vao, fbo, depth, target, indices, normals, vertices):
            obj.release()
    hit = pixels[:, :, 3] > 0.0
    n = pixels[:, :, :3]
    length = np.linalg.norm(n, axis=2, keepdims=True)
    n = np.where(length > 0, n / np.maximum(length, 1e-12), 0.0)
    from sphrender.server.bench.analytic import pixel_rays

    facing = np.einsum("ijk,ijk->ij", n, pixel_rays(camera).directions)
    n = np.where((facing > 0)[..., None], -n, n)
    return Truth(hit, np.where(hit, pixels[:, :, 3], np.inf), np.where(hit[..., None], n, 0.0))
