"""The building blocks of the scene schema: limits, the vector type and `spec`, the field
constructor whose metadata (documentation, range, unit) the validator and the JSON Schema read.
"""

from __future__ import annotations

from dataclasses import MISSING, field
from typing import Any

#: Largest image side accepted by the configuration; the GL context may lower it further.
MAX_IMAGE_SIDE = 16384
#: Largest image area accepted (pixels).
MAX_IMAGE_PIXELS = 8192 * 8192
#: Longest string value (characters); strings must not contain NUL either.
MAX_STRING_LENGTH = 4096

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
    }
    if isinstance(default, list | tuple) or default is MISSING:
        if default is MISSING:
            return field(metadata=meta)
        return field(default=tuple(default), metadata=meta)
    return field(default=default, metadata=meta)
