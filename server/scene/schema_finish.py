"""The scene's `[finish]` section: how the workpiece's surface was worked. An anisotropic GGX
lobe (brushed metal: smooth along the brush strokes, rough across them), a procedural surface
detail fixed in world space (grinding grooves along the same brush direction) and detail from an
image file (a height map tiled over the faces, plus an optional roughness map). Part of the
scene schema (`schema.py` re-exports it); all are off by default and cost nothing then.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from sphrender.core.errors import InputError
from sphrender.server.scene.fields import Vec3, spec

DetailPattern = Literal["none", "brushed"]


@dataclass(frozen=True)
class FinishConfig:
    """Brushed finish and world-space surface detail of the material."""

    anisotropy: float = spec(
        0.0,
        "brushed lobe: GGX alpha along the brush = alpha (1 - a), across = alpha (1 + a), both "
        "clamped to [0.002, 1]; 0 = isotropic, < 0 swaps the axes. No preset sets it; for "
        "brushed or ground metal",
        low=-1.0,
        high=1.0,
    )
    brush_direction: Vec3 = spec(
        (1.0, 0.0, 0.0),
        "world direction of the brush strokes (components in [-1, 1], not all 0), projected "
        "onto each surface point's tangent plane; along the normal the lobe turns isotropic. "
        "No preset sets it",
        low=-1.0,
        high=1.0,
    )
    detail: DetailPattern = spec(
        "none",
        "surface detail fixed in world space: none, or brushed (grooves along brush_direction "
        "tilting the normal and varying the roughness). No preset sets it; for worked plates",
    )
    detail_scale: float = spec(
        0.01,
        "width of the finest grooves; coarser octaves are 2x and 4x that, and grooves run about "
        "40x their width along the brush. No preset sets it; match the workpiece's scale",
        low=0.0,
        low_open=True,
        unit="scene units",
    )
    detail_normal_strength: float = spec(
        0.15,
        "typical slope of the grooves (tangent of the normal's tilt); 0 leaves normals alone. "
        "No preset sets it; raise for coarse grinding, lower for fine brushing",
        low=0.0,
        high=1.0,
    )
    detail_roughness_strength: float = spec(
        0.0,
        "how far the grooves move roughness, up in their troughs and down on their crests "
        "(roughness units, clamped to [0, 1]). No preset sets it; for a patchy satin look",
        low=0.0,
        high=1.0,
    )

    detail_image: str | None = spec(
        None,
        "height map (1 channel; a 2nd channel is a roughness map) tiled in world space over the "
        "faces, read with OpenImageIO, relative to one of the server's environment directories, "
        "at most 2048 px a side. No preset sets it; for scratches, grinding marks, mill scale",
    )
    detail_image_size: float = spec(
        0.05,
        "world size of one tile of detail_image (both sides), at least 1e-6. No preset sets "
        "it; match the marks' size on the workpiece",
        low=1e-6,
        unit="scene units",
    )
    detail_image_depth: float = spec(
        0.0005,
        "height between detail_image values 0 and 1; the normals tilt by the slope this gives. "
        "No preset sets it; raise for deep marks, 0 leaves normals alone",
        low=0.0,
        high=1e6,
        unit="scene units",
    )
    detail_image_roughness: float = spec(
        0.0,
        "how far detail_image moves roughness: + this x (2 g - 1), g its 2nd channel or else 1 - "
        "height (rougher in the troughs); clamped to [0, 1]. No preset sets it; for patchy scale",
        low=0.0,
        high=1.0,
    )


def check_finish(finish: FinishConfig) -> None:
    """The rules across the section's fields: a brush direction must have a length; an image
    name must not be blank."""
    length = math.sqrt(sum(c * c for c in finish.brush_direction))
    if not length > 0.0:
        raise InputError("finish.brush_direction", "must not be the zero vector")
    if finish.detail_image is not None and not finish.detail_image.strip():
        raise InputError("finish.detail_image", "must not be empty")
