"""Service logging: human-readable lines by default, JSON lines with ``[logging] json = true``.

Log calls attach structured fields through ``extra`` (``log.info("frame", extra={"event":
"frame", "session": sid, "ms": 12.3})``); the JSON formatter writes them as top-level keys next to
``ts`` (UTC, ISO 8601), ``level``, ``logger`` and ``message``, so a log shipper needs no parsing.
"""

from __future__ import annotations

import datetime
import json
import logging
import os
import sys
import warnings
from typing import Any, TextIO

#: The environment variable that hands the logging choice to the render process.
LOGGING_ENV = "SPHRENDER_LOGGING"
#: Where Python warnings are logged.
_warnings_log = logging.getLogger("sphrender.warnings")
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


def _show_warning(
    message: Warning | str,
    category: type[Warning],
    filename: str,
    lineno: int,
    file: TextIO | None = None,
    line: str | None = None,
) -> None:
    """Python warnings (numpy's RuntimeWarnings, say) as log records, not stderr text."""
    _warnings_log.warning(
        str(message),
        extra={
            "event": "python_warning",
            "category": category.__name__,
            "source": f"{os.path.basename(filename)}:{lineno}",
        },
    )


def configure_logging(*, json_lines: bool, level: str) -> None:
    """Route the ``sphrender`` loggers and Python warnings to stderr with the chosen format
    (replaces handlers). The choice is kept in the environment for the render process
    (`configure_inherited_logging`), which multiprocessing starts with a copy of it."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(JsonLinesFormatter() if json_lines else KeyValueFormatter())
    root = logging.getLogger("sphrender")
    for old in list(root.handlers):
        root.removeHandler(old)
    root.addHandler(handler)
    root.setLevel(level.upper())
    root.propagate = False
    warnings.showwarning = _show_warning
    os.environ[LOGGING_ENV] = json.dumps({"json_lines": json_lines, "level": level})


def configure_inherited_logging() -> None:
    """In a child process: the parent's `configure_logging` choice, if it made one."""
    try:
        choice = json.loads(os.environ.get(LOGGING_ENV, ""))
        json_lines, level = bool(choice["json_lines"]), str(choice["level"])
    except (ValueError, KeyError, TypeError):
        return
    configure_logging(json_lines=json_lines, level=level)
