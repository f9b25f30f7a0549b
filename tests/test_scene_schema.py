"""The scene's JSON Schema (schema/scene.schema.json): current, valid, and in agreement with the
server's own validator (`scene_from_dict`) on a generated set of good and bad scenes.

The cases are generated from the dataclasses' metadata, per field: the default, each bound and
the nearest float beyond it (`math.nextafter`: the exact edge, no tolerance), integers one past a
bound, wrong types, null, unknown keys, and per section: not a table, unknown key; plus the
rules that span fields. The only cases allowed to disagree are the ones `CROSS_FIELD_RULES`
names (rules JSON Schema cannot express), and each of those must really disagree, so the list
can neither hide a new disagreement nor keep a stale entry.
"""

from __future__ import annotations

import json
import math
import tomllib
import types
import typing
from collections.abc import Iterator
from dataclasses import MISSING, fields
from pathlib import Path
from typing import Any, Literal, get_args, get_origin

import pytest
from cli_harness import run_sphrender
from jsonschema import Draft202012Validator
from jsonschema.exceptions import best_match

from sphrender.core.errors import InputError
from sphrender.server.scene import MAX_LIGHTS, Scene, Vec3, scene_from_dict, scene_to_dict
from sphrender.server.scene.fields import is_bench_only
from sphrender.server.scene.json_schema import (
    CROSS_FIELD_RULES,
    scene_json_schema,
    scene_json_schema_text,
)
from sphrender.server.scene.presets import PRESETS, preset_sections
from sphrender.server.scene.schema import scene_sections

REPO = Path(__file__).resolve().parents[1]
COMMITTED = REPO / "schema" / "scene.schema.json"
VALIDATOR = Draft202012Validator(scene_json_schema())

Case = tuple[str, dict[str, Any]]


def schema_accepts(data: Any) -> bool:
    return VALIDATOR.is_valid(data)


def server_accepts(data: Any) -> tuple[bool, str | None]:
    try:
        scene_from_dict(data)
    except InputError as exc:
        return False, exc.field
    return True, None


def test_the_committed_schema_is_the_generated_one() -> None:
    assert COMMITTED.read_text(encoding="utf-8") == scene_json_schema_text(), (
        "schema/scene.schema.json is stale: run `sphrender schema -o schema/scene.schema.json`"
    )


def test_the_cli_prints_the_same_document(tmp_path: Path) -> None:
    out = tmp_path / "s.json"
    result = run_sphrender("schema", "-o", str(out))
    assert result.returncode == 0, result.stderr
    assert out.read_text(encoding="utf-8") == scene_json_schema_text()


def test_the_schema_is_valid_2020_12_and_closed_everywhere() -> None:
    schema = scene_json_schema()
    Draft202012Validator.check_schema(schema)
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    objects = [s for s in _subschemas(schema) if s.get("type") == "object"]
    assert len(objects) == 1 + len(schema["$defs"])  # the scene and each section
    for sub in objects:
        assert sub.get("additionalProperties") is False, sub.get("description")


def test_every_field_has_its_type_documentation_default_and_range() -> None:
    schema = scene_json_schema()
    camera = schema["$defs"]["CameraConfig"]["properties"]
    assert camera["fov_y"]["exclusiveMinimum"] == 0.0 and camera["fov_y"]["exclusiveMaximum"] == 180
    assert camera["fov_y"]["x-unit"] == "degrees" and camera["fov_y"]["default"] == 45.0
    assert "vertical field of view" in camera["fov_y"]["description"]
    image = schema["$defs"]["ImageConfig"]["properties"]["width"]
    assert (image["type"], image["minimum"], image["maximum"]) == ("integer", 1, 16384)
    quality = schema["$defs"]["QualityConfig"]["properties"]["filter"]
    assert quality["enum"] == ["narrow_range", "bilateral", "gaussian", "none"]
    hints_by_section = {f.name: typing.get_type_hints(Scene)[f.name] for f in scene_sections()}
    assert set(schema["properties"]) == set(hints_by_section)
    for name, hint in hints_by_section.items():
        cls = get_args(hint)[0] if get_origin(hint) is tuple else hint
        props = schema["$defs"][cls.__name__]["properties"]
        users = [f for f in fields(cls) if not is_bench_only(f)]
        assert set(props) == {f.name for f in users}, name
        for f in users:
            assert props[f.name]["description"], f"{name}.{f.name}"
            if f.default is not MISSING:
                assert props[f.name]["default"] == _json(f.default), f"{name}.{f.name}"
    assert schema["properties"]["lights"]["maxItems"] == MAX_LIGHTS


