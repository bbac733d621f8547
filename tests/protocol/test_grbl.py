"""GrblProtocol: bytes and time in, bytes and events out; a fake GRBL checks the wire."""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest

from printers.protocol.errors import CommandRejected, LocalProtocolError
from printers.protocol.events import (
    Ack,
    Alarm,
    CommandFailed,
    FirmwareMessage,
    FirmwareReset,
    LineKind,
    Received,
    Sent,
    StatusReport,
)
from printers.protocol.grbl import GrblProtocol
from printers.protocol.grbl_codes import ALARMS
from printers.protocol.grbl_events import ProgramEnd
from tests.protocol.grbl_helpers import (
    BANNER,
    EEPROM_WRITES,
    PLAIN_LINES,
    as_wire,
    drain,
    fill,
    make,
    meanings,
)

if TYPE_CHECKING:
    from printers.protocol.link import LinkProtocol


# -- window and sync rules -----------------------------------------------------------


def test_it_counts_characters_up_to_rx_buffer() -> None:
    protocol = make()
    assert fill(protocol, "G1X1") == 25  # 25 * 5 = 125; a 26th would make 130
    assert protocol.in_flight == 25
    assert not protocol.can_send("G1")  # 125 + 3 = 128
    assert protocol.can_send("G")  # 125 + 2 = 127 still fits
    protocol.send("G", 0.0)
    assert not protocol.can_send("G")
    with pytest.raises(LocalProtocolError, match="0 bytes free"):
        protocol.send("G", 0.0)


def test_offer_queues_only_what_can_send_allows() -> None:
    protocol = make()
    assert fill(protocol, "G1X1") == 25
    assert not protocol.offer("G1", 0.0, tag="full")  # 125 + 3 = 128
    assert protocol.in_flight == 25  # nothing queued
    assert protocol.offer("G", 0.0, tag="fits")  # 125 + 2 = 127
    assert protocol.in_flight == 26
    with pytest.raises(CommandRejected):
        protocol.offer("G1 X1 ~", 0.0)  # a realtime byte inside a line, never taken


@pytest.mark.parametrize("text", EEPROM_WRITES)
def test_offer_holds_an_eeprom_write_until_grbl_settles(text: str) -> None:
    protocol = make()
    protocol.send("G0X0", 0.0, tag="before")
    assert not protocol.offer(text, 0.0, tag="eeprom")
    protocol.data_to_send()
    protocol.receive_data(b"ok\n<Idle|MPos:0,0,0>\n", 0.1)
    assert protocol.offer(text, 0.2, tag="eeprom")
    assert protocol.data_to_send() == (as_wire(text) + "\n").encode()


def test_an_answer_frees_the_bytes_of_the_oldest_line() -> None:
    protocol = make()
    protocol.send("G1" + "X1" * 38, 0.0, tag="long")  # 79 chars, 80 bytes
    protocol.send("G0" + "Y2" * 22, 0.0, tag="short")  # 46 chars, 47 bytes
    protocol.data_to_send()
    assert not protocol.can_send("G4")
    protocol.receive_data(b"ok\r\n", 1.0)
    assert meanings(protocol) == [Ack("long")]
    assert protocol.can_send("G1" + "X1" * 38)  # 47 + 80 = 127
    protocol.send("G1" + "X1" * 38, 1.0)
    assert not protocol.can_send("G")


@pytest.mark.parametrize("text", EEPROM_WRITES)
def test_eeprom_writes_go_ping_pong(text: str) -> None:
    protocol = make()
    protocol.send("G0X0", 0.0, tag="before")
    assert not protocol.can_send(text)
    with pytest.raises(LocalProtocolError, match="nothing else is in flight"):
        protocol.send(text, 0.0, tag="eeprom")
    protocol.data_to_send()
    protocol.receive_data(b"ok\n<Idle|MPos:0,0,0>\n", 0.1)
    assert protocol.can_send(text)
    protocol.send(text, 0.1, tag="eeprom")
    assert protocol.data_to_send() == (as_wire(text) + "\n").encode()
    assert not protocol.can_send("G0X1")
    assert not protocol.can_send("$$")
    protocol.receive_data(b"ok\n", 0.2)
    assert meanings(protocol) == [
        Ack("before"),
        StatusReport("Idle", {"MPos": "0,0,0"}),
        Ack("eeprom"),
    ]
    assert protocol.can_send("G0X1")


@pytest.mark.parametrize("text", PLAIN_LINES)
def test_other_lines_share_the_window(text: str) -> None:
    protocol = make()
    protocol.send("G0X0", 0.0)
    assert protocol.can_send(text)
    protocol.send(text, 0.0)
    assert protocol.can_send("G0X1")


# -- replies -------------------------------------------------------------------------


def test_ok_acks_lines_in_order() -> None:
    protocol = make()
    protocol.send("G0 X1", 0.0, tag="a")
    protocol.send("G0 X2", 0.0, tag="b")
    assert protocol.data_to_send() == b"G0X1\nG0X2\n"
    assert drain(protocol) == [Sent("G0X1"), Sent("G0X2")]
    protocol.receive_data(b"ok\r\nok\r\n", 0.1)
    assert drain(protocol) == [
        Received("ok", LineKind.ACK),
        Ack("a"),
        Received("ok", LineKind.ACK),
        Ack("b"),
    ]
    assert protocol.in_flight == 0


