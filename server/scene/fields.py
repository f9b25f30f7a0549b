"""The building blocks of the scene schema: limits, the vector type, `spec` (the field
constructor whose metadata, documentation, range and unit, the validator and the JSON Schema
read), `bench_spec` for the benchmark's own settings, and `SceneNote`.
"""

from __future__ import annotations

from dataclasses import MISSING, dataclass, field
from typing import Any

#: Largest image side accepted by the configuration; the GL context may lower it further.
MAX_IMAGE_SIDE = 16384
#: Largest image area accepted (pixels).
MAX_IMAGE_PIXELS = 8192 * 8192
#: Longest string value (characters); strings must not contain NUL either.
MAX_STRING_LENGTH = 4096
#: Range of a length the renderer cubes in float32 (particle radius, kernel support): 1e±12 keeps
#: r^3 and 1 / r^3 normal floats.
MIN_LENGTH = 1e-12
MAX_LENGTH = 1e12
#: Range of a rest density: frames carry densities as float32, with room for 0.35-1.5 x of it.
MIN_DENSITY = 1e-30
MAX_DENSITY = 1e30

Vec3 = tuple[float, float, float]


def spec(
    default: Any = MISSING,
    doc: str = "",
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
    unit: str | None = None,
    bench_only: bool = False,
) -> Any:
    """A dataclass field with its documentation, numeric range (closed unless *_open; for a
    vector, the range of each component) and unit. The validator (`validate.py`) and the JSON
    Schema (`json_schema.py`) both read this metadata, so a field's rules are written once."""
    meta = {
        "doc": doc,
        "low": low,
        "high": high,
        "low_open": low_open,
        "high_open": high_open,
        "unit": unit,
        "bench_only": bench_only,
    }
    if isinstance(default, list | tuple) or default is MISSING:
        if default is MISSING:
            return field(metadata=meta)
        return field(default=tuple(default), metadata=meta)
    return field(default=default, metadata=meta)


def bench_spec(default: Any, doc: str) -> Any:
    """A field only the benchmark sets (`bench_scene_from_dict`): scene files, JSON scenes and
    the JSON Schema do not have it, and a scene that gives it is refused naming the key."""
    return spec(default, doc, bench_only=True)


def is_bench_only(f: Any) -> bool:
    """Whether the dataclass field `f` is a benchmark setting (`bench_spec`)."""
    return bool(f.metadata.get("bench_only", False))


@dataclass(frozen=True)
class SceneNote:
    """Something reading a scene changed (an old key name), said to the user with each frame's
    notes: the key as given, and what was done, in words."""

    field: str
    message: str
