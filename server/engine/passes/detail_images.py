"""The detail pass's image textures (`[finish] detail_image`): each file's texels
(`lighting/detail_image.py`) as an RGBA16F texture that repeats, with mipmaps (the shader picks
the level from the pixel's footprint), and the scale of its slopes. Cached by (resolved path,
size, mtime): an unchanged file is read and uploaded once, a changed one again; the least
recently used beyond `CACHE_SIZE` are released. Owned by the surface-detail pass, on the GL
owner thread.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import moderngl

from sphrender.server.engine.lighting.detail_image import find_detail_image, read_detail_image
from sphrender.server.engine.lighting.environment import FileCache
from sphrender.server.engine.passes.context import PassContext

#: Image textures kept (a scene rarely names more than one; a changed file is a new entry).
CACHE_SIZE = 2


@dataclass(frozen=True)
class DetailTexture:
    texture: moderngl.Texture
    #: The texels' slopes times this are d height / d (tile coordinate).
    slope_scale: float


class DetailImages:
    def __init__(self, context: PassContext, directories: Sequence[str | Path] = ()) -> None:
        self._context = context
        self._directories = tuple(Path(d).resolve() for d in directories)
        self._textures: FileCache[DetailTexture] = FileCache(
            CACHE_SIZE, lambda entry: entry.texture.release()
        )

    def texture(self, name: str) -> DetailTexture:
        """The texture of the file `name` (relative to the environment directories)."""
        return self._textures.get(find_detail_image(self._directories, name), self._upload)

    def _upload(self, path: Path) -> DetailTexture:
        texels = read_detail_image(path)
        texture = self._context.gl.ctx.texture(texels.size, 4, texels.texels.tobytes(), dtype="f2")
        texture.repeat_x = texture.repeat_y = True
        texture.build_mipmaps()
        texture.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        return DetailTexture(texture, texels.slope_scale)

    def release(self) -> None:
        for entry in self._textures:
            entry.texture.release()
        self._textures.clear()
