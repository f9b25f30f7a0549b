"""The shade pass's hot-metal resources: heat tint and molten metal (`shaders/lighting/
thin_film.glsl`, tables from `lighting/thin_film.py`, constants from `lighting/materials.py`).

Owned by `ShadePass`, on the GL owner thread. Only a frame with temperatures whose material asks
for `heat_tint` or `molten` uses any of it: the defines are 0 otherwise and the shader is the
one it was without them. Owns the film tables (RGBA32F, one per substrate F0 and film index).
"""

from __future__ import annotations

import moderngl

from sphrender.server.engine.lighting.materials import LIQUID_F0, LIQUID_ROUGHNESS, Material
from sphrender.server.engine.lighting.thin_film import (
    FILM_MAX_NM,
    OXIDE_REFERENCE_NM,
    FilmSpec,
    film_spec,
    film_table,
)
from sphrender.server.engine.passes.context import PassContext
from sphrender.server.scene import MaterialConfig


def heat_defines(material: MaterialConfig, has_temperature: bool) -> dict[str, bool]:
    """HEAT_TINT and MOLTEN of the shade shader: on only with temperatures to read."""
    return {
        "HEAT_TINT": has_temperature and material.heat_tint,
        "MOLTEN": has_temperature and material.molten,
    }


def heat_uniforms(material: Material) -> dict[str, object]:
    """The hot-metal uniforms (a variant without them drops them: set_if_used skips those)."""
    return {
        "u_film_max_nm": FILM_MAX_NM,
        "u_oxide_calibration": material.oxide_calibration,
        "u_oxide_reference_nm": OXIDE_REFERENCE_NM,
        "u_melting_range": (material.solidus_k, material.liquidus_k),
        "u_liquid_f0": LIQUID_F0,
        "u_liquid_roughness": LIQUID_ROUGHNESS,
    }


class FilmTables:
    """The film reflectance tables as textures, built on first use per `FilmSpec`."""

    def __init__(self, context: PassContext) -> None:
        self._context = context
        self._textures: dict[FilmSpec, moderngl.Texture] = {}

    def texture(self, material: Material) -> moderngl.Texture:
        spec = film_spec(material.preset, material.specular_f0)
        texture = self._textures.get(spec)
        if texture is None:
            table = film_table(spec)
            texture = self._context.gl.ctx.texture(
                (table.shape[1], table.shape[0]), 4, table.tobytes(), dtype="f4"
            )
            texture.filter = (moderngl.LINEAR, moderngl.LINEAR)
            texture.repeat_x = texture.repeat_y = False
            self._textures[spec] = texture
        return texture

    def release(self) -> None:
        for texture in self._textures.values():
            texture.release()
        self._textures.clear()
