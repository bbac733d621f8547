"""A fake GRBL (the serial side of gnea/grbl, as far as streaming can tell) checks
what GrblProtocol writes: character counting never overflows it, and EEPROM writes
travel alone."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from hypothesis import given, settings
from hypothesis import strategies as st

from printers.protocol.events import (
    Ack,
    CommandFailed,
    LinkFailed,
    Sent,
)
from printers.protocol.grbl import GrblProtocol
from tests.protocol.grbl_helpers import (
    EEPROM_WRITES,
    as_wire,
    drain,
)

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
