"""MarlinProtocol: bytes in, events out, against a tiny in-test firmware."""

from __future__ import annotations

import pytest

from printers.protocol.checksum import format_line
from printers.protocol.errors import CommandRejected, LocalProtocolError
from printers.protocol.events import (
    Ack,
    FirmwareError,
    FirmwareHalted,
    FirmwareReset,
    LineKind,
    Received,
    Sent,
)
from printers.protocol.marlin import MarlinProtocol
from tests.protocol.marlin_helpers import (
    CHECKSUM_ERROR,
    JOB,
    TinyMarlin,
    acks,
    events,
    exchange,
    meaning,
    run,
    sent_lines,
    streaming,
)

# -- construction, framing, rejection ------------------------------------------------


@pytest.mark.parametrize(
    "options",
    [
        {"checksums": "sometimes"},
        {"flow": "windowed"},
        {"rx_buffer": 0},
        {"bufsize": 0},
        {"max_line_length": 0},
        {"ack_timeout": 0},
        {"busy_timeout": -1},
        {"max_resends": 0},
        {"max_timeouts": -1},
        {"baud": 0},
    ],
)
def test_nonsense_settings_are_refused(options: dict[str, object]) -> None:
    with pytest.raises(ValueError, match=r"must|sizes"):
        MarlinProtocol(**options)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("", "empty"),
        ("   ", "empty"),
        ("M117 Grüße", "ASCII"),
        ("G1 X1\nG1 X2", "ASCII"),
        ("G1 X1\x00", "ASCII"),
        ("M117 " + "x" * 91, "characters"),
        # Framed again as N1 N7 M110 N500*127*62: the firmware's count jumps.
        ("N7 M110 N500*127", "its own line number"),
    ],
)
def test_unsendable_commands_are_rejected(text: str, problem: str) -> None:
    proto = MarlinProtocol(checksums="never")
    with pytest.raises(CommandRejected, match=problem):
        proto.send(text, 0.0)
    assert proto.in_flight == 0
    assert proto.data_to_send() == b""


def test_length_limit_counts_number_and_checksum() -> None:
    text = "M117 " + "x" * 88  # 93 characters: fits bare, not framed as N1 ...*cs
    MarlinProtocol(checksums="never").send(text, 0.0)
    with pytest.raises(CommandRejected, match=r"N1 M117 x+\*\d+"):
        MarlinProtocol(checksums="always").send(text, 0.0)


def test_first_numbered_line_is_preceded_by_m110_which_goes_alone() -> None:
    proto, firmware = MarlinProtocol(checksums="always", flow="buffered"), TinyMarlin()
    proto.send("G28", 0.0, tag="home")
    assert proto.data_to_send() == b"N0 M110 N0*125\n"
    assert not proto.can_send("G1 X1")  # nothing follows an M110 before its ok
    proto.receive_data(b"ok\n", 0.1)
    assert proto.data_to_send() == f"{format_line(1, 'G28')}\n".encode()
    proto.receive_data(firmware.ok(1).encode() + b"\n", 0.2)
    assert acks(events(proto)) == ["home"]  # the M110's ok acks nothing of ours


@pytest.mark.parametrize(
    ("checksums", "printing", "wire"),
    [
        ("always", False, "N1 G28*18"),
        ("never", True, "G28"),
        ("printing", True, "N1 G28*18"),
        ("printing", False, "G28"),
    ],
)
def test_checksum_modes(checksums: str, printing: bool, wire: str) -> None:
    proto = MarlinProtocol(checksums=checksums)
    proto.printing = printing
    log = run(proto, TinyMarlin(), ["G28"])
    assert [e.text for e in sent_lines(log)][-1] == wire
    assert acks(log) == [0]


