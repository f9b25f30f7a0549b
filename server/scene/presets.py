"""Quality presets: `fast`, `balanced` (= the built-in defaults) and `best`.

Each preset is a scene TOML fragment shipped in `configs/quality-<name>.toml` holding only the
sections that trade speed against error ([quality], [shading], [sph]). A preset is the base a scene
file is laid over: keys the scene file sets win, so `--quality fast --scene my.toml` keeps
`my.toml`'s camera, material and any quality key it sets explicitly. The presets were chosen from
the benchmark's Pareto front (`sphrender bench`, see benchmarks/REPORT.md). A scene's own
``quality.preset`` is laid under it the same way by validation (`layering.py`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from sphrender.server.scene import Scene, merge_scene_dicts, read_scene_toml, scene_from_dict
from sphrender.server.scene.layering import PRESETS, preset_sections

__all__ = ["PRESETS", "load_scene_with_preset", "preset_sections"]


def load_scene_with_preset(path: str | Path | None, preset: str | None) -> Scene:
    """The scene file (or the defaults) laid over the preset (or the file's own
    ``quality.preset``, which `preset` replaces)."""
    data: dict[str, Any] = {} if path is None else read_scene_toml(path)
    if preset:
        preset_sections(preset)  # an unknown name is refused naming `quality`, as before
        data = merge_scene_dicts(data, {"quality": {"preset": preset}})
    return scene_from_dict(data)
