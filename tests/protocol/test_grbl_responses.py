"""Every GRBL reply read into its response-log kind and meaning."""

from __future__ import annotations

import pytest

from printers.protocol.events import (
    Alarm,
    FirmwareInfo,
    FirmwareMessage,
    FirmwareReset,
    LineKind,
    StatusReport,
)
from printers.protocol.grbl_codes import (
    ALARMS,
    ERRORS,
    REALTIME_COMMANDS,
    alarm_meaning,
    error_meaning,
    line_traits,
)
from printers.protocol.grbl_events import (
    BuildOptions,
    CheckMode,
    Locked,
    ProgramEnd,
    Unlocked,
)
from printers.protocol.grbl_responses import Answer, parse_response, parse_status

ACK, RESPONSE, IMPORTANT = LineKind.ACK, LineKind.RESPONSE, LineKind.IMPORTANT

READINGS = [
    ("ok", ACK, Answer()),
    ("error:22", IMPORTANT, Answer(True, 22, "error:22 no feed rate has been set")),
    ("error:9", IMPORTANT, Answer(True, 9, "error:9 " + ERRORS[9])),
    ("error:99", IMPORTANT, Answer(True, 99, "error:99 unknown error code 99")),
    # GRBL 0.9 words its errors instead of numbering them.
    (
        "error: Bad number format",
        IMPORTANT,
        Answer(True, None, "error: Bad number format"),
    ),
    (
        "<Idle|MPos:0.000,0.000,0.000|FS:0,0>",
        ACK,
        StatusReport("Idle", {"MPos": "0.000,0.000,0.000", "FS": "0,0"}),
    ),
    (
        "<Run|MPos:1.500,2.000,0.000|Bf:15,128|FS:500,8000|Ov:100,100,100>",
        ACK,
        StatusReport(
            "Run",
            {
                "MPos": "1.500,2.000,0.000",
                "Bf": "15,128",
                "FS": "500,8000",
                "Ov": "100,100,100",
            },
        ),
    ),
    (
        "<Hold:0|WPos:1.000,2.000,3.000>",
        ACK,
        StatusReport("Hold:0", {"WPos": "1.000,2.000,3.000"}),
    ),
    (
        "<Door:1|MPos:0,0,0|Pn:XD>",
        ACK,
        StatusReport("Door:1", {"MPos": "0,0,0", "Pn": "XD"}),
    ),
    ("<Alarm>", ACK, StatusReport("Alarm", {})),
    (
        "<Idle,MPos:0.000,0.000,0.000,WPos:0.000,0.000,0.000>",
        ACK,
        StatusReport("Idle", {}),
    ),
    ("<Idle|MPos:0.000", RESPONSE, FirmwareMessage("<Idle|MPos:0.000")),
    ("<>", RESPONSE, FirmwareMessage("<>")),
    ("Grbl 1.1h ['$' for help]", IMPORTANT, FirmwareReset("Grbl 1.1h ['$' for help]")),
    ("Grbl 0.9j ['$' for help]", IMPORTANT, FirmwareReset("Grbl 0.9j ['$' for help]")),
    (
        "GrblHAL 1.1f ['$' or '$HELP' for help]",
        IMPORTANT,
        FirmwareReset("GrblHAL 1.1f ['$' or '$HELP' for help]"),
    ),
    ("Grbl is great", RESPONSE, FirmwareMessage("Grbl is great")),
    ("ALARM:1", IMPORTANT, Alarm(1, f"ALARM:1 {ALARMS[1]}")),
    ("ALARM:10", IMPORTANT, Alarm(10, f"ALARM:10 {ALARMS[10]}")),
    ("ALARM:42", IMPORTANT, Alarm(42, "ALARM:42 unknown alarm code 42")),
    ("ALARM: Hard limit", IMPORTANT, Alarm(0, "Hard limit")),
    ("[MSG:Reset to continue]", RESPONSE, FirmwareMessage("Reset to continue")),
    ("[MSG:'$H'|'$X' to unlock]", IMPORTANT, Locked("'$H'|'$X' to unlock")),
    (
        "[VER:1.1h.20190825:my router]",
        RESPONSE,
        FirmwareInfo(
            "Grbl 1.1h.20190825", {"VER": "1.1h.20190825", "INFO": "my router"}
        ),
    ),
    (
        "[VER:1.1h.20190825:]",
        RESPONSE,
        FirmwareInfo("Grbl 1.1h.20190825", {"VER": "1.1h.20190825", "INFO": ""}),
    ),
    (
        "[OPT:V,15,128]",
        RESPONSE,
        BuildOptions("V", 15, 128, {"OPT": "V,15,128"}),
    ),
    (
        "[OPT:VNMSL,35,1024,3,0]",
        RESPONSE,
        BuildOptions("VNMSL", 35, 1024, {"OPT": "VNMSL,35,1024,3,0"}),
    ),
    ("[OPT:VL]", RESPONSE, BuildOptions("VL", None, None, {"OPT": "VL"})),
    (
        "[FIRMWARE:grblHAL]",
        RESPONSE,
        FirmwareInfo("grblHAL", {"FIRMWARE": "grblHAL"}),
    ),
    ("[MSG:Pgm End]", RESPONSE, ProgramEnd()),
    ("[MSG:Enabled]", IMPORTANT, CheckMode(enabled=True)),
    ("[MSG:Disabled]", IMPORTANT, CheckMode(enabled=False)),
    ("[MSG:Caution: Unlocked]", IMPORTANT, Unlocked("Caution: Unlocked")),
    (
        "[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]",
        RESPONSE,
        FirmwareMessage("[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]"),
    ),
    (
        "[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line]",
        RESPONSE,
        FirmwareMessage("[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line]"),
    ),
    (
        "[PRB:0.000,0.000,1.492:1]",
        RESPONSE,
        FirmwareMessage("[PRB:0.000,0.000,1.492:1]"),
    ),
    ("[echo:G1X1]", RESPONSE, FirmwareMessage("[echo:G1X1]")),
    ("[G54:0.000,0.000,0.000]", RESPONSE, FirmwareMessage("[G54:0.000,0.000,0.000]")),
    ("$110=500.000", RESPONSE, FirmwareMessage("$110=500.000")),
    ("$N0=G20", RESPONSE, FirmwareMessage("$N0=G20")),
    (">G54G20:ok", RESPONSE, FirmwareMessage(">G54G20:ok")),
    (">G54G20:error:20", RESPONSE, FirmwareMessage(">G54G20:error:20")),
    # Neither is an answer: only a bare `ok` counts.
    ("okay", RESPONSE, FirmwareMessage("okay")),
    ("ok ok", RESPONSE, FirmwareMessage("ok ok")),
    ("something else", RESPONSE, FirmwareMessage("something else")),
]