def test_every_shipped_scene_is_valid() -> None:
    """configs/*.toml loaded as the product loads them (tomllib), and the presets laid under the
    demo as `--quality` does; server.toml is server settings, not a scene."""
    configs = sorted(p for p in (REPO / "configs").glob("*.toml") if p.name != "server.toml")
    assert len(configs) >= 4
    demo = tomllib.loads((REPO / "configs" / "demo.toml").read_text())
    scenes = [tomllib.loads(p.read_text()) for p in configs]
    scenes += [{**preset_sections(name), **demo} for name in PRESETS]
    for data in scenes:
        error = best_match(VALIDATOR.iter_errors(data))
        assert error is None, f"{error.json_path}: {error.message}"


def test_resolved_scenes_are_valid_and_complete() -> None:
    """`scene_to_dict` (what POST /v1/sessions answers) validates, and fills every field whose
    default is a value."""
    resolved = scene_to_dict(Scene())
    assert schema_accepts(resolved)
    assert resolved["camera"]["eye"] == [0.0, 1.0, 3.0] and "far" not in resolved["camera"]
    assert resolved["image"] == {"width": 640, "height": 360}
    json.dumps(resolved, allow_nan=False)


# -- the generated set ------------------------------------------------------------------------


def _json(value: Any) -> Any:
    return [_json(v) for v in value] if isinstance(value, tuple) else value


def _subschemas(node: Any) -> Iterator[dict[str, Any]]:
    if isinstance(node, dict):
        yield node
        for value in node.values():
            yield from _subschemas(value)
    elif isinstance(node, list):
        for value in node:
            yield from _subschemas(value)


def _edges(meta: typing.Mapping[str, Any], is_int: bool) -> Iterator[float]:
    """Each bound, and the nearest representable value beyond it, on either side."""
    for key, inward in (("low", math.inf), ("high", -math.inf)):
        bound = meta.get(key)
        if bound is None:
            continue
        yield bound
        if is_int:
            yield bound - 1 if key == "low" else bound + 1
            yield bound + 1 if key == "low" else bound - 1
        else:
            yield math.nextafter(bound, -inward)
            yield math.nextafter(bound, inward)


def _values(annotation: Any, meta: typing.Mapping[str, Any]) -> Iterator[Any]:
    """Good and bad values for one field of this annotation."""
    origin = get_origin(annotation)
    if origin is types.UnionType or origin is typing.Union:
        yield None
        yield from _values(next(a for a in get_args(annotation) if a is not type(None)), meta)
        return
    yield {"nested": 1}  # wrong type: a table
    if origin is Literal:
        allowed = get_args(annotation)
        yield from allowed
        yield "not-a-choice"
        yield True
        if isinstance(allowed[0], int) and not isinstance(allowed[0], bool):
            yield float(allowed[0])  # 8.0: JSON's one number type
            yield allowed[0] + 1
        return
    if annotation is str:
        yield from ("", "a.exr", "x" * 4096, "x" * 4097, "nul\x00byte", "   ", 3)
        return
    if annotation is bool:
        yield from (True, False, 1, "true", None)
        return
    if annotation in (int, float):
        yield from (True, "1", [1], None)
        yield from _edges(meta, annotation is int)
        if annotation is int:
            low = meta.get("low") or 0
            yield float(low + 1)  # an integral float is the integer
            yield low + 1.5
        return
    if annotation == Vec3:
        for edge in _edges(meta, False):
            yield [edge, edge, edge]
            yield [0.5, edge, 0.5] if edge != 0 else [0.5, 0.0, 0.5]
        yield from ([1.0, 2.0], [1.0, 2.0, 3.0, 4.0], [1.0, "2", 3.0], [1.0, None, 3.0], 1.0)
        yield from ([0, 0, 0], [0.0, 1.0, 0.0], [0.0, -1.0, 2.5], [-0.0, 0.0, 0.0])
        return
    if origin is tuple:
        (item,) = get_args(annotation)[:1]
        yield from ([], list(get_args(item)), list(get_args(item)[:1]) * 2, ["nope"], "Z")
        return
    raise TypeError(annotation)


#: A valid light of each type, so a light field's cases test that field.
POINT = {"type": "point", "position": [1.0, 2.0, 3.0]}
DIRECTIONAL = {"type": "directional", "direction": [0.0, -1.0, 0.0]}


def field_cases() -> Iterator[Case]:
    hints = typing.get_type_hints(Scene)
    for section in scene_sections():
        hint = hints[section.name]
        listed = get_origin(hint) is tuple
        cls = get_args(hint)[0] if listed else hint
        yield f"{section.name}: not a table", {section.name: "big" if not listed else {"a": 1}}
        yield (
            f"{section.name}: unknown key",
            (
                {section.name: [{**DIRECTIONAL, "colour": [1, 1, 1]}]}
                if listed
                else {section.name: {"colour": 1}}
            ),
        )
        yield f"{section.name}: empty", {section.name: [] if listed else {}}
        cls_hints = typing.get_type_hints(cls)
        for f in fields(cls):
            for value in _values(cls_hints[f.name], f.metadata):
                label = f"{section.name}.{f.name} = {value!r:.40}"
                if listed:
                    base = dict(POINT if f.name == "position" else DIRECTIONAL)
                    yield label, {section.name: [{**base, f.name: value}]}
                else:
                    yield label, {section.name: {f.name: value}}
    yield "unknown section", {"imag": {}}
    yield "scene not a table", []  # type: ignore[misc]


