"""Scene mappings laid over each other: a quality preset under a scene (`preset_sections`), a
per-frame partial scene over a session's (`merge_scene_dicts`). Plain mappings, no `Scene`, so
validation can lay a scene's own ``quality.preset`` under it."""

from __future__ import annotations

import copy
import tomllib
from collections.abc import Mapping
from importlib import resources
from typing import Any

from sphrender.core.errors import InputError, show

#: The quality presets, `configs/quality-<name>.toml`.
PRESETS = ("fast", "balanced", "best")


def preset_sections(name: str) -> dict[str, Any]:
    """The preset's sections as a mapping (InputError naming `quality` for an unknown name)."""
    if name not in PRESETS:
        raise InputError("quality", f"must be one of {', '.join(PRESETS)}, got {show(name)}")
    text = resources.files("sphrender.configs").joinpath(f"quality-{name}.toml").read_text()
    return tomllib.loads(text)


def merge_scene_dicts(base: Mapping[str, Any], top: Mapping[str, Any]) -> dict[str, Any]:
    """`top` laid over `base` (neither is modified): tables merge key by key, anything else
    (values, the ``lights`` array) replaces the base's value. Used for quality presets under a
    scene file and for per-frame partial scenes over a session's scene."""
    merged = copy.deepcopy(dict(base))
    for key, value in top.items():
        current = merged.get(key)
        if isinstance(value, Mapping) and isinstance(current, Mapping):
            merged[key] = merge_scene_dicts(current, value)
        else:
            merged[key] = copy.deepcopy(value)
    return merged
