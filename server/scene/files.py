"""Scene files and scene mappings: TOML reading, layering (presets, per-frame partial
scenes) and the way back from a `Scene` to a plain mapping."""

from __future__ import annotations

import copy
import tomllib
from collections.abc import Mapping
from dataclasses import fields
from pathlib import Path
from typing import Any

from sphrender.client.errors import InputError
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


def scene_to_dict(scene: Scene) -> dict[str, Any]:
    """The scene as a plain mapping (for JSON over the wire and for `scene_from_dict`)."""

    def table(value: Any) -> dict[str, Any]:
        return {
            f.name: list(v) if isinstance(v := getattr(value, f.name), tuple) else v
            for f in fields(value)
            if getattr(value, f.name) is not None
        }

    out: dict[str, Any] = {}
    for section in fields(Scene):
        value = getattr(scene, section.name)
        if isinstance(value, tuple):
            out[section.name] = [table(item) for item in value]
        else:
            out[section.name] = table(value)
    return out
