"""`HttpError`: an HTTP error answer (status, error code, message, field), raised anywhere in a
request and written as the documented JSON body by the handler (PROTOCOL.md, HTTP API)."""

from __future__ import annotations

from sphrender.core.errors import InputError
from sphrender.core.protocol import ErrorCode, LimitError


class HttpError(Exception):
    """An error answer: status, error code, message and the offending field."""

    def __init__(
        self,
        status: int,
        code: str,
        message: str,
        field: str | None = None,
        *,
        close: bool = False,
        retry_after_s: int | None = None,
        headers: dict[str, str] | None = None,
    ) -> None:
        super().__init__(message)
        self.status = status
        self.code = code
        self.message = message
        self.field = field
        self.close = close
        self.retry_after_s = retry_after_s
        self.headers = headers or {}

    @classmethod
    def from_input(cls, exc: InputError, *, close: bool = False) -> HttpError:
        if isinstance(exc, LimitError):
            return cls(413, ErrorCode.TOO_LARGE, exc.message, exc.field, close=close)
        return cls(400, ErrorCode.BAD_INPUT, exc.message, exc.field, close=close)
