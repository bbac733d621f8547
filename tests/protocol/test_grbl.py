"""GrblProtocol: bytes and time in, bytes and events out; a fake GRBL checks the wire."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from printers.protocol.errors import CommandRejected, LocalProtocolError
from printers.protocol.events import (
    Ack,
    Alarm,
    CommandFailed,
    Event,
    FirmwareMessage,
    FirmwareReset,
    LineKind,
    LinkFailed,
    Received,
    Sent,
    StatusReport,
)
from printers.protocol.grbl import GrblProtocol
from printers.protocol.grbl_codes import ALARMS, REALTIME_COMMANDS
from printers.protocol.grbl_events import Locked, ProgramEnd

if TYPE_CHECKING:
    from printers.protocol.link import LinkProtocol

BANNER = b"Grbl 1.1h ['$' for help]\r\n"
EEPROM_WRITES = [
    "$100=250.000",
    "$N0=G20 G54",
    "$N1=",
    "$I=shop router",
    "$RST=$",
    "$rst=*",
    "G10 L2 P1 X0 Y0",
    "G10L20P1X0",
    "G28.1",
    "G30.1",
]
PLAIN_LINES = ["$$", "$H", "$X", "$#", "$N", "$J=G91 X1 F100", "G28", "G30", "G10 L200"]


def make(**options: object) -> GrblProtocol:
    """A protocol that does not poll, so tests see only the bytes they cause."""
    options.setdefault("status_interval", None)
    return GrblProtocol(**options)  # type: ignore[arg-type]


def drain(protocol: GrblProtocol) -> list[Event]:
    events = []
    while (event := protocol.next_event()) is not None:
        events.append(event)
    return events


def meanings(protocol: GrblProtocol) -> list[Event]:
    """Events without the Received/Sent log lines."""
    return [e for e in drain(protocol) if not isinstance(e, Received | Sent)]


def fill(protocol: GrblProtocol, text: str, now: float = 0.0) -> int:
    """Send *text* until the window is full; returns how many went."""
    count = 0
    while protocol.can_send(text):
        protocol.send(text, now, tag=count)
        count += 1
    return count


# -- a fake GRBL: the serial side of gnea/grbl, as far as streaming can tell ----------


class FakeGrbl:
    """A 128-byte RX ring that drops overflow, realtime bytes taken off at once,
    one answer per line, and an RX interrupt that is off while EEPROM is written."""

    RING = 128

    def __init__(self, *, eeprom_ticks: int = 1) -> None:
        self.eeprom_ticks = eeprom_ticks
        self.wire = bytearray()  # written by the host, not arrived yet
        self.ring = bytearray()
        self.output = bytearray()
        self.executed: list[str] = []
        self.dropped = 0  # command bytes lost: the host broke a rule
        self.deaf_ticks = 0  # an EEPROM write is going on

    def tick(self, arriving: int, lines: int) -> None:
        """*arriving* bytes come off the wire, then up to *lines* lines run."""
        self.receive(bytes(self.wire[:arriving]))
        del self.wire[:arriving]
        self.work(lines)

    def receive(self, data: bytes) -> None:
        for byte in data:
            if self.deaf_ticks:
                if byte != ord("?"):  # a lost poll is harmless: the host asks again
                    self.dropped += 1
            elif byte == ord("?"):
                free = self.RING - len(self.ring)
                state = "Run" if self.ring else "Idle"
                self.output += f"<{state}|MPos:0,0,0|Bf:15,{free}>\r\n".encode()
            elif byte in b"!~\x18" or byte >= 0x80:
                continue
            elif len(self.ring) >= self.RING:
                self.dropped += 1
            else:
                self.ring.append(byte)

    def work(self, lines: int) -> None:
        """Execute up to *lines* whole lines; an EEPROM write takes a few ticks."""
        if self.deaf_ticks:
            self.deaf_ticks -= 1
            if not self.deaf_ticks:
                self.output += b"ok\r\n"
            return
        for _ in range(lines):
            end = self.ring.find(b"\n")
            if end < 0:
                return
            line = self.ring[:end].decode()
            del self.ring[: end + 1]
            self.executed.append(line)
            if line in WIRE_EEPROM_WRITES:
                self.deaf_ticks = self.eeprom_ticks
                return
            self.output += b"error:20\r\n" if line == "M999" else b"ok\r\n"
            self.output += b"[MSG:Pgm End]\r\n" if line == "M2" else b""

    def take(self, size: int) -> bytes:
        chunk = bytes(self.output[:size])
        del self.output[:size]
        return chunk


def as_wire(text: str) -> str:
    """What compact mode should make of *text*, worked out independently."""
    text = text.strip()
    if text.startswith("$") or "(" in text:
        return text
    return text.replace(" ", "")


WIRE_EEPROM_WRITES = {as_wire(text) for text in EEPROM_WRITES}


@dataclass(frozen=True)
class Pace:
    """How fast things move per worker turn: serial both ways and GRBL's work."""

    workloads: list[int]  # lines GRBL runs per turn, cycled
    wire_chunk: int  # bytes that reach GRBL per turn
    reply_chunk: int  # bytes that reach the host per turn


