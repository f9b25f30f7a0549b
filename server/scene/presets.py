"""Quality presets: `fast`, `balanced` (= the built-in defaults) and `best`.

Each preset is a scene TOML fragment shipped in `configs/quality-<name>.toml` holding only the
sections that trade speed against error ([quality], [shading], [sph]). A preset is the base a scene
file is laid over: keys the scene file sets win, so `--quality fast --scene my.toml` keeps
`my.toml`'s camera, material and any quality key it sets explicitly. The presets were chosen from
the benchmark's Pareto front (`sphrender bench`, see benchmarks/REPORT.md).
"""

from __future__ import annotations

import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

from sphrender.core.errors import InputError, show
from sphrender.server.scene import Scene, merge_scene_dicts, read_scene_toml, scene_from_dict

PRESETS = ("fast", "balanced", "best")


def preset_sections(name: str) -> dict[str, Any]:
    """The preset's sections as a mapping (InputError naming `quality` for an unknown name)."""
    if name not in PRESETS:
        raise InputError("quality", f"must be one of {', '.join(PRESETS)}, got {show(name)}")
    text = resources.files("sphrender.configs").joinpath(f"quality-{name}.toml").read_text()
    return tomllib.loads(text)


def load_scene_with_preset(path: str | Path | None, preset: str | None) -> Scene:
    """The scene file (or the defaults) laid over the preset (or the file's own
    ``quality.preset``, which `preset` replaces)."""
    data: dict[str, Any] = {} if path is None else read_scene_toml(path)
    if preset:
        preset_sections(preset)  # an unknown name is refused naming `quality`, as before
        data = merge_scene_dicts(data, {"quality": {"preset": preset}})
    return scene_from_dict(data)
