"""Validation of scene mappings (TOML / JSON) into the dataclasses of `schema.py`.

`section_from_dict` reads each field's type and `spec` metadata, so a field is declared once
(in `schema.py`) and validated here without a second list; `scene_from_dict` reads old key names
first (`renames.py`) and adds the rules that span fields (camera basis, lights, environment
source, image area).
"""

from __future__ import annotations

import math
import types
import typing
from collections.abc import Mapping, Sequence
from dataclasses import fields
from typing import Any, Literal, TypeVar, get_args, get_origin

from sphrender.core.errors import InputError, LimitError, kind_of, show
from sphrender.server.scene.fields import is_bench_only
from sphrender.server.scene.layering import PRESETS, merge_scene_dicts, preset_sections
from sphrender.server.scene.renames import upgrade_scene_dict
from sphrender.server.scene.schema import (
    MAX_IMAGE_PIXELS,
    MAX_STRING_LENGTH,
    LightConfig,
    Scene,
    Vec3,
    scene_sections,
)
from sphrender.server.scene.schema_finish import check_finish

T = TypeVar("T")


def _describe_range(meta: Mapping[str, Any]) -> str:
    low, high = meta["low"], meta["high"]
    lo = "(" if meta["low_open"] else "["
    hi = ")" if meta["high_open"] else "]"
    return (
        f"{lo}{'-inf' if low is None else _fmt(low)}, {'inf' if high is None else _fmt(high)}{hi}"
    )


def _fmt(x: float) -> str:
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e7 else f"{x:g}"


def _check_range(key: str, value: float, meta: Mapping[str, Any]) -> None:
    low, high = meta["low"], meta["high"]
    bad = (low is not None and (value <= low if meta["low_open"] else value < low)) or (
        high is not None and (value >= high if meta["high_open"] else value > high)
    )
    if bad:
        raise InputError(key, f"must be in {_describe_range(meta)}, got {show(value)}")


def _convert(key: str, value: Any, annotation: Any, meta: Mapping[str, Any]) -> Any:
    origin = get_origin(annotation)
    if origin is types.UnionType or origin is typing.Union:
        options = [a for a in get_args(annotation) if a is not type(None)]
        if value is None:
            return None
        return _convert(key, value, options[0], meta)
    if origin is Literal:
        allowed = get_args(annotation)
        if value not in allowed or isinstance(value, bool) != isinstance(allowed[0], bool):
            raise InputError(
                key, f"must be one of {', '.join(map(show, allowed))}, got {show(value)}"
            )
        return allowed[allowed.index(value)]  # 16.0 (JSON has one number type) -> 16
    if annotation is str:
        if not isinstance(value, str):
            raise InputError(key, f"must be a string, got {show(value)}")
        if len(value) > MAX_STRING_LENGTH or "\x00" in value:
            raise InputError(key, f"must be at most {MAX_STRING_LENGTH} characters without NUL")
        return value
    if annotation is bool:
        if not isinstance(value, bool):
            raise InputError(key, f"must be true or false, got {show(value)}")
        return value
    if annotation is int:
        # JSON has one number type: 640.0 is the integer 640 (as JSON Schema's "integer" says).
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if isinstance(value, bool) or not isinstance(value, int):
            raise InputError(key, f"must be an integer, got {show(value)}")
        _check_range(key, value, meta)
        return value
    if annotation is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise InputError(key, f"must be a number, got {show(value)}")
        if not math.isfinite(value):
            raise InputError(key, f"must be finite, got {show(value)}")
        _check_range(key, float(value), meta)
        return float(value)
    if annotation == Vec3:
        if not isinstance(value, list | tuple) or len(value) != 3:
            raise InputError(key, f"must be a list of 3 numbers, got {show(value)}")
        return tuple(_convert(f"{key}[{i}]", v, float, meta) for i, v in enumerate(value))
    if origin is tuple:
        (item_type, _ellipsis) = get_args(annotation)
        if not isinstance(value, list | tuple):
            raise InputError(key, f"must be a list, got {show(value)}")
        items = tuple(_convert(f"{key}[{i}]", v, item_type, meta) for i, v in enumerate(value))
        if len(set(items)) != len(items):
            raise InputError(key, f"must not repeat entries, got {show(list(value))}")
        return items
    raise TypeError(f"unsupported annotation {annotation!r} for {key}")  # programming error


def section_from_dict(cls: type[T], data: Any, prefix: str, *, bench: bool = False) -> T:
    """Validate one table into the frozen dataclass `cls` whose fields are declared with `spec`
    (also used for the server settings): unknown keys, wrong types and values outside a field's
    range raise `InputError` named `prefix.key`. The benchmark's settings (`bench_spec`) are
    read only with `bench`."""
    if not isinstance(data, Mapping):
        raise InputError(prefix, f"must be a table, got {kind_of(data)}")
    hints = typing.get_type_hints(cls)
    every = {f.name: f for f in fields(cls)}  # type: ignore[arg-type]
    known = {name: f for name, f in every.items() if bench or not is_bench_only(f)}
    for key in data:
        if key in every and key not in known:
            raise InputError(
                f"{prefix}.{key}",
                "was removed from the scene: a benchmark setting (sphrender bench sets it)",
            )
        if key not in known:
            raise InputError(f"{prefix}.{key}", f"unknown key; allowed: {', '.join(sorted(known))}")
    kwargs = {
        name: _convert(f"{prefix}.{name}", data[name], hints[name], f.metadata)
        for name, f in known.items()
        if name in data
    }
    return cls(**kwargs)


