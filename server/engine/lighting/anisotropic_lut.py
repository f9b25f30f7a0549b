"""The anisotropic GGX lobe's split-sum table: the directional albedo's scale and bias (A, B)
for F0, as the isotropic BRDF table (`ibl.py`) but over (sqrt(n.v), the view's azimuth from the
brush folded to [0, pi/2] at cosine spacing, sqrt(alpha_t), sqrt(alpha_b)), so the prefiltered
IBL and the multiple-scattering compensation follow the brushed lobe's albedo, which the
isotropic table at any single roughness cannot.

`lighting/anisotropic_lut.frag.glsl` integrates every entry into a 2-D atlas, read back once
into an RG16F 3-D texture (32 x 24 x 16^2); `lighting/anisotropic_albedo.glsl` reads it
(hardware trilinear over the first three axes, two fetches over the fourth). Built on first use
per G term and kept by `AnisotropicLut`, owned by the shade pass on the GL owner thread. Its
accuracy and cost: benchmarks/STUDIES.md; it is least accurate next to the horizon.
"""

from __future__ import annotations

import moderngl
import numpy as np

from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.gpu.programs import ProgramCache

#: Texels along sqrt(n.v), the view azimuth, and each of sqrt(alpha_t), sqrt(alpha_b).
NV_SIZE = 32
PHI_SIZE = 24
ROUGH_SIZE = 16
#: Gauss-Legendre nodes (and midpoint-rule steps) per axis of the sampling map.
NODES = 32
_G_TERM_DEFINES = {"smith_height_correlated": 0, "cook_torrance": 1}


class AnisotropicLut:
    """The anisotropic split-sum tables by G term, built on first use."""

    def __init__(self, gl: GLContext, programs: ProgramCache) -> None:
        self._gl = gl
        self._programs = programs
        self._tables: dict[str, moderngl.Texture3D] = {}

    def texture(self, g_term: str) -> moderngl.Texture3D:
        table = self._tables.get(g_term)
        if table is None:
            table = self._build(g_term)
            self._tables[g_term] = table
        return table

    def _build(self, g_term: str) -> moderngl.Texture3D:
        ctx = self._gl.ctx
        atlas_size = (NV_SIZE * PHI_SIZE, ROUGH_SIZE * ROUGH_SIZE)
        program = self._programs.get(
            "common/fullscreen.vert.glsl",
            "lighting/anisotropic_lut.frag.glsl",
            {
                "G_TERM": _G_TERM_DEFINES[g_term],
                "NV": NV_SIZE,
                "PHI": PHI_SIZE,
                "ROUGH": ROUGH_SIZE,
                "NODES": NODES,
            },
        )
        nodes, weights = np.polynomial.legendre.leggauss(NODES)
        program["u_nodes"].write(((nodes + 1.0) * 0.5).astype(np.float32).tobytes())  # type: ignore[union-attr]
        program["u_weights"].write((weights * 0.5).astype(np.float32).tobytes())  # type: ignore[union-attr]
        atlas = ctx.texture(atlas_size, 2, dtype="f4")
        fbo = ctx.framebuffer([atlas])
        vao = ctx.vertex_array(program, [])
        try:
            fbo.use()
            vao.render(moderngl.TRIANGLES, vertices=3)
            data = np.frombuffer(fbo.read(components=2, dtype="f4"), np.float32)
        finally:
            vao.release()
            fbo.release()
            atlas.release()
        # Atlas rows are (i_t + ROUGH i_b), columns (i_nv + NV i_phi): already the 3-D
        # texture's (depth, height, width) order.
        table = ctx.texture3d(
            (NV_SIZE, PHI_SIZE, ROUGH_SIZE * ROUGH_SIZE),
            2,
            data.astype(np.float16).tobytes(),
            dtype="f2",
        )
        table.filter = (moderngl.LINEAR, moderngl.LINEAR)
        table.repeat_x = table.repeat_y = table.repeat_z = False
        return table

    def release(self) -> None:
        for table in self._tables.values():
            table.release()
        self._tables.clear()
