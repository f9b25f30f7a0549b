"""Quality presets: `fast`, `balanced` (= the built-in defaults) and `best`.

Each preset is a scene TOML fragment shipped in `configs/quality-<name>.toml` holding only the
sections that trade speed against error ([quality], [shading], [sph]). A preset is the base a scene
file is laid over: keys the scene file sets win, so `--quality fast --scene my.toml` keeps
`my.toml`'s camera, material and any quality key it sets explicitly. The presets were chosen from
the benchmark's Pareto front (`sphrender bench`, see benchmarks/REPORT.md).
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any

from sphrender.client.errors import InputError
from sphrender.server.scene import Scene, read_scene_toml, scene_from_dict

PRESETS = ("fast", "balanced", "best")


def preset_sections(name: str) -> dict[str, Any]:
    """The preset's sections as a mapping (InputError naming `quality` for an unknown name)."""
    if name not in PRESETS:
        raise InputError("quality", f"must be one of {', '.join(PRESETS)}, got {name!r}")
    text = resources.files("sphrender.configs").joinpath(f"quality-{name}.toml").read_text()
    return tomllib.loads(text)


def merge_sections(base: Mapping[str, Any], top: Mapping[str, Any]) -> dict[str, Any]:
    """`top` laid over `base`: tables merge key by key, anything else (values, the [[lights]]
    list) is replaced whole."""
    merged: dict[str, Any] = {key: value for key, value in base.items()}
    for key, value in top.items():
        if isinstance(value, Mapping) and isinstance(merged.get(key), Mapping):
            merged[key] = merge_sections(merged[key], value)
        else:
            merged[key] = value
    return merged


def load_scene_with_preset(path: str | Path | None, preset: str | None) -> Scene:
    """The scene file (or the defaults) laid over the preset (or nothing)."""
    data: dict[str, Any] = preset_sections(preset) if preset else {}
    if path is not None:
        data = merge_sections(data, read_scene_toml(path))
    return scene_from_dict(data)
