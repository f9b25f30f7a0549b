"""The scene's JSON Schema (draft 2020-12), generated from the dataclasses of `schema.py`.

One source of truth: each property's type, description, unit (``x-unit``), default and range or
enum come from the field's annotation and its `spec` metadata, the same metadata `validate.py`
reads. Every object has ``additionalProperties: false``, as the validator rejects unknown keys.

Rules that span fields are written here as JSON Schema where the language can say them (a
light's type decides whether it needs a direction or a position; at most one environment source;
no zero vectors; a non-blank environment file). What it cannot say (comparisons between two
values, products, vector geometry) is listed in `CROSS_FIELD_RULES` and in the schema's own
``x-cross-field-rules``: the server checks those too, so a scene the schema accepts can still get
a 400 naming one of those keys, and nothing else. Limits of one server (``limits.max_pixels``,
its environment directories, its GPU's largest image) are not scene rules and not here: see
``GET /v1/info``.

The committed copy is ``schema/scene.schema.json`` (``sphrender schema -o
schema/scene.schema.json`` writes it; a test checks it is current); ``GET /v1/schema`` serves the
same document.
"""

from __future__ import annotations

import json
import types
import typing
from dataclasses import MISSING, fields
from typing import Any, Literal, get_args, get_origin

from sphrender.server.scene.fields import is_bench_only
from sphrender.server.scene.schema import (
    MAX_IMAGE_PIXELS,
    MAX_STRING_LENGTH,
    CameraConfig,
    EnvironmentConfig,
    FinishConfig,
    LightConfig,
    Scene,
    Vec3,
    scene_sections,
)

SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"
SCHEMA_ID = "urn:sphrender:scene"

#: The validator's rules that JSON Schema cannot express: (keys, rule in plain words). A scene
#: the schema accepts and the server rejects breaks one of these, and only these.
CROSS_FIELD_RULES: tuple[tuple[str, str], ...] = (
    ("camera.far", "camera.far, when given, must be greater than camera.near"),
    ("camera.target", "camera.target must differ from camera.eye (a view direction exists)"),
    ("camera.up", "camera.up must not be parallel to camera.target - camera.eye"),
    ("finish.brush_direction", "finish.brush_direction must not be the zero vector"),
    ("image", f"image.width * image.height must be at most {MAX_IMAGE_PIXELS} pixels"),
)

_NO_NUL = "^[^\\u0000]*$"
_NOT_BLANK = "\\S"
_PYTHON_TYPES = {str: "string", bool: "boolean", int: "integer", float: "number"}