def test_reset_line_numbers_and_a_user_m110() -> None:
    proto, firmware = MarlinProtocol(checksums="always"), TinyMarlin()
    run(proto, firmware, ["G1 X1", "G1 X2"])
    proto.reset_line_numbers(1.0)
    assert proto.data_to_send() == b"N0 M110 N0*125\n"
    proto.receive_data(b"ok\n", 1.1)
    proto.send("M110 N100", 1.2, tag="renumber")
    assert proto.data_to_send() == f"{format_line(100, 'M110 N100')}\n".encode()
    proto.receive_data(b"ok\n", 1.3)
    proto.send("G1 X3", 1.4)
    assert proto.data_to_send().startswith(b"N101 G1 X3*")
    assert acks(events(proto)) == ["renumber"]


def test_sent_events_come_with_the_bytes() -> None:
    proto = MarlinProtocol(checksums="never")
    proto.send("M105", 0.0)
    assert events(proto) == []
    assert proto.data_to_send() == b"M105\n"
    assert events(proto) == [Sent("M105", None, resend=False)]


# -- the window ----------------------------------------------------------------------


def test_ping_pong_keeps_one_command_in_flight() -> None:
    proto = MarlinProtocol(checksums="never", flow="ping_pong")
    assert proto.can_send("G1 X1")
    proto.send("G1 X1", 0.0, tag=1)
    assert not proto.can_send("G1 X2")
    with pytest.raises(LocalProtocolError):
        proto.send("G1 X2", 0.0)
    proto.data_to_send()
    proto.receive_data(b"ok\n", 0.01)
    assert acks(events(proto)) == [1]
    assert proto.can_send("G1 X2")


def test_buffered_window_keeps_to_bufsize_and_rx_buffer() -> None:
    proto = MarlinProtocol(checksums="never", flow="buffered", bufsize=4)
    for n in range(4):
        assert proto.can_send(f"G1 X{n}")
        proto.send(f"G1 X{n}", 0.0)
    assert not proto.can_send("G1 X5")  # four lines in flight
    proto.receive_data(b"ok\n", 0.01)
    assert proto.can_send("G1 X5")

    long = "G1 X100.000 Y100.000 Z0.300 E12.34567 F1800"  # 43 + 1 bytes
    proto = MarlinProtocol(checksums="never", flow="buffered", rx_buffer=127)
    proto.send(long, 0.0)
    proto.send(long, 0.0)
    assert proto.bytes_in_flight == 88
    assert not proto.can_send(long)  # 132 > 127 with only two lines
    assert proto.can_send("G1 X1 Y2 Z3 E4")  # 15 more bytes fit


def offered(proto: MarlinProtocol, firmware: TinyMarlin, job: list[str]) -> bytes:
    """*job* streamed as the stream host does: each line offered until it is taken."""
    now, sent, wire = 0.0, 0, b""
    for _ in range(10_000):
        while sent < len(job) and proto.offer(job[sent], now, tag=sent):
            sent += 1
        wire += exchange(proto, firmware, now)
        if sent == len(job) and not proto.in_flight:
            return wire
        now += 0.01
    raise AssertionError("job did not finish")


@pytest.mark.parametrize("flow", ["ping_pong", "buffered", "auto"])
def test_offering_lines_writes_what_asking_then_sending_writes(flow: str) -> None:
    asked = MarlinProtocol(checksums="always", flow=flow)
    log = run(asked, TinyMarlin(advanced=True), JOB)
    wire = "".join(f"{e.text}\n" for e in sent_lines(log)).encode()
    taken = MarlinProtocol(checksums="always", flow=flow)
    assert offered(taken, TinyMarlin(advanced=True), JOB) == wire


def test_offer_leaves_out_a_line_the_window_has_no_room_for() -> None:
    proto = MarlinProtocol(checksums="never", flow="buffered", rx_buffer=127)
    long = "G1 X100.000 Y100.000 Z0.300 E12.34567 F1800"  # 43 + 1 bytes
    assert proto.offer(long, 0.0, tag=1)
    assert proto.offer(long, 0.0, tag=2)
    assert not proto.offer(long, 0.0, tag=3)  # 132 > 127
    assert proto.in_flight == 2
    assert proto.data_to_send() == f"{long}\n{long}\n".encode()
    assert proto.offer("G1 X1 Y2 Z3 E4", 0.0, tag=4)  # 15 more bytes fit
    with pytest.raises(CommandRejected, match="only printable ASCII"):
        proto.offer("G1 X\x07", 0.0)
    proto.receive_data(b"ok\nok\nok\n", 0.1)
    with pytest.raises(CommandRejected, match="truncates"):
        proto.offer("M117 " + "x" * 100, 0.1)
    assert proto.in_flight == 0