def test_error_fails_the_oldest_line_with_its_meaning() -> None:
    protocol = make()
    protocol.send("G1 X1", 0.0, tag="no feed")
    protocol.send("G0 X0", 0.0, tag="next")
    protocol.data_to_send()
    protocol.receive_data(b"error:22\r\n", 0.1)
    assert drain(protocol)[-2:] == [
        Received("error:22", LineKind.IMPORTANT),
        CommandFailed("no feed", "error:22 no feed rate has been set", code=22),
    ]
    assert protocol.in_flight == 1
    protocol.receive_data(b"ok\r\n", 0.2)
    assert meanings(protocol) == [Ack("next")]


def test_push_messages_never_consume_an_answer() -> None:
    protocol = make()
    protocol.send("G0X1", 0.0, tag=1)
    protocol.send("G0X2", 0.0, tag=2)
    protocol.data_to_send()
    protocol.receive_data(
        b"[MSG:Pgm End]\r\n<Idle|MPos:0,0,0>\r\nALARM:2\r\n[GC:G0 G54]\r\n"
        b"$0=10\r\n>G20:ok\r\nok\r\n",
        0.1,
    )
    assert meanings(protocol) == [
        ProgramEnd(),
        StatusReport("Idle", {"MPos": "0,0,0"}),
        Alarm(2, f"ALARM:2 {ALARMS[2]}"),
        FirmwareMessage("[GC:G0 G54]"),
        FirmwareMessage("$0=10"),
        FirmwareMessage(">G20:ok"),
        Ack(1),
    ]
    assert protocol.in_flight == 1


def test_alarm_is_important_and_explained() -> None:
    protocol = make()
    protocol.receive_data(b"ALARM:1\r\n", 0.0)
    assert drain(protocol) == [
        Received("ALARM:1", LineKind.IMPORTANT),
        Alarm(1, "ALARM:1 hard limit hit; position is likely lost, home again"),
    ]


def test_banner_reports_a_reset_and_abandons_everything() -> None:
    protocol = make()
    fill(protocol, "G1X1")
    protocol.data_to_send()
    protocol.receive_data(b"ok\r\n", 0.4)
    protocol.send("G1X2", 0.4)  # accepted, not written yet
    protocol.receive_data(BANNER, 0.5)
    assert drain(protocol)[-2:] == [
        Received("Grbl 1.1h ['$' for help]", LineKind.IMPORTANT),
        FirmwareReset("Grbl 1.1h ['$' for help]"),
    ]
    assert protocol.in_flight == 0
    assert protocol.next_deadline() is None
    protocol.receive_data(b"ok\r\n", 0.6)  # nothing can be waiting for this one
    assert drain(protocol) == [Received("ok", LineKind.ACK)]


def test_stale_answers_are_only_logged() -> None:
    protocol = make()
    protocol.send("G0X1", 0.0, tag=1)
    protocol.data_to_send()
    drain(protocol)
    protocol.abandon()
    assert protocol.in_flight == 0
    protocol.receive_data(b"ok\r\nerror:9\r\n", 0.1)
    assert drain(protocol) == [
        Received("ok", LineKind.ACK),
        Received("error:9", LineKind.IMPORTANT),
    ]


def test_an_ok_before_the_line_is_written_acks_nothing() -> None:
    protocol = make()
    protocol.send("G0X1", 0.0, tag=1)
    protocol.receive_data(b"ok\n", 0.0)
    assert meanings(protocol) == []
    assert protocol.in_flight == 1


def test_received_data_is_split_into_lines() -> None:
    protocol = make()
    protocol.send("G0X1", 0.0, tag=1)
    protocol.data_to_send()
    drain(protocol)
    protocol.receive_data(b"o", 0.1)
    protocol.receive_data(b"k\r", 0.1)
    assert drain(protocol) == []
    protocol.receive_data(b"\n\r\n\n  \r\n\xff[MSG:caf\xc3\xa9]\n", 0.2)
    assert drain(protocol) == [
        Received("ok", LineKind.ACK),
        Ack(1),
        Received("\ufffd[MSG:café]", LineKind.RESPONSE),
        FirmwareMessage("\ufffd[MSG:café]"),
    ]


def test_endless_noise_without_newline_is_handed_over() -> None:
    protocol = make()
    protocol.receive_data(b"x" * 1000, 0.0)
    assert drain(protocol) == []
    protocol.receive_data(b"x" * 1000, 0.1)
    assert drain(protocol) == [
        Received("x" * 2000, LineKind.RESPONSE),
        FirmwareMessage("x" * 2000),
    ]


def test_it_keeps_counters_and_the_last_status() -> None:
    protocol = make()
    assert protocol.lines_sent == 0
    assert protocol.last_status is None
    protocol.send("G0X1", 0.0)
    assert protocol.lines_sent == 0  # counted when written
    protocol.data_to_send()
    protocol.receive_data(b"<Run|MPos:1,0,0>\r\n<Hold:1|MPos:2,0,0>\r\n", 0.1)
    assert protocol.lines_sent == 1
    assert protocol.last_status == StatusReport("Hold:1", {"MPos": "2,0,0"})


