"""MarlinProtocol: bytes in, events out, against a tiny in-test firmware."""

from __future__ import annotations

import pytest

from printers.protocol.checksum import format_line, parse_framed_line
from printers.protocol.errors import CommandRejected, LocalProtocolError
from printers.protocol.events import (
    Ack,
    Busy,
    Event,
    FirmwareError,
    FirmwareHalted,
    FirmwareReset,
    LineKind,
    LinkFailed,
    Received,
    ResendServed,
    Sent,
    TemperatureReport,
)
from printers.protocol.history import LineHistory
from printers.protocol.marlin import MarlinProtocol

LINE_ERROR = "Error:Line Number is not Last Line Number+1, Last Line: {}"
CHECKSUM_ERROR = "Error:checksum mismatch, Last Line: {}"


class TinyMarlin:
    """Replies as Marlin would to each wire line, with no buffer limits and no flush.

    *damaged* holds line numbers whose first arrival is rejected as corrupt. Lines out
    of sequence get Marlin's Error/Resend/ok, the non-cooperation that makes hosts
    see a Resend per line in flight. With *repetier* they get `skip N` + ok instead.
    """

    def __init__(
        self,
        *,
        advanced: bool = False,
        damaged: tuple[int, ...] = (),
        repetier: bool = False,
    ) -> None:
        self.advanced, self.repetier = advanced, repetier
        self.damaged = set(damaged)
        self.last_n = 0
        self.executed: list[str] = []

    def __call__(self, data: bytes) -> bytes:
        replies = [r for line in data.decode().splitlines() for r in self.reply(line)]
        return "".join(f"{r}\n" for r in replies).encode()

    def reply(self, line: str) -> list[str]:
        number, command, good = parse_framed_line(line)
        if number is None:
            self.executed.append(command)
            return ["ok"]
        if command.startswith("M110"):
            self.last_n = number
            return [self.ok(number)]
        if number != self.last_n + 1:
            if self.repetier:
                return [f"skip {number}", "ok"]
            return self.resend(LINE_ERROR)
        if number in self.damaged or not good:
            self.damaged.discard(number)
            return self.resend(CHECKSUM_ERROR)
        self.last_n = number
        self.executed.append(command)
        return [self.ok(number)]

    def ok(self, number: int) -> str:
        return f"ok N{number} P15 B3" if self.advanced else "ok"

    def resend(self, error: str) -> list[str]:
        return [error.format(self.last_n), f"Resend: {self.last_n + 1}", "ok"]


def events(proto: MarlinProtocol) -> list[Event]:
    out = []
    while (event := proto.next_event()) is not None:
        out.append(event)
    return out


def meaning(proto: MarlinProtocol) -> list[Event]:
    """Events without the Sent/Received log."""
    return [e for e in events(proto) if not isinstance(e, Sent | Received)]


def exchange(proto: MarlinProtocol, firmware: TinyMarlin, now: float) -> bytes:
    """One round trip: what the protocol writes goes to the firmware and back."""
    data = proto.data_to_send()
    proto.receive_data(firmware(data), now)
    return data


def run(proto: MarlinProtocol, firmware: TinyMarlin, job: list[str]) -> list[Event]:
    """Stream *job* to the end, moving the clock 10 ms a turn; returns all events."""
    now, sent, log = 0.0, 0, []
    for _ in range(10_000):
        while sent < len(job) and proto.can_send(job[sent]):
            proto.send(job[sent], now, tag=sent)
            sent += 1
        exchange(proto, firmware, now)
        log += events(proto)
        if sent == len(job) and not proto.in_flight:
            return log
        now += 0.01
        deadline = proto.next_deadline()
        if deadline is not None and now >= deadline:
            proto.handle_timeout(now)
    raise AssertionError("job did not finish")


def acks(log: list[Event]) -> list[object]:
    return [e.tag for e in log if isinstance(e, Ack)]


def sent_lines(log: list[Event]) -> list[Sent]:
    return [e for e in log if isinstance(e, Sent)]


JOB = [f"G1 X{i} Y{i * 2} E{i / 10:.3f}" for i in range(1, 31)]


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


# -- acknowledgements ----------------------------------------------------------------