@pytest.mark.parametrize(
    ("line", "kind", "meaning"), READINGS, ids=[r[0] for r in READINGS]
)
def test_it_reads_every_reply(line: str, kind: LineKind, meaning: object) -> None:
    response = parse_response(line)
    assert response.kind == kind
    assert response.meaning == meaning


def test_only_ok_and_error_are_answers() -> None:
    answers = [
        line
        for line, _, meaning in READINGS
        if isinstance(parse_response(line).meaning, Answer)
    ]
    assert all(line == "ok" or line.startswith("error:") for line in answers)
    assert len(answers) == 5


@pytest.mark.parametrize("line", ["Idle|MPos:0,0,0>", "<", "<|MPos:0,0,0>", ""])
def test_parse_status_refuses_malformed_reports(line: str) -> None:
    assert parse_status(line) is None


def test_every_grbl_1_1_code_has_a_meaning() -> None:
    assert sorted(ERRORS) == list(range(1, 39))
    assert sorted(ALARMS) == list(range(1, 11))
    assert all(text and "unknown" not in text for text in ERRORS.values())
    assert error_meaning(11) == ERRORS[11]
    assert alarm_meaning(3) == ALARMS[3]
    assert error_meaning(0) == "unknown error code 0"
    assert alarm_meaning(11) == "unknown alarm code 11"


def test_realtime_commands_are_single_bytes_grbl_knows() -> None:
    assert all(len(char) == 1 for char in REALTIME_COMMANDS)
    wire = {char.encode("latin-1") for char in REALTIME_COMMANDS}
    assert {
        b"?",
        b"!",
        b"~",
        b"\x18",
        b"\x84",
        b"\x85",
        b"\x9e",
        b"\xa0",
        b"\xa1",
    } <= wire
    assert {bytes([code]) for code in range(0x90, 0x9E)} <= wire
    assert len(wire) == 23


@pytest.mark.parametrize(
    ("text", "writes"),
    [
        ("$100=250.000", True),
        ("$0=10", True),
        ("$N0=G20 G54", True),
        ("$N1=", True),
        ("$I=my router", True),
        ("$RST=$", True),
        ("$rst=#", True),
        ("G10 L2 P1 X0 Y0", True),
        ("G10L20P1X0", True),
        ("g10 l20 p2 x5", True),
        ("G90 G10 L2 P1 X0", True),
        ("G28.1", True),
        ("G30.1", True),
        ("$$", False),
        ("$N", False),
        ("$H", False),
        ("$J=G91 X1 F100", False),
        ("$C", False),
        ("G10 L200 P1", False),
        ("G10 L1 P1 Z5", False),
        ("G28", False),
        ("G30", False),
        ("G28.2", False),
        ("G1 X28.1", False),
        ("G1 X1 (G10 L2 is not here)", False),
        ("G 10 L 20 P1 X0", True),  # spaces GRBL ignores: the quick screen must too
        ("G010 L2 P1 X0", True),
        ("g28.1", True),
        ("G 30 .1", True),
    ],
)
def test_it_knows_which_commands_write_eeprom(text: str, writes: bool) -> None:
    assert line_traits(text)[0] is writes


@pytest.mark.parametrize(
    ("text", "seconds"),
    [
        ("G4 P15", 15.0),
        ("G4P0.5", 0.5),
        ("G04 P2", 2.0),
        ("g4 p3", 3.0),
        ("G4", 0.0),
        ("G4 P-1", 0.0),
        ("G40", 0.0),
        ("G1 X4 P9", 0.0),
        ("$N0=G4P10", 0.0),
        ("G 4 P7", 7.0),  # spaces GRBL ignores: the quick screen must too
        ("G0004 P8", 8.0),
        ("G+4 P9", 9.0),
        ("G4.0 P1", 1.0),
        ("G1 X1 G4 P2", 2.0),
    ],
)
def test_it_reads_dwell_seconds(text: str, seconds: float) -> None:
    assert line_traits(text)[1] == seconds
