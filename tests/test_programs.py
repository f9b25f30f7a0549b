"""GLSL compile errors name the original file and line (real GL compiler)."""

from __future__ import annotations

from pathlib import Path

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
