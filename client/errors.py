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
