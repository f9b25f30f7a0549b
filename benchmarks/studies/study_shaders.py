"""The studies' GLSL (benchmarks/studies/shaders/) beside the product's: a shader root where the
product's folders and `studies/` sit side by side, so a study shader includes product code
(``#include "field/field_normals.glsl"``) exactly as a pass's shader does."""

from __future__ import annotations

import importlib.resources
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

#: The studies' shaders; named `studies/<file>` under `shader_root()`.
STUDY_SHADERS = Path(__file__).resolve().parent / "shaders"


@contextmanager
def shader_root() -> Iterator[Path]:
    """A temporary folder of links: every folder of `sphrender.shaders`, and `studies/`. Pass it
    to `ShaderLoader(root)`; it is removed when the block ends."""
    product = Path(str(importlib.resources.files("sphrender.shaders")))
    with tempfile.TemporaryDirectory(prefix="study-shaders-") as folder:
        root = Path(folder)
        for entry in product.iterdir():
            (root / entry.name).symlink_to(entry, target_is_directory=entry.is_dir())
        (root / "studies").symlink_to(STUDY_SHADERS, target_is_directory=True)
        yield root