def test_stray_ok_is_ignored() -> None:
    proto = MarlinProtocol()
    proto.receive_data(b"ok\n", 0.0)
    assert events(proto) == [Received("ok", LineKind.ACK)]


def test_ok_with_temperatures_acks_and_reports() -> None:
    proto = MarlinProtocol(checksums="never")
    proto.send("M105", 0.0, tag="poll")
    proto.data_to_send()
    proto.receive_data(b"ok T:210.00 /210.00 B:60.00 /60.00 @:127 B@:0\n", 0.01)
    assert meaning(proto) == [
        TemperatureReport({"T0": (210.0, 210.0), "B": (60.0, 60.0)}),
        Ack("poll"),
    ]


def test_advanced_ok_n_repairs_a_lost_ok() -> None:
    proto = MarlinProtocol(checksums="always", flow="buffered")
    run(proto, TinyMarlin(), ["G1 X0"])
    for n in range(1, 4):
        proto.send(f"G1 X{n}", 1.0, tag=n)
    proto.data_to_send()
    proto.receive_data(b"ok N4 P15 B3\n", 1.1)  # the oks of N2 and N3 were lost
    assert acks(events(proto)) == [1, 2, 3]
    assert proto.in_flight == 0


def test_repetier_ok_n_acks_by_number() -> None:
    proto = MarlinProtocol(checksums="always", flow="buffered")
    run(proto, TinyMarlin(), ["G1 X0"])
    for n in range(1, 4):
        proto.send(f"G1 X{n}", 1.0, tag=n)
    proto.data_to_send()
    proto.receive_data(b"ok 3\n", 1.1)  # N2 and N3 are tags 1 and 2
    assert acks(events(proto)) == [1, 2]
    assert proto.in_flight == 1


def test_ok_for_an_unknown_number_falls_back_to_fifo() -> None:
    proto = MarlinProtocol(checksums="never", flow="buffered")
    proto.send("M105", 0.0, tag="a")
    proto.send("M114", 0.0, tag="b")
    proto.data_to_send()
    proto.receive_data(b"ok N77 P15 B3\n", 0.01)
    assert acks(events(proto)) == ["a"]


# -- resends -------------------------------------------------------------------------


def test_resend_with_marlins_reply_sequence() -> None:
    proto = MarlinProtocol(checksums="always")
    firmware = TinyMarlin(damaged=(3,))
    log = run(proto, firmware, JOB[:5])
    served = [e for e in log if isinstance(e, ResendServed)]
    assert served == [ResendServed(3, CHECKSUM_ERROR.format(2))]
    assert firmware.executed == JOB[:5]
    assert acks(log) == [0, 1, 2, 3, 4]
    resent = [e.line_number for e in sent_lines(log) if e.resend]
    assert resent == [3]
    assert proto.resends == 1


def test_duplicates_from_lines_in_flight_do_not_loop() -> None:
    proto = MarlinProtocol(
        checksums="always", flow="buffered", bufsize=8, rx_buffer=400
    )
    firmware = TinyMarlin(damaged=(5, 20))
    log = run(proto, firmware, JOB)
    assert firmware.executed == JOB
    assert acks(log) == list(range(len(JOB)))
    served = [e.line_number for e in log if isinstance(e, ResendServed)]
    assert served == [5, 20]  # the duplicates from lines behind were ignored
    resent = [e for e in sent_lines(log) if e.resend]
    assert len(resent) <= 2 * 8  # each line in flight at most once more
    assert proto.resends == 2


def test_duplicate_detection_needs_the_line_number_error() -> None:
    proto = _streaming(lines=4)  # N1..N4 in flight
    proto.receive_data(f"{CHECKSUM_ERROR.format(1)}\nResend: 2\nok\n".encode(), 1.0)
    proto.receive_data(f"{CHECKSUM_ERROR.format(1)}\nResend: 2\nok\n".encode(), 1.0)
    served = [e for e in events(proto) if isinstance(e, ResendServed)]
    assert len(served) == 2  # a checksum error again: the re-sent line was damaged


