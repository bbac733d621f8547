"""parse_response against real Marlin, Prusa and Repetier wording."""

from __future__ import annotations

import pytest

from printers.protocol.events import (
    ActionCommand,
    Busy,
    Capability,
    FirmwareError,
    FirmwareHalted,
    FirmwareInfo,
    FirmwareMessage,
    FirmwareReset,
    LineKind,
    TemperatureReport,
)
from printers.protocol.marlin_responses import (
    ReplyKind,
    parse_response,
    parse_temperatures,
)

ACK, IMPORTANT, RESPONSE = LineKind.ACK, LineKind.IMPORTANT, LineKind.RESPONSE

# line, kind, line kind, number
CLASSIFIED = [
    ("ok", ReplyKind.OK, ACK, None),
    ("ok ", ReplyKind.OK, ACK, None),
    ("ok N12 P15 B3", ReplyKind.OK, ACK, 12),
    ("ok P15 B3", ReplyKind.OK, ACK, None),
    ("ok 1234", ReplyKind.OK, ACK, 1234),
    ("ok T:210.00 /210.00 B:60.00 /60.00 @:127 B@:0", ReplyKind.OK, ACK, None),
    ("Resend: 5", ReplyKind.RESEND, IMPORTANT, 5),
    ("Resend:5", ReplyKind.RESEND, IMPORTANT, 5),
    ("Resend:N5", ReplyKind.RESEND, IMPORTANT, 5),
    ("rs 17", ReplyKind.RESEND, IMPORTANT, 17),
    ("rs N17", ReplyKind.RESEND, IMPORTANT, 17),
    ("skip 42", ReplyKind.SKIP, IMPORTANT, 42),
    ("wait", ReplyKind.WAIT, ACK, None),
    ("echo:busy: processing", ReplyKind.BUSY, RESPONSE, None),
    ("echo:busy: paused for user", ReplyKind.BUSY, RESPONSE, None),
    ("echo:busy: paused for input", ReplyKind.BUSY, RESPONSE, None),
    ("busy: processing", ReplyKind.BUSY, RESPONSE, None),
    (
        "Error:Line Number is not Last Line Number+1, Last Line: 41",
        ReplyKind.LINE_NUMBER_ERROR,
        IMPORTANT,
        41,
    ),
    # Repetier names the line it wants: its last good line is one before.
    ("Error:expected line 42 got 44", ReplyKind.LINE_NUMBER_ERROR, IMPORTANT, 41),
    ("Error:Wrong checksum", ReplyKind.CHECKSUM_ERROR, IMPORTANT, None),
    ("Error:Missing checksum", ReplyKind.CHECKSUM_ERROR, IMPORTANT, None),
    ("Error:Format error", ReplyKind.CHECKSUM_ERROR, IMPORTANT, None),
    (
        "Error:No Line Number with checksum, Last Line: 7",
        ReplyKind.CHECKSUM_ERROR,
        IMPORTANT,
        7,
    ),
    # Garbled by line noise on the way back: still a line error, never fatal.
    ("Error:checksum mizmatch, Last Line: 7", ReplyKind.CHECKSUM_ERROR, IMPORTANT, 7),
    (
        "Error:Line Numbxr is not Last Line Number+1, Last Line: 3",
        ReplyKind.CHECKSUM_ERROR,
        IMPORTANT,
        3,
    ),
    ("Error:chec\ufffdsum mismatch", ReplyKind.CHECKSUM_ERROR, IMPORTANT, None),
    ("Error:ch", ReplyKind.CHECKSUM_ERROR, IMPORTANT, None),
    ("Error:Line Nu", ReplyKind.CHECKSUM_ERROR, IMPORTANT, None),
    ("Error:Wrong chec4sum", ReplyKind.CHECKSUM_ERROR, IMPORTANT, None),
    ("Error:Probing failed", ReplyKind.ERROR, IMPORTANT, None),
    ("Error:Printer halted. kill() called!", ReplyKind.HALT, IMPORTANT, None),
    ("Error:checksus mi", ReplyKind.CHECKSUM_ERROR, IMPORTANT, None),
    ("Error:", ReplyKind.CHECKSUM_ERROR, IMPORTANT, None),
    ("Printer halted. kill() called!", ReplyKind.HALT, IMPORTANT, None),
    ("R?send: 304", ReplyKind.RESEND, IMPORTANT, None),
    ("Resen\ufffd: 304", ReplyKind.RESEND, IMPORTANT, None),
    (
        "Erro:checksum mismatch, Last Line: 305",
        ReplyKind.CHECKSUM_ERROR,
        IMPORTANT,
        None,
    ),
    ("Reset: done", ReplyKind.OTHER, RESPONSE, None),
    ("rs N12", ReplyKind.RESEND, IMPORTANT, 12),
    ("Resend:12", ReplyKind.RESEND, IMPORTANT, 12),
    (
        "Error:checksum mismatch, Last Line: 41",
        ReplyKind.CHECKSUM_ERROR,
        IMPORTANT,
        41,
    ),
    (
        "Error:No Checksum with line number, Last Line: 7",
        ReplyKind.CHECKSUM_ERROR,
        IMPORTANT,
        7,
    ),
    ("Error:No Line Number with checksum", ReplyKind.CHECKSUM_ERROR, IMPORTANT, None),
    ("Error:Format error", ReplyKind.CHECKSUM_ERROR, IMPORTANT, None),
    ("Error:Printer halted. kill() called!", ReplyKind.HALT, IMPORTANT, None),
    (
        "Error:Printer stopped due to errors. Fix the error and use M999 to restart.",
        ReplyKind.HALT,
        IMPORTANT,
        None,
    ),
    (
        "Error:Heating failed, system stopped! Heater_ID: 0",
        ReplyKind.HALT,
        IMPORTANT,
        None,
    ),
    (
        "Error:Thermal Runaway, system stopped! Heater_ID: bed",
        ReplyKind.HALT,
        IMPORTANT,
        None,
    ),
    ("Error:Thermal Malfunction", ReplyKind.HALT, IMPORTANT, None),
    (
        "Error:MAXTEMP triggered, system stopped! Heater_ID: 0",
        ReplyKind.HALT,
        IMPORTANT,
        None,
    ),
    (
        "Error:MINTEMP triggered, system stopped! Heater_ID: 0",
        ReplyKind.HALT,
        IMPORTANT,
        None,
    ),
    ("Error:KILL caused by KILL button/pin", ReplyKind.HALT, IMPORTANT, None),
    ("Error:Watchdog barked, system restarting", ReplyKind.HALT, IMPORTANT, None),
    ("!! Thermal runaway", ReplyKind.HALT, IMPORTANT, None),
    ("fatal: SD card gone", ReplyKind.HALT, IMPORTANT, None),
    ("Error:Probing failed", ReplyKind.ERROR, IMPORTANT, None),
    ("start", ReplyKind.START, IMPORTANT, None),
    ("//action:pause", ReplyKind.ACTION, IMPORTANT, None),
    ("T:210.00 /210.00 B:60.00 /60.00 @:127 B@:0", ReplyKind.TEMPERATURE, ACK, None),
    ("T:24.2 E:0 W:?", ReplyKind.TEMPERATURE, ACK, None),
    ("FIRMWARE_NAME:Marlin 2.1.2.1", ReplyKind.FIRMWARE_INFO, RESPONSE, None),
    ("Cap:AUTOREPORT_TEMP:1", ReplyKind.CAPABILITY, RESPONSE, None),
    ('echo:Unknown command: "G999"', ReplyKind.ECHO, RESPONSE, None),
    ("Marlin 2.1.2.1", ReplyKind.OTHER, RESPONSE, None),
    ("Cap:garbage", ReplyKind.OTHER, RESPONSE, None),
    ("Resend: soon", ReplyKind.OTHER, RESPONSE, None),
]