def _range(meta: typing.Mapping[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if meta.get("low") is not None:
        out["exclusiveMinimum" if meta["low_open"] else "minimum"] = meta["low"]
    if meta.get("high") is not None:
        out["exclusiveMaximum" if meta["high_open"] else "maximum"] = meta["high"]
    return out


def _type_schema(annotation: Any, meta: typing.Mapping[str, Any]) -> dict[str, Any]:
    """The schema of one value of `annotation` (the cases of `validate._convert`, in order)."""
    origin = get_origin(annotation)
    if origin is types.UnionType or origin is typing.Union:
        options = [a for a in get_args(annotation) if a is not type(None)]
        return {"anyOf": [_type_schema(options[0], meta), {"type": "null"}]}
    if origin is Literal:
        allowed = list(get_args(annotation))
        return {"type": _PYTHON_TYPES[type(allowed[0])], "enum": allowed}
    if annotation is str:
        return {"type": "string", "maxLength": MAX_STRING_LENGTH, "pattern": _NO_NUL}
    if annotation is bool:
        return {"type": "boolean"}
    if annotation is int:
        return {"type": "integer", **_range(meta)}
    if annotation is float:
        return {"type": "number", **_range(meta)}
    if annotation == Vec3:
        item = {"type": "number", **_range(meta)}
        return {"type": "array", "items": item, "minItems": 3, "maxItems": 3}
    if origin is tuple:
        (item_type, _ellipsis) = get_args(annotation)
        return {"type": "array", "items": _type_schema(item_type, meta), "uniqueItems": True}
    raise TypeError(f"no JSON Schema for annotation {annotation!r}")  # programming error


def _json_default(value: Any) -> Any:
    return [_json_default(v) for v in value] if isinstance(value, tuple) else value


def _description(cls: type) -> str | None:
    doc = cls.__doc__ or ""
    if not doc or doc.startswith(f"{cls.__name__}("):  # the dataclass's generated signature
        return None
    return " ".join(doc.split())


def _section_schema(cls: type) -> dict[str, Any]:
    hints = typing.get_type_hints(cls)
    properties: dict[str, Any] = {}
    for f in fields(cls):
        if is_bench_only(f):
            continue
        meta = f.metadata
        prop: dict[str, Any] = {}
        unit = meta.get("unit")
        doc = meta.get("doc", "")
        prop["description"] = f"{doc} [{unit}]" if unit else doc
        if unit:
            prop["x-unit"] = unit
        if f.default is not MISSING:
            prop["default"] = _json_default(f.default)
        prop.update(_type_schema(hints[f.name], meta))
        properties[f.name] = prop
    out: dict[str, Any] = {"type": "object"}
    if description := _description(cls):
        out["description"] = description
    out.update(properties=properties, additionalProperties=False)
    return out


def _given(key: str) -> dict[str, Any]:
    """`key` is present and not null (the validator treats null as absent)."""
    return {"required": [key], "properties": {key: {"not": {"type": "null"}}}}


_NONZERO = {"not": {"items": {"const": 0}}}


def _light_schema() -> dict[str, Any]:
    out = _section_schema(LightConfig)
    out["properties"]["direction"]["anyOf"][0].update(_NONZERO)
    # type defaults to directional: a point or sphere light needs a position and has no
    # direction, a directional light the other way round.
    point = {"required": ["type"], "properties": {"type": {"enum": ["point", "sphere"]}}}
    out["if"] = point
    out["then"] = {"allOf": [_given("position"), {"not": _given("direction")}]}
    out["else"] = {"allOf": [_given("direction"), {"not": _given("position")}]}
    # Only a sphere light has a radius above 0.
    sphere = {"required": ["type"], "properties": {"type": {"const": "sphere"}}}
    out["allOf"] = [{"if": sphere, "else": {"properties": {"radius": {"const": 0}}}}]
    # Only a directional light has an angular radius above 0 (type defaults to directional).
    not_directional = {
        "required": ["type"],
        "not": {"properties": {"type": {"const": "directional"}}},
    }
    out["allOf"].append(
        {"if": not_directional, "then": {"properties": {"angular_radius_deg": {"const": 0}}}}
    )
    return out


def _environment_schema() -> dict[str, Any]:
    out = _section_schema(EnvironmentConfig)
    file_schema = out["properties"]["file"]["anyOf"][0]
    file_schema["allOf"] = [{"pattern": _NOT_BLANK, "description": "not blank"}]
    sources = ("preset", "uniform", "file")
    pairs = [[a, b] for i, a in enumerate(sources) for b in sources[i + 1 :]]
    out["not"] = {
        "anyOf": [{"allOf": [_given(a), _given(b)]} for a, b in pairs],
        "description": "give at most one of preset, uniform, file",
    }
    return out


def scene_json_schema() -> dict[str, Any]:
    """The scene's JSON Schema as a mapping (JSON-serialisable, deterministic)."""
    hints = typing.get_type_hints(Scene)
    defs: dict[str, Any] = {}
    properties: dict[str, Any] = {}
    for f in scene_sections():
        hint = hints[f.name]
        if get_origin(hint) is tuple:  # lights: an array of tables
            (item_cls, _ellipsis) = get_args(hint)
            defs[item_cls.__name__] = _light_schema()
            prop: dict[str, Any] = {
                "description": _description(item_cls) or f.name,
                "type": "array",
                "items": {"$ref": f"#/$defs/{item_cls.__name__}"},
                "default": [],
            }
            if f.metadata.get("max_items") is not None:
                prop["maxItems"] = f.metadata["max_items"]
        else:
            section = _environment_schema() if hint is EnvironmentConfig else _section_schema(hint)
            if hint is CameraConfig:
                section["properties"]["up"].update(_NONZERO)
            if hint is FinishConfig:
                image_schema = section["properties"]["detail_image"]["anyOf"][0]
                image_schema["allOf"] = [{"pattern": _NOT_BLANK, "description": "not blank"}]
            defs[hint.__name__] = section
            prop = {"$ref": f"#/$defs/{hint.__name__}"}
        properties[f.name] = prop
    return {
        "$schema": SCHEMA_DIALECT,
        "$id": SCHEMA_ID,
        "title": "sphrender scene",
        "description": (
            f"{_description(Scene)} Every section and key is optional; absent keys take their "
            "default. Generated from sphrender's scene dataclasses (server/scene/schema.py). "
            "The server also checks the rules in x-cross-field-rules, which JSON Schema cannot "
            "express, and reads the previous release's key names (with a note)."
        ),
        "x-cross-field-rules": [{"key": key, "rule": rule} for key, rule in CROSS_FIELD_RULES],
        "type": "object",
        "properties": properties,
        "additionalProperties": False,
        "$defs": defs,
    }


def scene_json_schema_text() -> str:
    """The schema as the committed file holds it: 2-space indented JSON, a final newline."""
    return json.dumps(scene_json_schema(), indent=2, ensure_ascii=False, allow_nan=False) + "\n"
