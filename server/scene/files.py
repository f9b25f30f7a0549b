"""Scene files and scene mappings: TOML reading and layering (presets, per-frame partial
scenes); the way back from a `Scene` to a mapping is `export.scene_to_dict`."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from sphrender.core.errors import InputError
from sphrender.server.scene.layering import merge_scene_dicts
from sphrender.server.scene.schema import Scene
from sphrender.server.scene.validate import scene_from_dict

__all__ = ["load_scene", "merge_scene_dicts", "read_scene_toml"]


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