@pytest.mark.parametrize(("line", "kind", "line_kind", "number"), CLASSIFIED)
def test_it_classifies(
    line: str, kind: ReplyKind, line_kind: LineKind, number: int | None
) -> None:
    reply = parse_response(line)
    assert (reply.kind, reply.line_kind, reply.number) == (kind, line_kind, number)
    assert reply.text == line.strip()


def test_plain_ok_takes_the_fast_path() -> None:
    assert parse_response("ok") is parse_response("ok")


def test_advanced_ok_carries_planner_and_buffer_room() -> None:
    reply = parse_response("ok N1043 P15 B3")
    assert (reply.number, reply.planner_free, reply.buffer_free) == (1043, 15, 3)
    assert reply.advanced
    assert not parse_response("ok 1043").advanced  # Repetier's ok <n> is not


@pytest.mark.parametrize(
    ("line", "event"),
    [
        ("echo:busy: processing", Busy("processing")),
        ("echo:busy: paused for user", Busy("paused for user")),
        ("Error:Probing failed", FirmwareError("Probing failed")),
        (
            "Error:Printer halted. kill() called!",
            FirmwareHalted("Printer halted. kill() called!"),
        ),
        ("!! kill()", FirmwareHalted("kill()")),
        ("fatal: SD init fail", FirmwareHalted("SD init fail")),
        ("start", FirmwareReset("start")),
        ("//action:pause", ActionCommand("pause", "")),
        (
            "//action:prompt_begin Filament runout",
            ActionCommand("prompt_begin", "Filament runout"),
        ),
        ("Cap:EMERGENCY_PARSER:0", Capability("EMERGENCY_PARSER", enabled=False)),
        ("Cap:AUTOREPORT_TEMP:1", Capability("AUTOREPORT_TEMP", enabled=True)),
        ("echo:SD card ok", FirmwareMessage("SD card ok")),
        ("Marlin 2.1.2.1", FirmwareMessage("Marlin 2.1.2.1")),
    ],
)
def test_meaning_events(line: str, event: object) -> None:
    assert parse_response(line).event == event


