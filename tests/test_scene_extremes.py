"""Every scene number the schema leaves unbounded above, set to an extreme a client may send
(1e308, -1e308, just past float32's range, tiny), is either refused naming its field or warms
and renders a finite image: a scene the validator accepts must never fail the render (a session
warm-up that fails answers HTTP 500, not 400). The fields come from the JSON Schema, so a new
field is covered without editing this test."""

from __future__ import annotations

import copy
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from sphrender.core.errors import InputError
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.output.local import encode_for_scene, render_for_output
from sphrender.server.scene.json_schema import scene_json_schema
from sphrender.server.scene.validate import scene_from_dict
from sphrender.server.service.render.warmup import warm_frames

BASE: dict[str, Any] = {
    "image": {"width": 32, "height": 24},
    "camera": {"eye": [0.6, 0.5, 0.9], "target": [0.0, 0.0, 0.0], "fov_y": 40.0},
    "particles": {"radius": 0.02},
}
#: What a section needs beside the field for the field to be used at all.
CONTEXT: dict[str, dict[str, Any]] = {
    "lights": {"lights": [{"type": "point", "position": [0.3, 0.5, 0.3], "shadows": True}]},
    "quality": {"quality": {"filter": "gaussian"}},
    "glare": {"glare": {"enabled": True}},
    "finish": {"finish": {"detail": "brushed", "anisotropy": 0.5}},
}
EXTREMES = (1e308, -1e308, 3.5e38, 1e30, 1e-308, 1e-40)


def _unbounded_numbers() -> Iterator[tuple[str, bool]]:
    """(dotted path, is a 3-vector) of every number without a maximum in the scene schema."""
    schema = scene_json_schema()
    defs = schema["$defs"]

    def resolve(node: dict[str, Any]) -> dict[str, Any]:
        while "$ref" in node:
            node = defs[node["$ref"].split("/")[-1]]
        return node

    def walk(node: dict[str, Any], path: tuple[str, ...]) -> Iterator[tuple[str, bool]]:
        node = resolve(node)
        for option in node.get("anyOf", []):
            yield from walk(option, path)
        for key, child in node.get("properties", {}).items():
            yield from walk(child, (*path, key))
        kind = node.get("type")
        vector = kind == "array" and resolve(node.get("items", {})).get("type") == "number"
        leaf = resolve(node.get("items", {})) if vector else node
        if kind == "array" and not vector and "items" in node:
            yield from walk(node["items"], (*path, "0"))
        if (kind == "number" or vector) and not {"maximum", "exclusiveMaximum"} & set(leaf):
            yield ".".join(path), vector

    yield from sorted(set(walk(schema, ())))


def _scene_with(path: str, vector: bool, value: float) -> dict[str, Any]:
    keys = path.split(".")
    scene = copy.deepcopy(BASE)
    scene.update(copy.deepcopy(CONTEXT.get(keys[0], {})))
    if keys[:3] == ["lights", "0", "direction"]:
        scene["lights"] = [{"type": "directional", "direction": [0.0, -1.0, 0.0]}]
    node: Any = scene
    for key in keys[:-1]:
        node = node[int(key)] if key.isdigit() else node.setdefault(key, {})
    if vector:
        current = list(node.get(keys[-1], [0.3, 0.5, 0.3]))
        current[0] = value
        node[keys[-1]] = current
    else:
        node[keys[-1]] = value
    return scene


FIELDS = list(_unbounded_numbers())


def test_the_schema_walk_finds_the_fields_this_test_is_for() -> None:
    paths = {path for path, _ in FIELDS}
    assert {"camera.eye", "lights.0.position", "glare.threshold", "sph.mass"} <= paths


@pytest.mark.parametrize(("path", "vector"), FIELDS, ids=[p for p, _ in FIELDS])
def test_extreme_values_are_refused_or_render_finite(
    renderer: SurfaceRenderer, path: str, vector: bool
) -> None:
    for value in EXTREMES:
        try:
            scene = scene_from_dict(_scene_with(path, vector, value))
        except InputError as exc:
            assert exc.field.startswith(path.split(".")[0]), (path, value, exc.field)
            continue
        for frame in warm_frames(scene):
            try:
                rendered, _ = render_for_output(renderer, frame, scene, "exr")
            except InputError:
                continue  # a clear error about the frame in this scene: fine
            assert np.isfinite(rendered.rgba).all(), (path, value)
            encode_for_scene(rendered, scene, "png")
