"""Structured logging: one logger per node, readable on a terminal; JSON lines with SAGE_LOG_FORMAT=json.

``log = get_logger("serial_bridge"); log.info("port opened", port="/dev/ttyACM0")``
prints ``21:58:01.123 INFO  serial_bridge  port opened port=/dev/ttyACM0``. Field names
that look secret (password, key, token, secret) are always printed as ``***``. The last
records are kept in memory for the web admin page.
"""

from __future__ import annotations

import json
import logging
import os
import sys
import time
from collections import deque
from typing import Any

SECRET_HINTS = ("password", "passwd", "secret", "token", "api_key", "apikey", "key")
RECENT_RECORDS = 500  # log records kept for the admin page

_configured = False


def _redact(fields: dict[str, Any]) -> dict[str, Any]:
    return {
        k: ("***" if any(h in k.lower() for h in SECRET_HINTS) else v) for k, v in fields.items()
    }


class StructLogger:
    """A thin wrapper that turns keyword arguments into structured fields."""

    def __init__(self, name: str) -> None:
        self.name = name
        self._logger = logging.getLogger(f"sage.{name}")

    def _log(self, level: int, msg: str, exc_info: bool, fields: dict[str, Any]) -> None:
        self._logger.log(level, msg, exc_info=exc_info, extra={"sage_fields": _redact(fields)})

    def debug(self, msg: str, **fields: Any) -> None:
        self._log(logging.DEBUG, msg, False, fields)

    def info(self, msg: str, **fields: Any) -> None:
        self._log(logging.INFO, msg, False, fields)

    def warning(self, msg: str, **fields: Any) -> None:
        self._log(logging.WARNING, msg, False, fields)

    def error(self, msg: str, **fields: Any) -> None:
        self._log(logging.ERROR, msg, False, fields)

    def exception(self, msg: str, **fields: Any) -> None:
        self._log(logging.ERROR, msg, True, fields)


def get_logger(name: str) -> StructLogger:
    return StructLogger(name)


def _fields(record: logging.LogRecord) -> dict[str, Any]:
    return getattr(record, "sage_fields", {}) or {}


class HumanFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        t = time.strftime("%H:%M:%S", time.localtime(record.created))
        name = record.name.removeprefix("sage.")
        extra = " ".join(f"{k}={v}" for k, v in _fields(record).items())
        line = f"{t}.{int(record.msecs):03d} {record.levelname:<5} {name:<14} {record.getMessage()}"
        if extra:
            line += "  " + extra
        if record.exc_info and os.environ.get("SAGE_LOG_TRACEBACKS"):
            line += "\n" + self.formatException(record.exc_info)
        elif record.exc_info and record.exc_info[1] is not None:
            exc = record.exc_info[1]
            line += f"  error={type(exc).__name__}: {exc}"
        return line


class JsonFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        out = {
            "t": record.created,
            "level": record.levelname.lower(),
            "node": record.name.removeprefix("sage."),
            "msg": record.getMessage(),
            **{k: str(v) for k, v in _fields(record).items()},
        }
        if record.exc_info:
            out["traceback"] = self.formatException(record.exc_info)
        return json.dumps(out)


class RecentRecords(logging.Handler):
    """Keeps the last records as dicts (for the admin page and `sage status`)."""

    def __init__(self, size: int = RECENT_RECORDS) -> None:
        super().__init__(logging.INFO)
        self.records: deque[dict[str, Any]] = deque(maxlen=size)

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(
            {
                "t": record.created,
                "level": record.levelname.lower(),
                "node": record.name.removeprefix("sage."),
                "msg": record.getMessage(),
                "fields": {k: str(v) for k, v in _fields(record).items()},
            }
        )


RECENT = RecentRecords()


_console: logging.Handler | None = None  # the stderr handler configure() attached


def configure(level: str = "INFO", fmt: str | None = None) -> None:
    """Set up the root 'sage' logger once: human on a TTY, JSON otherwise (or SAGE_LOG_FORMAT).

    ``level`` is what reaches the terminal (the stderr handler's level). The logger itself
    stays at INFO or lower, so the in-memory records (admin page) keep INFO whatever the
    terminal shows; a later call only changes the terminal's level.
    """
    global _configured, _console
    root = logging.getLogger("sage")
    wanted = logging.getLevelName(level.upper())
    if not isinstance(wanted, int):
        raise ValueError(f"unknown log level {level!r}; use DEBUG, INFO, WARNING or ERROR")
    root.setLevel(min(wanted, logging.INFO))
    if _configured:
        if _console is not None:
            _console.setLevel(wanted)
        return
    _configured = True
    fmt = fmt or os.environ.get("SAGE_LOG_FORMAT") or "human"
    _console = logging.StreamHandler(sys.stderr)
    _console.setLevel(wanted)
    _console.setFormatter(JsonFormatter() if fmt == "json" else HumanFormatter())
    root.addHandler(_console)
    root.addHandler(RECENT)
    root.propagate = False
