"""Log lines as JSON objects, one a line, for log collectors (PRINTHOST_LOG_FORMAT=json).

Every printhost process (daphne, runhost, the printer workers, Celery) configures
its logging from `settings.LOGGING`; with `PRINTHOST_LOG_FORMAT=json` the console
handler uses `JsonFormatter`, and each record becomes one line:

    {"time": "2026-01-02T03:04:05.678Z", "level": "INFO", "logger": "printhost.runhost",
     "message": "starting daphne", "pid": 1234, "printer": "mk4-1"}

`time` is UTC with milliseconds; `message` is the formatted message; fields given
with `extra=` (printer, job, host, ...) follow as they are (anything JSON cannot
hold is written as its text); an exception adds `exception` (the traceback) and a
stack adds `stack`. A line never spans two lines: newlines inside strings are
escaped by JSON.

daphne writes its access log straight to a stream, not through logging; in JSON
mode `access_log` gives `printhost.serve` a `LoggedAccessLog` instead, so each
request and websocket event is a record of the `printhost.access` logger with its
fields (client, method, path, status, size), its query string already redacted.
"""

from __future__ import annotations

import json
import logging
from datetime import UTC, datetime
from typing import Any

from django.conf import settings

#: Attributes every LogRecord has: not "extra" fields.
_STANDARD = frozenset(logging.LogRecord("", 0, "", 0, "", (), None).__dict__) | {
    "message",
    "asctime",
    "taskName",
}


def _jsonable(value: Any) -> Any:
    """*value* if JSON holds it as is, else its text."""
    if value is None or isinstance(value, str | int | float | bool):
        return value
    if isinstance(value, list | tuple):
        return [_jsonable(item) for item in value]
    if isinstance(value, dict):
        return {str(key): _jsonable(item) for key, item in value.items()}
    return str(value)


class JsonFormatter(logging.Formatter):
    """One JSON object per record: time, level, logger, message, pid, extra fields."""

    def format(self, record: logging.LogRecord) -> str:
        moment = datetime.fromtimestamp(record.created, tz=UTC)
        line: dict[str, Any] = {
            "time": moment.isoformat(timespec="milliseconds").replace("+00:00", "Z"),
            "level": record.levelname,
            "logger": record.name,
            "message": record.getMessage(),
            "pid": record.process,
        }
        for key, value in record.__dict__.items():
            if key not in _STANDARD and not key.startswith("_") and key not in line:
                line[key] = _jsonable(value)
        if record.exc_info:
            line["exception"] = self.formatException(record.exc_info)
        elif record.exc_text:
            line["exception"] = record.exc_text
        if record.stack_info:
            line["stack"] = self.formatStack(record.stack_info)
        return json.dumps(line, ensure_ascii=False)


#: PRINTHOST_LOG_FORMAT values and the formatter each one names in LOGGING.
FORMATTERS: dict[str, dict[str, Any]] = {
    "text": {"format": "%(asctime)s %(levelname)s %(name)s: %(message)s"},
    "json": {"()": "printhost.logformat.JsonFormatter"},
}


#: daphne's websocket actions, as its own access log words them.
_WEBSOCKET = {
    "connecting": "WSCONNECTING",
    "rejected": "WSREJECT",
    "connected": "WSCONNECT",
    "disconnected": "WSDISCONNECT",
}


class LoggedAccessLog:
    """daphne's access log (its `action_logger` call) as `printhost.access` records."""

    logger = logging.getLogger("printhost.access")

    def __call__(self, protocol: str, action: str, details: dict[str, Any]) -> None:
        client, path = details.get("client"), details.get("path")
        if protocol == "http" and action == "complete":
            method, status, size = (
                details.get("method"), details.get("status"), details.get("size"),
            )  # fmt: skip
            self.logger.info(
                "%s %s %s %s", method, path, status, size,
                extra={"client": client, "method": method, "path": path,
                       "status": status, "size": size},
            )  # fmt: skip
        elif protocol == "websocket" and action in _WEBSOCKET:
            self.logger.info(
                "%s %s", _WEBSOCKET[action], path,
                extra={"client": client, "websocket": action, "path": path},
            )  # fmt: skip


def access_log(default: Any) -> Any:
    """The access log daphne should use: *default* (its own), or in JSON mode logging."""
    if settings.PRINTHOST_LOG_FORMAT == "json":
        return LoggedAccessLog()
    return default
