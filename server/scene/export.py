"""The way back from a validated `Scene` to a plain, JSON-safe mapping.

`scene_to_dict` is what the service answers with (``POST /v1/sessions`` returns the resolved
scene: every default filled in), what ``sphrender submit`` sends, and what `scene_from_dict`
reads back unchanged (``scene_from_dict(scene_to_dict(s)) == s``).
"""

from __future__ import annotations

from dataclasses import fields
from typing import Any

from sphrender.server.scene.fields import is_bench_only
from sphrender.server.scene.schema import Scene, scene_sections


def _json_value(value: Any) -> Any:
    return [_json_value(v) for v in value] if isinstance(value, tuple) else value


def _table(section: Any) -> dict[str, Any]:
    return {
        f.name: _json_value(value)
        for f in fields(section)
        if (value := getattr(section, f.name)) is not None and not is_bench_only(f)
    }


def scene_to_dict(scene: Scene) -> dict[str, Any]:
    """Every section and field of `scene` as JSON types (tuples become lists), defaults filled
    in. Fields whose value is absent (`None`: e.g. ``camera.far``, ``sph.mass``, the material
    overrides) are left out, as the TOML files leave them out: absence is their default, and
    the result stays valid TOML as well as JSON. ``lights`` is always present (``[]``). The
    benchmark's own settings (`fields.bench_spec`) and the scene's notes are left out."""
    out: dict[str, Any] = {}
    for section in scene_sections():
        value = getattr(scene, section.name)
        if isinstance(value, tuple):
            out[section.name] = [_table(item) for item in value]
        else:
            out[section.name] = _table(value)
    return out