def test_rs_form_and_resend_n_form() -> None:
    for request in (b"rs 2\nok\n", b"rs N2\nok\n", b"Resend:N2\nok\n"):
        proto = _streaming(lines=3)
        proto.receive_data(request, 1.0)
        log = events(proto)
        assert ResendServed(2, request.split(b"\n")[0].decode()) in log
        assert acks(log) == []  # the ok after the request belongs to the bad line
        proto.handle_timeout(proto.next_deadline() or 2.0)
        assert proto.data_to_send().startswith(b"N2 ")


def test_repetier_skip_is_a_duplicate() -> None:
    proto = MarlinProtocol(checksums="always", flow="buffered")
    firmware = TinyMarlin(damaged=(2,), repetier=True)
    log = run(proto, firmware, JOB[:6])
    assert firmware.executed == JOB[:6]
    assert acks(log) == list(range(6))
    assert [e.line_number for e in log if isinstance(e, ResendServed)] == [2]


def test_r7_resend_far_back_in_the_job_is_a_reset_not_a_replay() -> None:
    proto, firmware = MarlinProtocol(checksums="always"), TinyMarlin()
    job = [f"G1 X{i}" for i in range(300)]
    run(proto, firmware, job)
    proto.send("G1 X300", 5.0, tag="last")
    proto.data_to_send()
    error = LINE_ERROR.format(2).encode()  # lines 1..300 were acknowledged
    proto.receive_data(error + b"\nResend: 3\nok\n", 5.1)
    assert meaning(proto) == []  # once could be line noise
    proto.receive_data(error + b"\nResend: 3\nok\n", 5.2)
    assert meaning(proto) == [
        FirmwareReset("Resend: 3 after line 300 was acknowledged")
    ]
    assert proto.in_flight == 0
    assert proto.next_deadline() is None
    assert proto.data_to_send() == b""


def test_resend_limit_fails_the_link() -> None:
    proto = _streaming(lines=1, max_resends=3)
    request = f"{CHECKSUM_ERROR.format(0)}\nResend: 1\nok\n".encode()
    now = 1.0
    for _ in range(3):
        proto.receive_data(request, now)
        now = proto.next_deadline() or now
        proto.handle_timeout(now)
        assert proto.data_to_send().startswith(b"N1 ")
    proto.receive_data(request, now)
    failed = [e for e in events(proto) if isinstance(e, LinkFailed)]
    assert len(failed) == 1
    assert "keeps asking for line 1" in failed[0].message
    assert "cable" in failed[0].message
    assert proto.in_flight == 0


def test_r9_resend_for_a_line_never_sent_is_noise() -> None:
    proto = _streaming(lines=2)
    proto.receive_data(b"Resend: 9\nok\n", 1.0)  # "Resend: 1" with a digit garbled
    assert meaning(proto) == []
    proto.handle_timeout(proto.next_deadline() or 1.1)
    assert proto.data_to_send() == b""  # nothing re-sent, its ok swallowed
    assert proto.in_flight == 2


def test_r9_resend_contradicting_its_error_line_is_noise() -> None:
    proto = _streaming(lines=2)
    proto.receive_data(f"{CHECKSUM_ERROR.format(0)}\nResend: 2\nok\n".encode(), 1.0)
    assert not any(isinstance(e, ResendServed) for e in events(proto))


def test_resend_for_the_next_line_is_nothing_to_do() -> None:
    proto = _streaming(lines=2)
    proto.receive_data(b"ok\nok\n", 1.0)
    proto.receive_data(b"Resend: 3\nok\n", 1.1)
    assert meaning(proto) == [Ack(1), Ack(2)]
    assert proto.data_to_send() == b""


def test_resend_waits_for_the_buffer_to_drain() -> None:
    proto = _streaming(lines=3, baud=9600)
    proto.receive_data(f"{CHECKSUM_ERROR.format(0)}\nResend: 1\nok\n".encode(), 1.0)
    assert not proto.can_send("G1 X9")
    assert proto.data_to_send() == b""
    deadline = proto.next_deadline()
    assert deadline is not None
    assert deadline >= 1.0 + 127 * 10 / 9600
    proto.handle_timeout(deadline)
    assert proto.data_to_send().count(b"\n") == 1  # W4: one at a time until its ok
    proto.receive_data(b"ok\n", deadline + 0.01)
    assert proto.data_to_send().count(b"\n") == 2


