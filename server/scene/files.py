"""Scene files and scene mappings: TOML reading and layering (presets, per-frame partial
scenes); the way back from a `Scene` to a mapping is `export.scene_to_dict`."""

from __future__ import annotations

import copy
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from sphrender.core.errors import InputError
from sphrender.server.scene.schema import Scene
from sphrender.server.scene.validate import scene_from_dict


def read_scene_toml(path: str | Path) -> dict[str, Any]:
    """A scene TOML file as a mapping, unvalidated; unreadable or malformed files raise
    `InputError('scene', ...)`."""
    try:
        with open(path, "rb") as handle:
            return tomllib.load(handle)
    except OSError as exc:
        raise InputError("scene", f"cannot read {path}: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError("scene", f"{path} is not valid TOML: {exc}") from None


def load_scene(path: str | Path) -> Scene:
    """Load and validate a scene TOML file (see `read_scene_toml` for file errors)."""
    return scene_from_dict(read_scene_toml(path))


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