def _sections_from_list(cls: type[T], data: Any, prefix: str, section: Any) -> tuple[T, ...]:
    """An array of tables (TOML ``[[lights]]``): each entry validated as a section, errors
    named ``prefix[i].key``; the scene field's metadata may cap the count (``max_items``)."""
    if not isinstance(data, list | tuple):
        raise InputError(prefix, f"must be an array of tables, got {kind_of(data)}")
    limit = section.metadata.get("max_items")
    if limit is not None and len(data) > limit:
        raise InputError(prefix, f"at most {limit} entries, got {len(data)}")
    return tuple(section_from_dict(cls, item, f"{prefix}[{i}]") for i, item in enumerate(data))


def scene_from_dict(
    data: Mapping[str, Any], *, bench: bool = False, max_pixels: int | None = None
) -> Scene:
    """Build and validate a `Scene` from a TOML/JSON-like mapping (missing keys keep defaults).
    Old key names are read under their new ones, with a note on the scene (`Scene.notes`);
    `bench` also reads the benchmark's own settings (`bench_scene_from_dict` passes it).
    `max_pixels`: a server's own image limit (``limits.max_pixels``), refused as `LimitError`
    before any other cross-field rule; without it the absolute `MAX_IMAGE_PIXELS` applies."""
    if not isinstance(data, Mapping):
        raise InputError("scene", f"must be a table, got {kind_of(data)}")
    data, notes = upgrade_scene_dict(data)
    data = _under_preset(data)
    sections: dict[str, Any] = {}
    known = {f.name: f for f in scene_sections()}
    hints = typing.get_type_hints(Scene)
    for key, value in data.items():
        if key not in known:
            raise InputError(key, f"unknown section; allowed: {', '.join(sorted(known))}")
        hint = hints[key]
        if get_origin(hint) is tuple:
            sections[key] = _sections_from_list(get_args(hint)[0], value, key, known[key])
        else:
            sections[key] = section_from_dict(hint, value, key, bench=bench)
    scene = Scene(**sections, notes=notes)
    _check_pixels(scene, max_pixels)
    _check_cross_field(scene)
    return scene


def _under_preset(data: dict[str, Any]) -> dict[str, Any]:
    """`data` laid over the sections of its ``quality.preset`` (its own keys win), as the CLI's
    ``--quality`` does; unchanged without one."""
    quality = data.get("quality")
    name = quality.get("preset") if isinstance(quality, Mapping) else None
    if name is None:
        return data
    if not isinstance(name, str) or name not in PRESETS:
        allowed = ", ".join(map(show, PRESETS))
        raise InputError("quality.preset", f"must be one of {allowed}, got {show(name)}")
    return merge_scene_dicts(preset_sections(name), data)


def _check_pixels(scene: Scene, max_pixels: int | None) -> None:
    w, h = scene.image.width, scene.image.height
    if max_pixels is not None and w * h > max_pixels:
        raise LimitError(
            "image",
            f"{w}x{h} = {w * h} pixels exceeds this server's limit of {max_pixels} "
            "(limits.max_pixels)",
        )
    if w * h > MAX_IMAGE_PIXELS:
        raise InputError("image", f"{w}x{h} exceeds the limit of {MAX_IMAGE_PIXELS} pixels")


def _length(vector: Sequence[float], field: str, what: str = "the vector") -> float:
    """A vector's length; one whose length overflows binary64 is refused naming `field`."""
    length = math.sqrt(sum(c * c for c in vector))
    if not math.isfinite(length):
        raise InputError(field, f"{what} is too long: its length overflows a 64-bit float")
    return length


def _check_cross_field(scene: Scene) -> None:
    cam = scene.camera
    if cam.far is not None and cam.far <= cam.near:
        raise InputError(
            "camera.far", f"must be greater than camera.near ({cam.near}), got {cam.far}"
        )
    view = [t - e for t, e in zip(cam.target, cam.eye, strict=True)]
    length = _length(view, "camera.target", "target - eye")
    if length == 0.0 or length < 1e-12 * max(1.0, *(abs(e) for e in cam.eye)):
        raise InputError("camera.target", "must differ from camera.eye (no view direction)")
    up_len = _length(cam.up, "camera.up")
    if up_len == 0.0:
        raise InputError("camera.up", "must not be the zero vector")
    cos = abs(sum(v * u for v, u in zip(view, cam.up, strict=True))) / (length * up_len)
    if cos > 1.0 - 1e-9:
        raise InputError("camera.up", "must not be parallel to the view direction (target - eye)")
    _check_lights(scene.lights)
    check_finish(scene.finish)
    env = scene.environment
    given = [k for k in ("preset", "uniform", "file") if getattr(env, k) is not None]
    if len(given) > 1:
        raise InputError(
            f"environment.{given[1]}", f"give only one of preset, uniform, file (got {given})"
        )
    if env.file is not None and not env.file.strip():
        raise InputError("environment.file", "must not be empty")


def _check_lights(lights: tuple[LightConfig, ...]) -> None:
    for i, light in enumerate(lights):
        key = f"lights[{i}]"
        if light.type == "directional":
            if light.direction is None:
                raise InputError(f"{key}.direction", "a directional light needs a direction")
            if _length(light.direction, f"{key}.direction") == 0.0:
                raise InputError(f"{key}.direction", "must not be the zero vector")
            if light.position is not None:
                raise InputError(f"{key}.position", "only point lights have a position")
        else:
            if light.position is None:
                raise InputError(f"{key}.position", f"a {light.type} light needs a position")
            if light.direction is not None:
                raise InputError(f"{key}.direction", "only directional lights have a direction")
        if light.radius > 0.0 and light.type != "sphere":
            raise InputError(f"{key}.radius", "only sphere lights have a radius")
        if light.angular_radius_deg > 0.0 and light.type != "directional":
            raise InputError(
                f"{key}.angular_radius_deg", "only directional lights have an angular radius"
            )