def test_resend_flow_errors_carry_no_event() -> None:
    assert parse_response("Error:checksum mismatch, Last Line: 3").event is None


def test_m115_first_line() -> None:
    line = (
        "FIRMWARE_NAME:Marlin 2.1.2.1 (Aug  8 2023 12:00:00) "
        "SOURCE_CODE_URL:github.com/MarlinFirmware/Marlin PROTOCOL_VERSION:1.0 "
        "MACHINE_TYPE:Ender-3 V2 EXTRUDER_COUNT:1 "
        "UUID:cede2a2f-41a2-4748-9b12-c55c62f367ff"
    )
    assert parse_response(line).event == FirmwareInfo(
        "Marlin 2.1.2.1 (Aug  8 2023 12:00:00)",
        {
            "SOURCE_CODE_URL": "github.com/MarlinFirmware/Marlin",
            "PROTOCOL_VERSION": "1.0",
            "MACHINE_TYPE": "Ender-3 V2",
            "EXTRUDER_COUNT": "1",
            "UUID": "cede2a2f-41a2-4748-9b12-c55c62f367ff",
        },
    )


def test_m115_name_ends_at_the_next_key() -> None:
    line = (
        "FIRMWARE_NAME:Prusa-Firmware 3.13.2 based on Marlin "
        "FIRMWARE_URL:https://github.com/prusa3d/Prusa-Firmware PROTOCOL_VERSION:1.0"
    )
    info = parse_response(line).event
    assert isinstance(info, FirmwareInfo)
    assert info.name == "Prusa-Firmware 3.13.2 based on Marlin"
    assert info.fields["FIRMWARE_URL"] == "https://github.com/prusa3d/Prusa-Firmware"


@pytest.mark.parametrize(
    ("line", "readings"),
    [
        (
            "T:210.00 /210.00 B:60.00 /60.00 T0:210.00 /210.00 @:127 B@:0",
            {"T0": (210.0, 210.0), "B": (60.0, 60.0)},
        ),
        (
            "T:200.0 /200.0 B:55.5 /60.0 T0:200.0 /200.0 T1:25.3 /0.0 @:0 B@:0",
            {"T0": (200.0, 200.0), "T1": (25.3, 0.0), "B": (55.5, 60.0)},
        ),
        (
            "T:21.5 /0.0 B:20.1 /0.0 C:30.0 /35.0",
            {"T0": (21.5, 0.0), "B": (20.1, 0.0), "C": (30.0, 35.0)},
        ),
        ("T:24.2 E:0 W:?", {"T0": (24.2, None)}),
        ("T:210.0/215.0 B:60/60", {"T0": (210.0, 215.0), "B": (60.0, 60.0)}),
        ("B:60.00 /60.00 @:0 B@:0", {"B": (60.0, 60.0)}),
    ],
)
def test_temperatures(
    line: str, readings: dict[str, tuple[float, float | None]]
) -> None:
    assert parse_temperatures(line) == readings
    event = parse_response(line).event
    assert isinstance(event, TemperatureReport)
    assert event.readings == readings


def test_ok_with_temperatures_reports_them() -> None:
    reply = parse_response("ok T:210.00 /210.00 B:60.00 /60.00 @:127 B@:0")
    assert reply.kind is ReplyKind.OK
    assert reply.event == TemperatureReport({"T0": (210.0, 210.0), "B": (60.0, 60.0)})


def test_power_and_wait_fields_are_not_sensors() -> None:
    assert parse_temperatures("T:1 /2 @:127 B@:64 W:3") == {"T0": (1.0, 2.0)}


@pytest.mark.parametrize(
    "raw",
    [
        # RepRapFirmware sends its degree sign in UTF-8; the simulator's latin-1.
        b"Error: Heater 1 fault: temperature rising much more slowly than the "
        b"expected 1.5\xc2\xb0C/sec",
        b"Error: Heater 1 fault: temperature excursion exceeded 15.0\xb0C",
    ],
)
def test_a_readable_error_with_a_degree_sign_is_the_firmwares_not_noise(
    raw: bytes,
) -> None:
    """Decoded as the protocol decodes a line: one stray symbol in a readable
    message is a firmware error (the job stops), not a garbled line error."""
    text = raw.decode("utf-8", errors="replace").strip()
    reply = parse_response(text)
    assert reply.kind is ReplyKind.ERROR
    assert isinstance(reply.event, FirmwareError)
    assert "Heater 1 fault" in reply.event.message


def test_an_error_line_mostly_noise_is_still_a_line_error() -> None:
    text = b"Error:\x93\x01\xfe\x81x".decode("utf-8", errors="replace")
    assert parse_response(text).kind is ReplyKind.CHECKSUM_ERROR