def test_a_damaged_m110_is_sent_again_whatever_number_marlin_names() -> None:
    proto = MarlinProtocol(checksums="always")
    proto.send("G28", 0.0)
    proto.data_to_send()
    # Marlin still counts from an earlier session, so it asks for its own line 58.
    damaged = f"{CHECKSUM_ERROR.format(57)}\nResend: 58\nok\n"
    proto.receive_data(damaged.encode(), 0.1)
    leftover = f"{LINE_ERROR.format(57)}\nResend: 58\nok\n"
    proto.receive_data(leftover.encode(), 0.1)
    assert meaning(proto) == [ResendServed(0, CHECKSUM_ERROR.format(57))]
    proto.handle_timeout(proto.next_deadline() or 1.0)
    assert proto.data_to_send() == b"N0 M110 N0*125\n"


def test_a_late_ok_for_a_timed_out_m110_stops_its_resend() -> None:
    proto = MarlinProtocol(checksums="always", ack_timeout=1.0)
    proto.send("G28", 0.0)
    proto.data_to_send()
    proto.handle_timeout(1.0)  # the M110 will go again once the buffer drained
    proto.receive_data(b"ok\n", 1.001)  # its answer was late, not lost
    proto.handle_timeout(proto.next_deadline() or 2.0)
    assert proto.data_to_send() == f"{format_line(1, 'G28')}\n".encode()


def test_the_second_ok_of_a_repeated_m110_is_not_taken_for_the_next_line() -> None:
    proto = MarlinProtocol(checksums="always", ack_timeout=1.0)
    proto.send("G28", 0.0, tag="home")
    proto.data_to_send()
    proto.handle_timeout(1.0)
    proto.handle_timeout(proto.next_deadline() or 2.0)
    assert proto.data_to_send() == b"N0 M110 N0*125\n"
    proto.receive_data(b"ok N0 P15 B3\n", 1.2)  # the first copy's answer
    assert proto.data_to_send().startswith(b"N1 G28*")
    proto.receive_data(b"ok N0 P15 B3\n", 1.3)  # the second copy's answer
    assert acks(events(proto)) == []
    proto.receive_data(b"ok N1 P15 B3\n", 1.4)
    assert acks(events(proto)) == ["home"]


# -- timeouts, busy, wait --------------------------------------------------------------


def test_ack_timeout_retransmits_then_fails_the_link() -> None:
    proto = _streaming(lines=1, ack_timeout=5.0, max_timeouts=2, probe_after=None)
    now = 0.0
    for _ in range(2):
        deadline = proto.next_deadline()
        assert deadline is not None
        proto.handle_timeout(deadline - 0.01)  # too early: nothing happens
        assert proto.data_to_send() == b""
        now = deadline
        proto.handle_timeout(now)
        proto.handle_timeout(proto.next_deadline() or now)  # the drain
        assert proto.data_to_send().startswith(b"N1 ")
    proto.handle_timeout(proto.next_deadline() or now)
    failed = [e for e in events(proto) if isinstance(e, LinkFailed)]
    assert len(failed) == 1
    assert "N1 G1 X1" in failed[0].message
    assert proto.timeouts == 3


def test_timeout_recovery_learns_from_the_resend() -> None:
    proto = _streaming(lines=3, ack_timeout=5.0, probe_after=None)
    proto.handle_timeout(5.0)  # the oks of N1..N3 were lost
    proto.handle_timeout(proto.next_deadline() or 6.0)
    assert proto.data_to_send().count(b"\n") == 1  # W4
    proto.receive_data(f"{LINE_ERROR.format(3)}\nResend: 4\nok\n".encode(), 6.1)
    assert acks(events(proto)) == [1, 2, 3]
    assert proto.in_flight == 0


def test_unnumbered_command_timeout_assumes_a_lost_ok_when_idle() -> None:
    proto = MarlinProtocol(checksums="never", ack_timeout=2.0)
    proto.send("M105", 0.0, tag="poll")
    proto.data_to_send()
    proto.handle_timeout(2.0)
    assert meaning(proto) == [Ack("poll")]


def test_unnumbered_command_timeout_while_printing_fails() -> None:
    proto = MarlinProtocol(checksums="never", ack_timeout=2.0)
    proto.printing = True
    proto.send("G1 X1", 0.0)
    proto.data_to_send()
    proto.handle_timeout(2.0)
    assert [type(e) for e in meaning(proto)] == [LinkFailed]


