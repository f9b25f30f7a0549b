"""The scene's `[glare]` section: the eye's point-spread function applied to the exposed image
(server/engine/passes/glare.py). Part of the scene schema (`schema.py` re-exports it)."""

from __future__ import annotations

from dataclasses import dataclass

from sphrender.server.scene.fields import spec


@dataclass(frozen=True)
class GlareConfig:
    """Glare: light of very bright pixels spread by the eye's point-spread function."""

    enabled: bool = spec(
        False,
        "spread the exposed light above threshold through Spencer et al.'s 1995 photopic "
        "point-spread function (energy-conserving). No preset sets it; for arc and pool glare",
    )
    threshold: float = spec(
        1.0,
        "exposed luminance (after output.exposure; 1 = display white) above which light "
        "glares; 0 spreads the whole image as the eye does. No preset sets it; lower for more",
        low=0.0,
        unit="display-linear luminance",
    )
    exr: bool = spec(
        False,
        "apply the glare to the colour of exr and raw float outputs too (Z and N never). "
        "No preset sets it; for compositing a finished image",
    )