def stream(
    protocol: GrblProtocol, grbl: FakeGrbl, lines: list[str], pace: Pace
) -> tuple[list[str], list[object], list[object]]:
    """Run the worker loop until every line is answered; returns what it saw."""
    todo = deque(enumerate(lines))
    sent: list[str] = []
    answered: tuple[list[object], list[object]] = ([], [])
    now = 0.0
    for step in range(20_000):
        now += 0.01
        protocol.receive_data(grbl.take(pace.reply_chunk), now)
        for event in drain(protocol):
            if isinstance(event, Ack | CommandFailed):
                answered[isinstance(event, CommandFailed)].append(event.tag)
            elif isinstance(event, Sent) and not event.text.startswith("<"):
                sent.append(event.text)
            assert not isinstance(event, LinkFailed)
        while todo and protocol.can_send(todo[0][1]):
            tag, text = todo.popleft()
            protocol.send(text, now, tag=tag)
        grbl.wire += protocol.data_to_send()
        grbl.tick(pace.wire_chunk, pace.workloads[step % len(pace.workloads)])
        if grbl.dropped or (not todo and not protocol.in_flight):
            break
    return sent, *answered


gcode_lines = st.one_of(
    # Short lines of many sizes pack the window tightly: an overflow shows at once.
    st.integers(0, 10**6).map("G1X{}".format),
    st.sampled_from(["M5", "G91", "G0X1Y2Z3", "G4P0"]),
    st.builds(
        "G1 X{:.3f} Y{:.3f} F{}".format,
        st.floats(-999, 999),
        st.floats(-999, 999),
        st.integers(1, 9000),
    ),
    st.text(alphabet="GMXYZF0123456789.- ", min_size=1, max_size=79).filter(str.strip),
    st.text(alphabet="XYZ0123456789 ", max_size=60).map(lambda t: f"G0 {t} (note)"),
    st.sampled_from(EEPROM_WRITES),
    st.sampled_from(["M999", "M2", "$$"]),
)


@settings(max_examples=40, deadline=None, database=None)
@given(
    lines=st.lists(gcode_lines, min_size=10, max_size=80),
    pace=st.builds(
        Pace,
        # Idle turns and an instant wire fill GRBL's ring up to what is in flight.
        workloads=st.lists(st.sampled_from([0, 0, 1, 2, 3]), max_size=12).map(
            lambda w: [*w, 1]
        ),
        wire_chunk=st.one_of(st.just(1000), st.integers(1, 140)),
        reply_chunk=st.integers(1, 80),
    ),
    eeprom_ticks=st.integers(1, 4),
)
def test_character_counting_never_overflows_grbl(
    lines: list[str], pace: Pace, eeprom_ticks: int
) -> None:
    grbl = FakeGrbl(eeprom_ticks=eeprom_ticks)
    protocol = GrblProtocol(status_interval=0.03)
    sent, acked, failed = stream(protocol, grbl, lines, pace)
    assert grbl.dropped == 0
    assert grbl.executed == sent == [as_wire(text) for text in lines]
    assert sorted(acked + failed) == list(range(len(lines)))
    assert acked == sorted(acked)
    assert failed == [tag for tag, text in enumerate(lines) if text == "M999"]
    assert protocol.lines_sent == len(lines)


def test_the_fake_grbl_catches_a_host_that_overflows_it() -> None:
    grbl = FakeGrbl()
    greedy = GrblProtocol(rx_buffer=400, status_interval=None)
    lines = ["G1 X100.000 Y100.000 F3000"] * 40
    stream(greedy, grbl, lines, Pace([0, 0, 1], wire_chunk=500, reply_chunk=80))
    assert grbl.dropped > 0


def test_the_fake_grbl_loses_bytes_sent_during_an_eeprom_write() -> None:
    grbl = FakeGrbl(eeprom_ticks=2)
    grbl.wire += b"$100=250.000\nG0X0\n?"
    grbl.tick(13, lines=1)
    grbl.tick(6, lines=1)
    assert grbl.dropped == 5  # G0X0 and its newline; the `?` is not counted
    grbl.tick(0, lines=1)
    assert grbl.output == b"ok\r\n"


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
