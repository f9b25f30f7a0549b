"""GLSL compile errors name the original file and line (real GL compiler)."""

from __future__ import annotations

from pathlib import Path

import moderngl
import numpy as np
import pytest

from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.gpu.programs import ProgramCache, ShaderCompileError
from sphrender.server.engine.gpu.shader_loader import ShaderLoader


def test_compile_error_names_included_file_and_line(tmp_path: Path, gl_context: GLContext) -> None:
    (tmp_path / "lib").mkdir()
    (tmp_path / "lib" / "broken.glsl").write_text(
        "// helper\nfloat helper(float x) {\n    return x * undefined_thing;\n}\n"
    )
    (tmp_path / "main.frag.glsl").write_text(
        '#version 330 core\n#include "lib/broken.glsl"\nout vec4 color;\n'
        "void main() { color = vec4(helper(1.0)); }\n"
    )
    (tmp_path / "quad.vert.glsl").write_text(
        "#version 330 core\nvoid main() { gl_Position = vec4(0.0); }\n"
    )
    cache = ProgramCache(gl_context, ShaderLoader(tmp_path))
    with pytest.raises(ShaderCompileError) as info:
        cache.get("quad.vert.glsl", "main.frag.glsl")
    assert "lib/broken.glsl:3" in str(info.value)
    cache.release()


def test_every_shipped_program_compiles(gl_context: GLContext) -> None:
    cache = ProgramCache(gl_context)
    cache.get("splat/splat_sphere.vert.glsl", "splat/splat_sphere.frag.glsl")
    cache.get("common/fullscreen.vert.glsl", "normals/surface_normals.frag.glsl")
    cache.get(
        "splat/splat_sphere.vert.glsl", "splat/splat_sphere.frag.glsl", {"HAS_TEMPERATURE": True}
    )
    for fragment in ("lighting/prefilter_ggx.frag.glsl", "lighting/brdf_probe.frag.glsl"):
        cache.get("common/fullscreen.vert.glsl", fragment)
    for g_term in (0, 1):
        cache.get("common/fullscreen.vert.glsl", "lighting/brdf_lut.frag.glsl", {"G_TERM": g_term})
    # Every define of the shading shader on its own (the combinations share the code paths).
    for defines in (
        {},
        {"IBL_MODE": 0},
        {"IBL_MODE": 2, "G_TERM": 1},
        {"COMBINE": 1, "HAS_TEMPERATURE": True, "BACKGROUND_ENVIRONMENT": True},
        {"IBL_MODE": 0, "MULTIPLE_SCATTERING": True},
        {"IBL_MODE": 2, "MULTIPLE_SCATTERING": True},
        *({"DEBUG_VIEW": view} for view in range(1, 6)),
    ):
        cache.get("common/fullscreen.vert.glsl", "shade/shade_pbr.frag.glsl", defines)
    for filter_id in (0, 1, 2):
        for kernel_size in (0, 1):
            cache.get(
                "common/fullscreen.vert.glsl",
                "smooth/smooth_depth.frag.glsl",
                {"FILTER": filter_id, "KERNEL_SIZE": kernel_size},
            )
            for axis in (0, 1):
                cache.get(
                    "common/fullscreen.vert.glsl",
                    "smooth/smooth_depth_separable.frag.glsl",
                    {"FILTER": filter_id, "KERNEL_SIZE": kernel_size, "AXIS": axis},
                )
    cache.get("common/fullscreen.vert.glsl", "common/image_pack.frag.glsl")
    cache.get("common/fullscreen.vert.glsl", "common/image_unpack.frag.glsl")
    for axis in (0, 1):
        cache.get(
            "common/fullscreen.vert.glsl",
            "temperature/smooth_temperature.frag.glsl",
            {"AXIS": axis},
        )
    cache.release()


def test_samplers_are_bound_to_their_units_when_built(
    tmp_path: Path, gl_context: GLContext
) -> None:
    """`samplers` points each sampler at its unit once, at build; later gets (which skip it)
    find the program still reading the right textures."""
    (tmp_path / "two.frag.glsl").write_text(
        "#version 330 core\nuniform sampler2D u_first;\nuniform sampler2D u_second;\n"
        "out vec4 colour;\nvoid main() {\n"
        "    colour = vec4(texture(u_first, vec2(0.5)).r, texture(u_second, vec2(0.5)).r, 0, 1);\n"
        "}\n"
    )
    (tmp_path / "tri.vert.glsl").write_text(
        "#version 330 core\nvoid main() {\n"
        "    vec2 p = vec2(gl_VertexID == 1 ? 3.0 : -1.0, gl_VertexID == 2 ? 3.0 : -1.0);\n"
        "    gl_Position = vec4(p, 0.0, 1.0);\n}\n"
    )
    ctx = gl_context.ctx
    cache = ProgramCache(gl_context, ShaderLoader(tmp_path))
    units = {"u_first": 2, "u_second": 1}
    textures = [
        ctx.texture((1, 1), 1, np.array([v], np.float32).tobytes(), dtype="f4") for v in (7, 5, 3)
    ]
    target = ctx.texture((1, 1), 4, dtype="f4")
    fbo = ctx.framebuffer([target])
    try:
        for unit, texture in enumerate(textures):
            texture.use(unit)
        program = cache.get("tri.vert.glsl", "two.frag.glsl", None, units)
        assert cache.get("tri.vert.glsl", "two.frag.glsl", None, units) is program
        vao = ctx.vertex_array(program, [])
        fbo.use()
        vao.render(moderngl.TRIANGLES, vertices=3)
        pixel = np.frombuffer(fbo.read(components=4, dtype="f4"), np.float32)
        assert pixel[:2].tolist() == [3.0, 5.0]  # unit 2 holds 3, unit 1 holds 5
        vao.release()
    finally:
        fbo.release()
        target.release()
        for texture in textures:
            texture.release()
        cache.release()
