"""GrblProtocol's realtime bytes, status polling and timeouts: bytes and time in,
bytes and events out."""

from __future__ import annotations

import pytest

from printers.protocol.errors import LocalProtocolError
from printers.protocol.events import (
    Ack,
    FirmwareReset,
    LinkFailed,
    Received,
    Sent,
    StatusReport,
)
from printers.protocol.grbl import GrblProtocol
from printers.protocol.grbl_codes import REALTIME_COMMANDS
from printers.protocol.grbl_events import Locked
from tests.protocol.grbl_helpers import (
    BANNER,
    drain,
    fill,
    make,
    meanings,
)

# -- realtime bytes ------------------------------------------------------------------


def test_realtime_bytes_go_first_even_with_the_window_full() -> None:
    protocol = make()
    count = fill(protocol, "G1X1")
    protocol.send_emergency("!", 0.0)
    protocol.send_emergency("\x85", 0.0)
    wire = protocol.data_to_send()
    assert wire == b"!\x85" + b"G1X1\n" * count
    assert drain(protocol)[:3] == [
        Sent("<! feed hold>"),
        Sent("<0x85 jog cancel>"),
        Sent("G1X1"),
    ]
    assert not protocol.can_send("G1X1")
    protocol.receive_data(b"ok\n", 0.1)
    assert protocol.can_send("G1X1")  # one line freed, the realtime bytes cost nothing
    protocol.send("G1X1", 0.1)
    assert not protocol.can_send("G1X1")


@pytest.mark.parametrize("char", sorted(REALTIME_COMMANDS))
def test_every_realtime_command_is_one_byte(char: str) -> None:
    protocol = make()
    protocol.send_emergency(char, 0.0)
    assert protocol.data_to_send() == bytes([ord(char)])
    (sent,) = drain(protocol)
    assert sent.text.startswith("<") and REALTIME_COMMANDS[char] in sent.text


@pytest.mark.parametrize("text", ["", "x", "!!", "\x19", "\x98\x99", "M112", "G1X1"])
def test_send_emergency_takes_realtime_commands_only(text: str) -> None:
    with pytest.raises(LocalProtocolError, match="not a GRBL realtime command"):
        make().send_emergency(text, 0.0)


def test_soft_reset_drops_unwritten_lines_and_waits_for_the_banner() -> None:
    protocol = make()
    protocol.send("G0X1", 0.0, tag="written")
    protocol.data_to_send()
    protocol.send("G0X2", 0.0, tag="unwritten")
    protocol.send_emergency("\x18", 0.1)
    assert protocol.data_to_send() == b"\x18"
    assert drain(protocol) == [Sent("G0X1"), Sent("<0x18 soft reset>")]
    assert protocol.in_flight == 1
    assert not protocol.can_send("G0X3")
    with pytest.raises(LocalProtocolError, match="soft reset"):
        protocol.send("G0X3", 0.2)
    protocol.receive_data(BANNER + b"[MSG:'$H'|'$X' to unlock]\r\n", 0.3)
    assert meanings(protocol) == [
        FirmwareReset("Grbl 1.1h ['$' for help]"),
        Locked("'$H'|'$X' to unlock"),
    ]
    assert protocol.in_flight == 0
    assert protocol.can_send("G0X3")


def test_a_soft_reset_without_banner_fails_the_link_once() -> None:
    protocol = make(ack_timeout=5.0)
    protocol.send("G0X1", 0.0)
    protocol.data_to_send()
    protocol.send_emergency("\x18", 1.0)
    protocol.data_to_send()
    assert protocol.next_deadline() == 6.0
    protocol.handle_timeout(5.9)
    assert meanings(protocol) == []
    protocol.handle_timeout(6.0)
    assert meanings(protocol) == [
        LinkFailed(
            "GRBL did not restart within 5 s of a soft reset (no welcome banner)"
        )
    ]
    protocol.handle_timeout(60.0)
    assert meanings(protocol) == []
    assert protocol.next_deadline() is None
    protocol.abandon()
    assert protocol.can_send("G0X1")


# -- status polling ------------------------------------------------------------------


def test_it_polls_status_at_the_interval() -> None:
    protocol = GrblProtocol(status_interval=0.2)
    assert protocol.data_to_send() == b""  # no time seen yet
    assert protocol.next_deadline() is None
    protocol.receive_data(b"", 0.0)
    assert protocol.next_deadline() == 0.0
    assert protocol.data_to_send() == b"?"
    protocol.receive_data(b"<Idle|MPos:0,0,0>\r\n", 0.01)
    assert protocol.next_deadline() == pytest.approx(0.2)
    protocol.receive_data(b"", 0.19)
    assert protocol.data_to_send() == b""
    protocol.handle_timeout(0.2)
    assert protocol.data_to_send() == b"?"
    assert [type(e) for e in drain(protocol)] == [Received, StatusReport]  # no Sent