def test_offer_takes_a_line_that_fills_the_rx_buffer_to_the_last_byte() -> None:
    proto = MarlinProtocol(checksums="never", flow="buffered", rx_buffer=127)
    long = "G1 X100.000 Y100.000 Z0.300 E12.34567 F1800"  # 43 + 1 bytes
    assert proto.offer(long, 0.0) and proto.offer(long, 0.0)
    assert not proto.offer("M117 " + "x" * 34, 0.0)  # 88 + 40 bytes: one over
    assert proto.offer("M117 " + "x" * 33, 0.0)  # 88 + 39: 127 to the byte
    assert proto.bytes_in_flight == 127


def test_forced_ping_pong_ignores_advanced_ok() -> None:
    proto = MarlinProtocol(checksums="always", flow="ping_pong")
    log = run(proto, TinyMarlin(advanced=True), JOB[:5])
    assert proto.advanced_ok
    assert proto.flow_mode == "ping_pong"
    assert acks(log) == list(range(5))
    proto.send("G1 X1", 1.0)
    assert not proto.can_send("G1 X2")


def test_a_line_larger_than_the_buffer_goes_alone() -> None:
    proto = MarlinProtocol(checksums="never", flow="buffered", rx_buffer=16)
    assert proto.can_send("G1 X100 Y100 Z100")
    proto.send("G1 X100 Y100 Z100", 0.0)
    assert not proto.can_send("G1 X1")


def test_auto_switches_to_a_window_of_b_plus_one_after_advanced_ok() -> None:
    proto = MarlinProtocol(checksums="always")
    firmware = TinyMarlin(advanced=True)
    assert proto.flow_mode == "ping_pong"
    log = run(proto, firmware, JOB)
    assert proto.advanced_ok
    assert proto.flow_mode == "advanced"
    assert acks(log) == list(range(len(JOB)))
    assert firmware.executed == JOB
    proto.send("G1 X1", 1.0)
    for _ in range(3):
        assert proto.can_send("G1 X1")  # B3 -> four lines in flight
        proto.send("G1 X1", 1.0)
    assert not proto.can_send("G1 X1")


@pytest.mark.parametrize(
    "reply",
    ["ok N2 P15 B3", "ok N1 P14 B0", "ok N3 P15 B7", "ok N9 P15 B3", "ok N-1 P1 B1"],
)
def test_an_advanced_ok_taken_quickly_does_what_classifying_it_does(reply) -> None:
    """`ok N<n> P<p> B<b>` skips parse_response (_quick_ok): same events, acks,
    window and what a Resend after it would see."""
    quick, classified = (
        MarlinProtocol(checksums="always", flow="buffered", bufsize=5) for _ in range(2)
    )
    for proto in (quick, classified):
        proto.send("G1 X0", 0.0, tag=0)
        proto.data_to_send()
        proto.receive_data(b"ok\n", 0.1)  # the M110's: lines N1.. go now
        for n in range(1, 4):
            proto.send(f"G1 X{n}", 0.2, tag=n)
        proto.data_to_send()
        events(proto)
    quick.receive_data(f"{reply}\n".encode(), 0.5)
    classified._handle_line(reply)
    classified._pump()
    assert events(quick) == events(classified)
    assert quick.can_send("G1 X9") == classified.can_send("G1 X9")
    for proto in (quick, classified):
        if proto.can_send("G1 X9"):
            proto.send("G1 X9", 0.6)
    assert quick.data_to_send() == classified.data_to_send()
    assert (quick.lines_acked, quick.in_flight, quick.flow_mode) == (
        classified.lines_acked,
        classified.in_flight,
        classified.flow_mode,
    )
    assert quick._max_b == classified._max_b
    assert quick._previous.kind is classified._previous.kind


