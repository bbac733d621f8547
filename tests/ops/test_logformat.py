"""JSON log lines: one object a line with time, level, logger, message and extras."""

from __future__ import annotations

import io
import json
import logging
import os
import subprocess
import sys
from datetime import datetime

import pytest

from printhost.logformat import JsonFormatter, LoggedAccessLog, access_log
from tests.conftest import ROOT


def logged(emit, name: str = "printhost.test") -> list[dict]:
    """The JSON objects a logger wrote while *emit*(logger) ran."""
    stream = io.StringIO()
    handler = logging.StreamHandler(stream)
    handler.setFormatter(JsonFormatter())
    logger = logging.getLogger(name)
    logger.addHandler(handler)
    logger.setLevel(logging.DEBUG)
    try:
        emit(logger)
    finally:
        logger.removeHandler(handler)
    lines = stream.getvalue().splitlines()
    return [json.loads(line) for line in lines]


def test_a_record_is_one_json_line_with_its_extra_fields():
    [line] = logged(
        lambda log: log.warning(
            "job %s\non %s",
            7,
            "mk4",
            extra={"printer": "mk4", "job": 7, "host": "rack1"},
        )
    )
    assert line["level"] == "WARNING"
    assert line["logger"] == "printhost.test"
    assert line["message"] == "job 7\non mk4"
    assert (line["printer"], line["job"], line["host"]) == ("mk4", 7, "rack1")
    assert line["pid"] == os.getpid()
    assert line["time"].endswith("Z")
    assert datetime.fromisoformat(line["time"].replace("Z", "+00:00"))


def test_values_json_cannot_hold_are_written_as_text():
    class Thing:
        def __str__(self) -> str:
            return "a thing"

    [line] = logged(
        lambda log: log.info("x", extra={"what": Thing(), "list": (1, Thing())})
    )
    assert line["what"] == "a thing"
    assert line["list"] == [1, "a thing"]


def test_an_exception_is_kept_with_its_traceback():
    def emit(log: logging.Logger) -> None:
        try:
            raise ValueError("bad gcode")
        except ValueError:
            log.exception("analysis failed")

    [line] = logged(emit)
    assert line["message"] == "analysis failed"
    assert "ValueError: bad gcode" in line["exception"]
    assert "Traceback" in line["exception"]


def test_the_access_log_becomes_records_of_printhost_access():
    def emit(_: logging.Logger) -> None:
        access = LoggedAccessLog()
        details = {"client": "10.0.0.5:5000", "method": "GET", "path": "/metrics",
                   "status": 200, "size": 512}  # fmt: skip
        access("http", "complete", details)
        access(
            "websocket",
            "connected",
            {"client": "10.0.0.5:5001", "path": "/ws/printers/"},
        )
        access("http", "unknown", details)

    http, websocket = logged(emit, "printhost.access")
    assert http["message"] == "GET /metrics 200 512"
    assert (http["client"], http["status"], http["size"]) == ("10.0.0.5:5000", 200, 512)
    assert websocket["message"] == "WSCONNECT /ws/printers/"
    assert websocket["websocket"] == "connected"


def test_the_access_log_goes_through_logging_in_json_mode_only(settings):
    daphnes = object()
    settings.PRINTHOST_LOG_FORMAT = "text"
    assert access_log(daphnes) is daphnes
    settings.PRINTHOST_LOG_FORMAT = "json"
    assert isinstance(access_log(daphnes), LoggedAccessLog)


@pytest.mark.parametrize(
    ("value", "json_lines"), [("json", True), ("JSON", True), ("text", False)]
)
def test_a_management_command_logs_in_the_chosen_format(value, json_lines, tmp_path):
    code = "import logging; logging.getLogger('printhost.x').info('hi', extra={'printer': 'p1'})"
    result = run_manage(tmp_path, {"PRINTHOST_LOG_FORMAT": value}, "shell", "-c", code)
    assert result.returncode == 0, result.stderr
    [line] = [line for line in result.stderr.splitlines() if "hi" in line]
    if json_lines:
        assert json.loads(line)["printer"] == "p1"
    else:
        assert line.endswith("INFO printhost.x: hi")


def test_an_unknown_format_stops_the_start_with_the_variable_named(tmp_path):
    result = run_manage(tmp_path, {"PRINTHOST_LOG_FORMAT": "xml"}, "check")
    assert result.returncode != 0
    assert "PRINTHOST_LOG_FORMAT='xml'" in result.stderr
    assert "json, text" in result.stderr


def run_manage(tmp_path, env: dict, *args: str) -> subprocess.CompletedProcess:
    environment = {**os.environ, "PRINTHOST_DATA_DIR": str(tmp_path), **env}
    return subprocess.run(
        [sys.executable, "manage.py", *args], cwd=ROOT, env=environment,
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