def cross_field_cases() -> Iterator[Case]:
    yield "8 lights", {"lights": [DIRECTIONAL] * MAX_LIGHTS}
    yield "9 lights", {"lights": [DIRECTIONAL] * (MAX_LIGHTS + 1)}
    yield "point light without position", {"lights": [{"type": "point"}]}
    yield "light without type needs a direction", {"lights": [{"position": [1, 2, 3]}]}
    yield "light without type, with direction", {"lights": [{"direction": [1, 2, 3]}]}
    yield "point light with a direction", {"lights": [{**POINT, "direction": [0, 1, 0]}]}
    yield "point light, direction null", {"lights": [{**POINT, "direction": None}]}
    yield "directional light with a position", {"lights": [{**DIRECTIONAL, "position": [1, 1, 1]}]}
    yield "directional light, zero direction", {"lights": [{"direction": [0, 0, 0]}]}
    yield "two environment sources", {"environment": {"preset": "studio", "uniform": [1, 1, 1]}}
    yield "file and uniform", {"environment": {"file": "a.exr", "uniform": [1, 1, 1]}}
    yield "one source, others null", {"environment": {"preset": "studio", "file": None}}
    yield "zero up", {"camera": {"up": [0.0, 0.0, 0.0]}}
    # JSON Schema cannot express these (CROSS_FIELD_RULES): the server rejects, the schema not.
    yield "far below near", {"camera": {"near": 1.0, "far": 0.5}}
    yield "far equal near", {"camera": {"near": 1.0, "far": 1.0}}
    yield "far above near", {"camera": {"near": 1.0, "far": 1.5}}
    yield "eye is target", {"camera": {"eye": [1, 2, 3], "target": [1, 2, 3]}}
    yield "up parallel to view", {"camera": {"eye": [0, 0, 3], "up": [0, 0, -2]}}
    yield "image area over the limit", {"image": {"width": 16384, "height": 16384}}
    yield "image area at the limit", {"image": {"width": 8192, "height": 8192}}
    yield "the defaults resolved", scene_to_dict(Scene())


def all_cases() -> list[Case]:
    return [*field_cases(), *cross_field_cases()]


def test_the_generated_set_is_large_and_mixed() -> None:
    verdicts = [server_accepts(data)[0] for _label, data in all_cases()]
    assert len(verdicts) > 500
    assert 150 < sum(verdicts) < len(verdicts) - 150  # plenty of both good and bad scenes


def test_validator_and_schema_agree_except_the_listed_cross_field_rules() -> None:
    disagreements: dict[str, list[str]] = {}
    for label, data in all_cases():
        server_ok, field = server_accepts(data)
        if server_ok == schema_accepts(data):
            continue
        # The only allowed kind: the server rejects a cross-field rule the schema cannot state.
        assert not server_ok, f"schema rejects what the server accepts: {label}: {data}"
        disagreements.setdefault(str(field), []).append(label)
    listed = {key for key, _rule in CROSS_FIELD_RULES}
    assert set(disagreements) == listed, disagreements
    # The cases written for each rule are among them (per-field cases hit the same rules too,
    # e.g. camera.eye = [0, 0, 0] is the default target, camera.far = 5e-324 is below near).
    purpose_built = {
        "camera.far": {"far below near", "far equal near"},
        "camera.target": {"eye is target"},
        "camera.up": {"up parallel to view"},
        "image": {"image area over the limit"},
    }
    for key, labels in purpose_built.items():
        assert labels <= set(disagreements[key]), (key, disagreements[key])


@pytest.mark.parametrize(
    ("data", "path", "field"),
    [
        ({"camera": {"fov_y": 180}}, "$.camera.fov_y", "camera.fov_y"),
        ({"camera": {"colour": 1}}, "$.camera", "camera.colour"),
        ({"image": {"width": 0}}, "$.image.width", "image.width"),
        ({"output": {"aovs": ["Z", "Z"]}}, "$.output.aovs", "output.aovs"),
        ({"shading": {"background": "black"}}, "$.shading.background", "shading.background"),
    ],
)
def test_both_name_the_key_they_reject(data: dict[str, Any], path: str, field: str) -> None:
    error = best_match(VALIDATOR.iter_errors(data))
    assert error is not None and error.json_path == path, error
    assert server_accepts(data) == (False, field)


def test_the_cli_names_an_unwritable_output(tmp_path: Path) -> None:
    result = run_sphrender("schema", "-o", str(tmp_path / "missing" / "s.json"))
    assert result.returncode == 2 and "output" in result.stderr and "Traceback" not in result.stderr