def test_advanced_window_never_outgrows_the_byte_budget() -> None:
    proto = MarlinProtocol(checksums="always", rx_buffer=63)
    firmware = TinyMarlin(advanced=True)
    now, sent, most = 0.0, 0, 0
    while sent < len(JOB) or proto.in_flight:
        while sent < len(JOB) and proto.can_send(JOB[sent]):
            proto.send(JOB[sent], now, tag=sent)
            sent += 1
            most = max(most, proto.bytes_in_flight)
        exchange(proto, firmware, now)
        now += 0.01
    assert 40 < most <= 63
    assert firmware.executed == JOB


# -- resets, halts, errors, emergencies ------------------------------------------------


def test_start_resets_the_protocol() -> None:
    proto = streaming(lines=2)
    proto.receive_data(b"start\n", 1.0)
    assert meaning(proto) == [FirmwareReset("start")]
    assert proto.in_flight == 0
    assert proto.next_deadline() is None
    proto.send("G1 X9", 1.1)
    assert proto.data_to_send() == b"N0 M110 N0*125\n"


def test_fatal_error_halts() -> None:
    proto = streaming(lines=2)
    proto.receive_data(b"Error:Thermal Runaway, system stopped! Heater_ID: 0\n", 1.0)
    proto.receive_data(b"Error:Printer halted. kill() called!\n", 1.0)
    assert meaning(proto) == [
        FirmwareHalted("Thermal Runaway, system stopped! Heater_ID: 0"),
        FirmwareHalted("Printer halted. kill() called!"),
    ]
    assert proto.in_flight == 0


def test_other_errors_are_reported_and_change_nothing() -> None:
    proto = streaming(lines=1)
    proto.receive_data(b"Error:Probing failed\nok\n", 1.0)
    assert meaning(proto) == [FirmwareError("Probing failed"), Ack(1)]


def test_resend_flow_errors_only_log() -> None:
    proto = streaming(lines=1)
    proto.receive_data(f"{CHECKSUM_ERROR.format(0)}\n".encode(), 1.0)
    assert events(proto) == [Received(CHECKSUM_ERROR.format(0), LineKind.IMPORTANT)]


def test_m112_goes_first_even_with_the_window_full() -> None:
    proto = MarlinProtocol(checksums="never", flow="buffered")
    for n in range(4):
        proto.send(f"G1 X{n}", 0.0)
    assert not proto.can_send("G1 X9")
    proto.send_emergency("M112", 0.0)
    assert proto.data_to_send().split(b"\n")[:2] == [b"M112", b"G1 X0"]
    assert proto.in_flight == 4  # M112 expects no ok


def test_m108_jumps_the_queue_and_expects_an_ok() -> None:
    proto = MarlinProtocol(checksums="never")
    proto.send("M109 S210", 0.0, tag="heat")
    proto.data_to_send()
    proto.send_emergency("M108", 0.1)
    assert proto.data_to_send() == b"M108\n"
    assert proto.in_flight == 2
    proto.receive_data(b"ok\nok\n", 0.2)
    assert acks(events(proto)) == ["heat"]
    assert proto.in_flight == 0


# -- receiving -------------------------------------------------------------------------


def test_lines_may_arrive_in_pieces_with_any_line_ending() -> None:
    proto = MarlinProtocol(checksums="never", flow="buffered")
    for n in range(3):
        proto.send(f"M{n}", 0.0, tag=n)
    proto.data_to_send()
    for piece in (b"o", b"k\r", b"\nok\rok", b"\n\n"):
        proto.receive_data(piece, 0.1)
    assert acks(events(proto)) == [0, 1, 2]


def test_undecodable_lines_are_responses() -> None:
    proto = MarlinProtocol()
    proto.receive_data(b"\xff\xfeok\n", 0.0)
    assert events(proto)[0] == Received("\ufffd\ufffdok", LineKind.RESPONSE)


def test_empty_data_only_moves_the_clock() -> None:
    proto = MarlinProtocol()
    proto.receive_data(b"", 1.0)
    assert events(proto) == []