# -- what a line may be --------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "wire"),
    [
        ("G1 X1 Y2", "G1X1Y2"),
        ("  G0   X0  ", "G0X0"),
        ("g1 x1", "g1x1"),
        ("$N0=G20 G54", "$N0=G20 G54"),
        ("$J=G91 X1 F100", "$J=G91 X1 F100"),
        ("$I=my shop", "$I=my shop"),
        ("G1 X1 (go right)", "G1 X1 (go right)"),
        ('M117 "hi there"', 'M117 "hi there"'),
        ("M117 'hi there'", "M117 'hi there'"),
    ],
)
def test_compact_mode_strips_spaces_from_plain_gcode(text: str, wire: str) -> None:
    protocol = make()
    protocol.receive_data(b"<Idle|MPos:0,0,0>\n", 0.0)  # EEPROM writes wait for it
    drain(protocol)
    protocol.send(text, 0.0)
    assert protocol.data_to_send() == f"{wire}\n".encode()
    assert drain(protocol) == [Sent(wire)]


def test_compact_mode_can_be_turned_off() -> None:
    protocol = make(compact=False)
    protocol.send("G1 X1 Y2", 0.0)
    assert protocol.data_to_send() == b"G1 X1 Y2\n"


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("", "empty"),
        ("   ", "empty"),
        ("G1 X1\n", "printable ASCII"),
        ("G1\tX1", "printable ASCII"),
        ("G1 X1 \x18", "printable ASCII"),
        ("M3 S1000 \x85", "printable ASCII"),
        ("G1 X1 é", "printable ASCII"),
        ("G1 X?", "realtime"),
        ("G1 X1 (stop!)", "realtime"),
        ("~", "realtime"),
        ("G1X" + "1" * 77, "80 characters long; GRBL takes at most 79"),
    ],
)
def test_lines_grbl_cannot_take_are_rejected(text: str, reason: str) -> None:
    protocol = make()
    assert protocol.can_send(
        text
    )  # so that the caller goes on to send() and learns why
    with pytest.raises(CommandRejected, match=reason):
        protocol.send(text, 0.0)
    assert protocol.in_flight == 0


def test_line_length_counts_what_goes_on_the_wire() -> None:
    padded = "G1 " + " ".join(["X1"] * 30)  # 92 characters, 63 compacted
    make().send("G1" + "X" * 77, 0.0)  # exactly 79
    make().send(padded, 0.0)
    with pytest.raises(CommandRejected, match="92 characters"):
        make(compact=False).send(padded, 0.0)
    with pytest.raises(CommandRejected, match="at most 40"):
        make(max_line_length=40).send("G1" + "X" * 39, 0.0)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"rx_buffer": 79}, "rx_buffer"),
        ({"rx_buffer": 100, "max_line_length": 100}, "rx_buffer"),
        ({"max_line_length": 0}, "max_line_length"),
        ({"ack_timeout": 0}, "ack_timeout"),
        ({"ack_timeout": -1.0}, "ack_timeout"),
        ({"status_interval": 0}, "status_interval"),
    ],
)
def test_impossible_settings_are_refused(
    options: dict[str, object], message: str
) -> None:
    with pytest.raises(ValueError, match=message):
        GrblProtocol(**options)  # type: ignore[arg-type]


def test_settings_at_the_limit_are_accepted() -> None:
    protocol = GrblProtocol(rx_buffer=80, max_line_length=79, status_interval=None)
    protocol.send("G1" + "X" * 77, 0.0)
    assert not protocol.can_send("G")


# -- the rest of the contract --------------------------------------------------------


def test_it_keeps_the_link_protocol_contract() -> None:
    protocol: LinkProtocol = make()
    assert protocol.printing is False
    protocol.printing = True
    protocol.reset_line_numbers(0.0)  # GRBL has no line numbers
    assert protocol.data_to_send() == b""
    assert protocol.next_event() is None
    assert protocol.in_flight == 0


def test_abandon_forgets_lines_but_keeps_realtime_bytes() -> None:
    protocol = make()
    protocol.send("G0X1", 0.0)
    protocol.data_to_send()
    protocol.send("G0X2", 0.0)
    protocol.send_emergency("!", 0.0)
    protocol.abandon()
    assert protocol.in_flight == 0
    assert protocol.next_deadline() is None
    assert protocol.data_to_send() == b"!"


@pytest.mark.parametrize("line", ["error:²", "ALARM:¹", "[OPT:V,15,²]"])
def test_a_digit_that_is_not_ascii_is_read_as_text_not_a_crash(line: str) -> None:
    """str.isdigit() takes "²" and "¹", which int() refuses: line noise stopped the
    worker mid-job (its feed hold never written)."""
    grbl = GrblProtocol()
    grbl.receive_data(line.encode() + b"\n", 0.0)
    events = []
    while (event := grbl.next_event()) is not None:
        events.append(event)
    assert events, "nothing was read"