def test_busy_extends_the_deadline() -> None:
    proto = _streaming(lines=1, ack_timeout=2.0, busy_timeout=30.0, command="G28")
    assert proto.next_deadline() == 2.0
    proto.receive_data(b"echo:busy: processing\n", 1.5)
    assert meaning(proto) == [Busy("processing")]
    assert proto.next_deadline() == 31.5
    proto.handle_timeout(2.0)
    assert proto.data_to_send() == b""


def test_temperatures_are_progress_only_during_a_long_command() -> None:
    proto = _streaming(lines=1, ack_timeout=2.0, command="M109 S210")
    proto.receive_data(b"T:180.1 E:0 W:?\n", 1.5)
    assert proto.next_deadline() == 3.5
    proto = _streaming(lines=1, ack_timeout=2.0, command="G1 X1", probe_after=None)
    proto.receive_data(b"T:180.1 /0.0 B:20.0 /0.0\n", 1.5)
    assert proto.next_deadline() == 2.0


def test_wait_with_a_command_in_flight_acts_like_a_timeout() -> None:
    proto = _streaming(lines=1, ack_timeout=10.0)
    proto.receive_data(b"wait\n", 1.0)
    assert [type(e) for e in meaning(proto)] == [ResendServed]
    assert proto.timeouts == 0
    idle = MarlinProtocol()
    idle.receive_data(b"wait\nwait\n", 1.0)
    assert meaning(idle) == []


# -- resets, halts, errors, emergencies ------------------------------------------------


def test_start_resets_the_protocol() -> None:
    proto = _streaming(lines=2)
    proto.receive_data(b"start\n", 1.0)
    assert meaning(proto) == [FirmwareReset("start")]
    assert proto.in_flight == 0
    assert proto.next_deadline() is None
    proto.send("G1 X9", 1.1)
    assert proto.data_to_send() == b"N0 M110 N0*125\n"


def test_fatal_error_halts() -> None:
    proto = _streaming(lines=2)
    proto.receive_data(b"Error:Thermal Runaway, system stopped! Heater_ID: 0\n", 1.0)
    proto.receive_data(b"Error:Printer halted. kill() called!\n", 1.0)
    assert meaning(proto) == [
        FirmwareHalted("Thermal Runaway, system stopped! Heater_ID: 0"),
        FirmwareHalted("Printer halted. kill() called!"),
    ]
    assert proto.in_flight == 0


def test_other_errors_are_reported_and_change_nothing() -> None:
    proto = _streaming(lines=1)
    proto.receive_data(b"Error:Probing failed\nok\n", 1.0)
    assert meaning(proto) == [FirmwareError("Probing failed"), Ack(1)]


def test_resend_flow_errors_only_log() -> None:
    proto = _streaming(lines=1)
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


# -- history -----------------------------------------------------------------------


def test_history_keeps_every_line_of_the_job() -> None:
    history = LineHistory()
    history.clear(0)
    for n in range(10_000):
        history.append(n, f"G1 X{n}")
    assert (history.first, history.last, len(history)) == (0, 9_999, 10_000)
    assert history.get(0) == "G1 X0"
    assert history.get(5_000) == "G1 X5000"
    assert 10_000 not in history
    with pytest.raises(KeyError):
        history.get(10_000)
    with pytest.raises(ValueError, match="does not follow"):
        history.append(10_001, "G1")
    history.clear(100)
    assert (history.first, history.last, len(history)) == (100, 99, 0)
    history.append(100, "M110 N100")
    assert history.get(100) == "M110 N100"


def _streaming(
    *, lines: int, command: str = "G1 X{}", **options: object
) -> MarlinProtocol:
    """A protocol with lines N1..N<lines> written at t=0 and not yet answered."""
    proto = MarlinProtocol(checksums="always", flow="buffered", **options)  # type: ignore[arg-type]
    proto.reset_line_numbers(0.0)
    proto.data_to_send()
    proto.receive_data(b"ok\n", 0.0)
    for n in range(1, lines + 1):
        proto.send(command.format(n), 0.0, tag=n)
    proto.data_to_send()
    events(proto)
    return proto
