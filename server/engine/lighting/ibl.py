"""Image-based lighting resources, built once per environment (or per G term) and cached.

* SH9 radiance coefficients (thesis eq 47-48; Ramamoorthi & Hanrahan 2001): numpy, from the
  equirect pixels weighted by their exact solid angle. The shader turns them into irradiance with
  R&H's c1..c5 (`shaders/common/sh9.glsl`).
* Source texture: the equirect radiance as RGB32F with a box-filtered mip chain (fp32 because a
  1e5 sun overflows half). The per-pixel sampling mode and the background read it.
* Prefiltered chain: an RGB32F equirect whose mip level i holds the GGX-prefiltered environment
  for roughness i / (levels - 1) (`prefilter_ggx.frag.glsl`). moderngl cannot attach a mip level to
  a framebuffer, so each level is rendered into a scratch target and copied into its level.
* BRDF table: (n.v, roughness) -> (A, B) in RG16F, one per G term (`brdf_lut.frag.glsl`).

All of it lives in `IblCache`, owned by the renderer on the GL owner thread: environments are
kept by content key in a small LRU (evicted textures are released at once), so a scene that
reuses an environment never prefilters again and a frame never does.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field

import moderngl
import numpy as np
import numpy.typing as npt

from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.gpu.programs import ProgramCache
from sphrender.server.engine.lighting.environment import (
    EnvironmentImage,
    pixel_directions,
    pixel_solid_angles,
)

F64 = npt.NDArray[np.float64]

#: SH basis constants of thesis eq 43 (R&H 2001, eq 3).
SH_Y00 = 0.282095
SH_Y1 = 0.488603
SH_Y2_CROSS = 1.092548
SH_Y20 = 0.315392
SH_Y22 = 0.546274

#: Prefiltered levels: roughness 0, 0.2, ..., 1.0. Level 0 is the mirror image.
PREFILTER_LEVELS = 6
#: Width of the prefiltered chain's level 0 (clamped to a power of two between these).
PREFILTER_MIN_WIDTH = 64
PREFILTER_MAX_WIDTH = 512
#: BRDF table size (texels per axis) and Gauss-Legendre nodes per texel axis of its product
#: rule (brdf_lut.frag.glsl; the error budget is in tests/test_shading_ibl.py).
BRDF_LUT_SIZE = 64
BRDF_LUT_NODES = 64
_G_TERM_DEFINES = {"smith_height_correlated": 0, "cook_torrance": 1}


def sh9_basis(directions: F64) -> F64:
    """The 9 real SH basis functions (eq 43) at unit directions (..., 3) -> (..., 9), in the
    order L00, L1-1, L10, L11, L2-2, L2-1, L20, L21, L22."""
    x, y, z = directions[..., 0], directions[..., 1], directions[..., 2]
    return np.stack(
        [
            np.full_like(x, SH_Y00),
            SH_Y1 * y,
            SH_Y1 * z,
            SH_Y1 * x,
            SH_Y2_CROSS * x * y,
            SH_Y2_CROSS * y * z,
            SH_Y20 * (3.0 * z * z - 1.0),
            SH_Y2_CROSS * x * z,
            SH_Y22 * (x * x - y * y),
        ],
        axis=-1,
    )


def sh9_coefficients(pixels: npt.NDArray[np.floating]) -> F64:
    """L_lm (9, 3) of an equirect radiance image: eq 48, sum of L Y_lm dOmega over pixels, with
    each pixel's exact solid angle (rows near the poles are small)."""
    height, width = pixels.shape[:2]
    weights = pixel_solid_angles(height, width)  # (H, 1)
    coefficients = np.zeros((9, 3))
    # Row blocks keep the (rows, W, 9) basis array small for big images.
    block = max(1, 262144 // width)
    for start in range(0, height, block):
        stop = min(height, start + block)
        directions = pixel_directions(height, width)[start:stop]
        basis = sh9_basis(directions) * weights[start:stop, :, None]
        radiance = pixels[start:stop].astype(np.float64)
        coefficients += np.einsum("hwk,hwc->kc", basis, radiance)
    return coefficients


def sh9_irradiance(coefficients: F64, normals: F64) -> F64:
    """E(n) from L_lm with R&H's closed form (the shader's sh9.glsl, in numpy) -> (..., 3)."""
    c1, c2, c3, c4, c5 = 0.429043, 0.511664, 0.743125, 0.886227, 0.247708
    x, y, z = (normals[..., i, None] for i in range(3))
    sh = coefficients
    result: F64 = (
        c1 * sh[8] * (x * x - y * y)
        + c3 * sh[6] * z * z
        + c4 * sh[0]
        - c5 * sh[6]
        + 2.0 * c1 * (sh[4] * x * y + sh[7] * x * z + sh[5] * y * z)
        + 2.0 * c2 * (sh[3] * x + sh[1] * y + sh[2] * z)
    )
    return result


@dataclass
class EnvironmentTextures:
    """GPU side of one environment image."""

    key: str
    source: moderngl.Texture
    sh: F64  # (9, 3) radiance coefficients
    prefiltered: dict[int, moderngl.Texture] = field(default_factory=dict)  # by sample count

    @property
    def source_size(self) -> tuple[int, int]:
        return self.source.size

    def release(self) -> None:
        self.source.release()
        for texture in self.prefiltered.values():
            texture.release()
        self.prefiltered.clear()


def _equirect_texture(
    ctx: moderngl.Context, width: int, height: int, data: bytes | None = None
) -> moderngl.Texture:
    texture = ctx.texture((width, height), 3, data, dtype="f4")
    texture.repeat_x = True
    texture.repeat_y = False
    return texture


class IblCache:
    """Environment textures by content key (LRU of `capacity`) and BRDF tables by G term."""

    def __init__(self, gl: GLContext, programs: ProgramCache, capacity: int = 4) -> None:
        self._gl = gl
        self._programs = programs
        self._capacity = capacity
        self._environments: OrderedDict[str, EnvironmentTextures] = OrderedDict()
        self._luts: dict[str, moderngl.Texture] = {}
        self.prefilter_runs = 0  # how many chains were built (tests check caching with it)

    def environment(self, image: EnvironmentImage) -> EnvironmentTextures:
        entry = self._environments.get(image.key)
        if entry is not None:
            self._environments.move_to_end(image.key)
            return entry
        ctx = self._gl.ctx
        source = _equirect_texture(ctx, image.width, image.height, image.pixels.tobytes())
        source.build_mipmaps()
        source.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        entry = EnvironmentTextures(image.key, source, sh9_coefficients(image.pixels))
        self._environments[image.key] = entry
        while len(self._environments) > self._capacity:
            _, evicted = self._environments.popitem(last=False)
            evicted.release()
        return entry

    def prefiltered(self, entry: EnvironmentTextures, samples: int) -> moderngl.Texture:
        texture = entry.prefiltered.get(samples)
        if texture is None:
            texture = self._prefilter(entry, samples)
            entry.prefiltered[samples] = texture
        return texture

    def _prefilter(self, entry: EnvironmentTextures, samples: int) -> moderngl.Texture:
        ctx = self._gl.ctx
        source_width, source_height = entry.source_size
        width = PREFILTER_MIN_WIDTH
        while width * 2 <= min(source_width, PREFILTER_MAX_WIDTH):
            width *= 2
        height = width // 2
        result = _equirect_texture(ctx, width, height)
        result.build_mipmaps(0, PREFILTER_LEVELS - 1)  # allocates levels 1..; overwritten below
        program = self._programs.get(
            "common/fullscreen.vert.glsl", "lighting/prefilter_ggx.frag.glsl"
        )
        vao = ctx.vertex_array(program, [])
        entry.source.use(0)
        program["u_source"] = 0
        program["u_source_size"] = (float(source_width), float(source_height))
        try:
            for level in range(PREFILTER_LEVELS):
                size = (max(width >> level, 1), max(height >> level, 1))
                scratch = ctx.texture(size, 3, dtype="f4")
                fbo = ctx.framebuffer([scratch])
                try:
                    fbo.use()
                    program["u_target_size"] = (float(size[0]), float(size[1]))
                    program["u_roughness"] = level / (PREFILTER_LEVELS - 1)
                    program["u_samples"] = samples
                    vao.render(moderngl.TRIANGLES, vertices=3)
                    result.write(scratch.read(), level=level)
                finally:
                    fbo.release()
                    scratch.release()
        finally:
            vao.release()
        result.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        self.prefilter_runs += 1
        return result

    def brdf_lut(self, g_term: str) -> moderngl.Texture:
        lut = self._luts.get(g_term)
        if lut is None:
            lut = self._build_lut(g_term)
            self._luts[g_term] = lut
        return lut

    def _build_lut(self, g_term: str) -> moderngl.Texture:
        ctx = self._gl.ctx
        size = (BRDF_LUT_SIZE, BRDF_LUT_SIZE)
        lut = ctx.texture(size, 2, dtype="f2")
        lut.filter = (moderngl.LINEAR, moderngl.LINEAR)
        lut.repeat_x = lut.repeat_y = False
        program = self._programs.get(
            "common/fullscreen.vert.glsl",
            "lighting/brdf_lut.frag.glsl",
            {"G_TERM": _G_TERM_DEFINES[g_term], "NODES": BRDF_LUT_NODES},
        )
        fbo = ctx.framebuffer([lut])
        vao = ctx.vertex_array(program, [])
        try:
            fbo.use()
            program["u_size"] = (float(size[0]), float(size[1]))
            nodes, weights = np.polynomial.legendre.leggauss(BRDF_LUT_NODES)
            program["u_nodes"].write(((nodes + 1.0) * 0.5).astype(np.float32).tobytes())  # type: ignore[union-attr]
            program["u_weights"].write((weights * 0.5).astype(np.float32).tobytes())  # type: ignore[union-attr]
            vao.render(moderngl.TRIANGLES, vertices=3)
        finally:
            vao.release()
            fbo.release()
        return lut

    def release(self) -> None:
        for entry in self._environments.values():
            entry.release()
        self._environments.clear()
        for lut in self._luts.values():
            lut.release()
        self._luts.clear()