def test_it_does_not_repeat_a_poll_while_one_is_pending() -> None:
    protocol = GrblProtocol(status_interval=0.2)
    protocol.receive_data(b"", 0.0)
    assert protocol.data_to_send() == b"?"
    assert protocol.next_deadline() == pytest.approx(1.0)
    for now in (0.2, 0.4, 0.99):
        protocol.handle_timeout(now)
        assert protocol.data_to_send() == b""
    protocol.handle_timeout(1.0)
    assert protocol.data_to_send() == b"?"  # the first one was lost: ask again
    protocol.send_emergency("?", 1.5)
    assert protocol.data_to_send() == b"?"  # asked for explicitly: goes anyway
    protocol.handle_timeout(2.0)
    assert protocol.data_to_send() == b""  # that explicit one is pending now


def test_polls_are_not_counted_in_the_window() -> None:
    protocol = GrblProtocol(status_interval=0.2)
    protocol.send("G1" + "X1" * 38, 0.0)
    protocol.send("G0" + "Y2" * 22, 0.0)  # 80 + 47 = 127 bytes: full
    assert protocol.data_to_send().startswith(b"?G1X1")
    assert protocol.in_flight == 2


def test_no_polls_without_an_interval() -> None:
    protocol = make()
    protocol.receive_data(b"", 0.0)
    protocol.handle_timeout(100.0)
    assert protocol.data_to_send() == b""
    assert protocol.next_deadline() is None


# -- timeouts ------------------------------------------------------------------------


def test_a_missing_answer_fails_the_link_once() -> None:
    protocol = make(ack_timeout=10.0)
    protocol.send("G1 X1 F100", 2.0, tag=1)
    protocol.data_to_send()
    assert protocol.next_deadline() == 12.0
    protocol.handle_timeout(11.99)
    assert meanings(protocol) == []
    protocol.handle_timeout(12.0)
    (failure,) = meanings(protocol)
    assert isinstance(failure, LinkFailed)
    assert failure.message.startswith("GRBL did not answer 'G1X1F100' within 10 s")
    protocol.handle_timeout(30.0)
    assert meanings(protocol) == []
    assert protocol.next_deadline() is None


@pytest.mark.parametrize(
    "state", ["Run", "Jog", "Home", "Hold:0", "Hold:1", "Door:1", "Check"]
)
def test_a_working_status_keeps_a_long_move_alive(state: str) -> None:
    protocol = make(ack_timeout=10.0)
    protocol.send("G1X500F50", 0.0, tag=1)
    protocol.data_to_send()
    protocol.receive_data(f"<{state}|MPos:1,0,0>\r\n".encode(), 9.0)
    assert protocol.next_deadline() == 19.0
    protocol.handle_timeout(15.0)
    assert meanings(protocol) == [StatusReport(state, {"MPos": "1,0,0"})]
    protocol.receive_data(b"ok\r\n", 18.0)
    assert meanings(protocol) == [Ack(1)]


@pytest.mark.parametrize("state", ["Idle", "Alarm", "Sleep"])
def test_a_resting_status_is_no_progress(state: str) -> None:
    protocol = make(ack_timeout=10.0)
    protocol.send("G1X500F50", 0.0, tag=1)
    protocol.data_to_send()
    protocol.receive_data(f"<{state}|MPos:1,0,0>\r\n".encode(), 9.0)
    assert protocol.next_deadline() == 10.0
    protocol.handle_timeout(10.0)
    assert isinstance(meanings(protocol)[-1], LinkFailed)


def test_each_answer_restarts_the_clock() -> None:
    protocol = make(ack_timeout=10.0)
    protocol.send("G0X1", 0.0, tag=1)
    protocol.send("G0X2", 0.0, tag=2)
    protocol.data_to_send()
    protocol.receive_data(b"ok\n", 8.0)
    assert protocol.next_deadline() == 18.0


def test_a_dwell_extends_the_deadline() -> None:
    protocol = make(ack_timeout=10.0)
    protocol.send("G4 P15", 0.0, tag="dwell")
    protocol.data_to_send()
    assert protocol.next_deadline() == 25.0
    protocol.handle_timeout(20.0)
    assert meanings(protocol) == []


def test_polling_and_ack_deadlines_combine() -> None:
    protocol = GrblProtocol(status_interval=0.2, ack_timeout=10.0)
    protocol.send("G0X1", 0.0)
    protocol.data_to_send()
    assert protocol.next_deadline() == pytest.approx(1.0)  # poll pending: retry at 1 s
    protocol.receive_data(b"<Run|MPos:0,0,0>\r\n", 0.05)
    assert protocol.next_deadline() == pytest.approx(0.2)
