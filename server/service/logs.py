"""Service logging: human-readable lines by default, JSON lines with ``[logging] json = true``.

Log calls attach structured fields through ``extra`` (``log.info("frame", extra={"event":
"frame", "session": sid, "ms": 12.3})``); the JSON formatter writes them as top-level keys next to
``ts`` (UTC, ISO 8601), ``level``, ``logger`` and ``message``, so a log shipper needs no parsing.
"""

from __future__ import annotations

import datetime
import json
import logging
import sys
from typing import Any

#: Attributes every LogRecord has; anything else on a record came from ``extra``.
_RECORD_FIELDS = set(vars(logging.makeLogRecord({}))) | {"message", "asctime", "taskName"}


class JsonLinesFormatter(logging.Formatter):
    """One JSON object per record, extra fields included, never a multi-line entry."""

    def format(self, record: logging.LogRecord) -> str:
        entry: dict[str, Any] = {
            "ts": datetime.datetime.fromtimestamp(record.created, datetime.UTC).isoformat(
                timespec="milliseconds"
            ),
            "level": record.levelname.lower(),
            "logger": record.name,
            "message": record.getMessage(),
        }
        for key, value in vars(record).items():
            if key not in _RECORD_FIELDS and not key.startswith("_"):
                entry[key] = value
        if record.exc_info:
            entry["exception"] = self.formatException(record.exc_info)
        return json.dumps(entry, default=str, allow_nan=False)


class KeyValueFormatter(logging.Formatter):
    """``logger: message key=value ...`` for people reading a terminal."""

    def format(self, record: logging.LogRecord) -> str:
        extras = " ".join(
            f"{key}={value}"
            for key, value in vars(record).items()
            if key not in _RECORD_FIELDS and not key.startswith("_")
        )
        text = f"{record.name}: {record.getMessage()}"
        if extras:
            text = f"{text} [{extras}]"
        if record.exc_info:
            text = f"{text}\n{self.formatException(record.exc_info)}"
        return text


def configure_logging(*, json_lines: bool, level: str) -> None:
    """Route the ``sphrender`` loggers to stderr with the chosen format (replaces handlers)."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(JsonLinesFormatter() if json_lines else KeyValueFormatter())
    root = logging.getLogger("sphrender")
    for old in list(root.handlers):
        root.removeHandler(old)
    root.addHandler(handler)
    root.setLevel(level.upper())
    root.propagate = False
