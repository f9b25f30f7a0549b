"""The scene's `[solids]` section: which particles are a solid workpiece, drawn with flat faces
and sharp edges instead of the fluid's smoothed surface. Part of the scene schema (`schema.py`
re-exports it); every field typed and documented here.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from sphrender.server.scene.fields import spec

SolidSource = Literal["flag", "temperature", "none"]


@dataclass(frozen=True)
class SolidsConfig:
    """Solid workpieces among the particles (plates, joints): told apart per particle."""

    source: SolidSource = spec(
        "flag",
        "which particles are solid: flag = the frame's `solid` array (when it carries one), "
        "temperature = below the material's solidus (frames with temperatures), none = all "
        "fluid. No preset sets it; temperature for a simulation with no flag",
    )
