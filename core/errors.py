"""The one error type for bad input, shared by the client and the server.

Every rejection of user input (a scene key, a particle array, a file) raises `InputError` with the
dotted name of the offending field, so a CLI, an HTTP handler or a test can say exactly what was
wrong without parsing a message.
"""

from __future__ import annotations


class InputError(ValueError):
    """Bad input: `field` names what was wrong (e.g. ``camera.fov_y`` or ``positions[12]``)."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field
        self.message = message

    def __reduce__(self) -> tuple[type[InputError], tuple[str, str]]:
        """Picklable (the default would call __init__ with the one formatted argument), so the
        error survives a trip between processes, e.g. out of a Ray actor."""
        return type(self), (self.field, self.message)


class LimitError(InputError):
    """Input over a configured size limit (HTTP 413, stream code ``too_large``)."""


def show(value: object, limit: int = 60) -> str:
    """A value as it appears in an error message: JSON (``"png"``, ``[1, 2]``, ``null``,
    ``true``), never a Python repr (``'png'``, ``np.float32(1.0)``, ``b'..'``, ``None``).
    Numpy scalars and arrays become plain numbers and lists, bytes their hex digits, anything
    else its type in plain words; long texts are cut to `limit` characters with an ellipsis."""
    import json
    import math

    def plain(item: object) -> object:
        if hasattr(item, "tolist") and callable(item.tolist):  # numpy scalars and arrays
            item = item.tolist()
        if isinstance(item, float) and not math.isfinite(item):
            return "NaN" if math.isnan(item) else ("Infinity" if item > 0 else "-Infinity")
        if isinstance(item, bytes | bytearray | memoryview):
            return f"bytes {bytes(item[:16]).hex(' ')}"
        if isinstance(item, dict):
            return {str(k): plain(v) for k, v in item.items()}
        if isinstance(item, list | tuple):
            return [plain(v) for v in item]
        if item is None or isinstance(item, bool | int | float | str):
            return item
        return f"a value of type {type(item).__name__}"

    converted = plain(value)
    if converted is not value and isinstance(converted, str) and not isinstance(value, str):
        text = converted  # NaN/Infinity (not JSON, but the names every reader knows), words
    else:
        text = json.dumps(converted, ensure_ascii=False, allow_nan=False)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def kind_of(value: object) -> str:
    """A JSON value's kind in plain words: object, array, string, number, boolean, null."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, int | float):
        return "a number"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, list | tuple):
        return "an array"
    if isinstance(value, dict):
        return "an object"
    return "a value of another type"
