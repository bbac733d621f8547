"""OctoPrint's tool, bed and print head calls: G-code on the command path, 409 where
OctoPrint refuses, 400 with the range for bad values."""

from __future__ import annotations

import json

import pytest

from jobs.models import Job
from printers.models import Printer, QueuedCommand
from printhost.models import AuditEntry
from tests.api.printer_api_helpers import call


def post(path: str, key: str, body: object) -> tuple[int, dict]:
    return call(
        "post", path, key, data=json.dumps(body), content_type="application/json"
    )


def sent() -> list[str]:
    return [row.text for row in QueuedCommand.objects.order_by("id")]


@pytest.mark.parametrize(
    ("path", "body", "gcode"),
    [
        ("tool", {"command": "target", "targets": {"tool0": 215, "tool1": 0}},
         "M104 T0 S215\nM104 T1 S0"),
        ("tool", {"command": "select", "tool": "tool1"}, "T1"),
        ("tool", {"command": "extrude", "amount": 5}, "G91\nG1 E5 F300\nG90"),
        ("tool", {"command": "flowrate", "factor": 95}, "M221 S95"),
        ("bed", {"command": "target", "target": 60}, "M140 S60"),
        ("printhead", {"command": "jog", "x": 10, "y": -2.5, "speed": 1200},
         "G91\nG1 X10 Y-2.5 F1200\nG90"),
        ("printhead", {"command": "jog", "z": 5, "absolute": True}, "G90\nG1 Z5 F3000"),
        ("printhead", {"command": "home", "axes": ["x", "y"]}, "G28 X0 Y0"),
        ("printhead", {"command": "feedrate", "factor": 150}, "M220 S150"),
    ],
)  # fmt: skip
def test_each_call_sends_its_gcode_and_is_audited(
    keys, printer: Printer, path: str, body: dict, gcode: str
) -> None:
    status, _ = post(f"/p/mk3/api/printer/{path}", keys("operator"), body)
    assert status == 204
    assert sent() == [gcode]
    assert AuditEntry.objects.filter(action="command", detail=gcode).exists()


@pytest.mark.parametrize(
    ("path", "body", "message"),
    [
        ("tool", {"command": "target", "targets": {"tool0": 999}}, "from 0 to 450"),
        ("tool", {"command": "target", "targets": {"nozzle": 200}}, "not a tool"),
        ("tool", {"command": "offset", "offsets": {"tool0": 5}}, "not supported"),
        ("tool", {"command": "flowrate", "factor": 300}, "from 75 to 125"),
        ("bed", {"command": "target", "target": "hot"}, "must be a number"),
        ("printhead", {"command": "jog"}, "needs x, y or z"),
        ("printhead", {"command": "home", "axes": ["q"]}, "axes"),
        ("printhead", {"command": "feedrate", "factor": 10}, "from 50 to 200"),
        ("printhead", {"command": "spin"}, "unknown command"),
    ],
)
def test_bad_values_get_400_with_the_range_and_send_nothing(
    keys, printer: Printer, path: str, body: dict, message: str
) -> None:
    status, answer = post(f"/p/mk3/api/printer/{path}", keys("operator"), body)
    assert status == 400
    assert message in json.dumps(answer)
    assert sent() == []


def test_moving_the_head_or_extruder_while_printing_is_409(
    keys, printer: Printer, make_job
) -> None:
    job = make_job(printer, "G28\nG1 X10\n")
    Job.objects.filter(pk=job.pk).update(state=Job.State.PRINTING)
    key = keys("operator")
    for path, body in (
        ("printhead", {"command": "jog", "x": 1}),
        ("printhead", {"command": "home", "axes": ["z"]}),
        ("tool", {"command": "extrude", "amount": 1}),
    ):
        status, _ = post(f"/p/mk3/api/printer/{path}", key, body)
        assert status == 409, path
    # Temperatures may change while printing.
    assert (
        post("/p/mk3/api/printer/bed", key, {"command": "target", "target": 65})[0]
        == 204
    )
    assert sent() == ["M140 S65"]


def test_an_offline_printer_is_409_and_a_viewer_403(keys, printer: Printer) -> None:
    body = {"command": "target", "target": 60}
    assert post("/p/mk3/api/printer/bed", keys("viewer"), body)[0] == 403
    Printer.objects.filter(pk=printer.pk).update(state=Printer.State.OFFLINE)
    status, answer = post("/p/mk3/api/printer/bed", keys("operator"), body)
    assert status == 409
    assert sent() == []


def test_grbl_jogs_with_its_jog_command_and_has_no_heaters(keys, make_printer) -> None:
    make_printer(slug="router", firmware="grbl", state=Printer.State.IDLE)
    key = keys("operator")
    body = {"command": "jog", "x": 5, "speed": 600}
    assert post("/p/router/api/printer/printhead", key, body)[0] == 204
    assert sent() == ["$J=G91 X5 F600"]
    status, _ = post(
        "/p/router/api/printer/bed", key, {"command": "target", "target": 50}
    )
    assert status == 409


def test_temperatures_are_read_per_heater(keys, printer: Printer) -> None:
    Printer.objects.filter(pk=printer.pk).update(
        temperatures={
            "T0": {"current": 200.5, "target": 210},
            "B": {"current": 59, "target": 60},
        }
    )
    status, tools = call("get", "/p/mk3/api/printer/tool", keys("viewer"))
    assert (status, tools) == (
        200,
        {"tool0": {"actual": 200.5, "target": 210, "offset": 0}},
    )
    status, bed = call("get", "/p/mk3/api/printer/bed", keys("viewer"))
    assert bed == {"bed": {"actual": 59, "target": 60, "offset": 0}}


def test_a_doubled_slash_in_the_path_reaches_the_same_call(
    keys, printer: Printer
) -> None:
    """pyoctoprintapi asks for `<base>//api/printer/bed`; OctoPrint's server takes it."""
    body = {"command": "target", "target": 55}
    assert post("/p/mk3//api/printer/bed", keys("operator"), body)[0] == 204
    assert sent() == ["M140 S55"]
