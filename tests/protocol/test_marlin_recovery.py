"""MarlinProtocol's acknowledgements and recovery: oks, resends, timeouts, busy
and wait (rules R1-R9, T1-T6) and the history lines are sent again from, against
a tiny in-test firmware."""

from __future__ import annotations

import pytest

from printers.protocol.checksum import format_line
from printers.protocol.events import (
    Ack,
    Busy,
    FirmwareReset,
    LineKind,
    LinkFailed,
    Received,
    ResendServed,
    TemperatureReport,
)
from printers.protocol.history import LineHistory
from printers.protocol.marlin import MarlinProtocol
from tests.protocol.marlin_helpers import (
    CHECKSUM_ERROR,
    JOB,
    LINE_ERROR,
    TinyMarlin,
    acks,
    events,
    meaning,
    run,
    sent_lines,
    streaming,
)

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
    proto = streaming(lines=4)  # N1..N4 in flight
    proto.receive_data(f"{CHECKSUM_ERROR.format(1)}\nResend: 2\nok\n".encode(), 1.0)
    proto.receive_data(f"{CHECKSUM_ERROR.format(1)}\nResend: 2\nok\n".encode(), 1.0)
    served = [e for e in events(proto) if isinstance(e, ResendServed)]
    assert len(served) == 2  # a checksum error again: the re-sent line was damaged


def test_rs_form_and_resend_n_form() -> None:
    for request in (b"rs 2\nok\n", b"rs N2\nok\n", b"Resend:N2\nok\n"):
        proto = streaming(lines=3)
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
    proto = streaming(lines=1, max_resends=3)
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
    proto = streaming(lines=2)
    proto.receive_data(b"Resend: 9\nok\n", 1.0)  # "Resend: 1" with a digit garbled
    assert meaning(proto) == []
    proto.handle_timeout(proto.next_deadline() or 1.1)
    assert proto.data_to_send() == b""  # nothing re-sent, its ok swallowed
    assert proto.in_flight == 2


def test_r9_resend_contradicting_its_error_line_is_noise() -> None:
    proto = streaming(lines=2)
    proto.receive_data(f"{CHECKSUM_ERROR.format(0)}\nResend: 2\nok\n".encode(), 1.0)
    assert not any(isinstance(e, ResendServed) for e in events(proto))


def test_resend_for_the_next_line_is_nothing_to_do() -> None:
    proto = streaming(lines=2)
    proto.receive_data(b"ok\nok\n", 1.0)
    proto.receive_data(b"Resend: 3\nok\n", 1.1)
    assert meaning(proto) == [Ack(1), Ack(2)]
    assert proto.data_to_send() == b""


def test_resend_waits_for_the_buffer_to_drain() -> None:
    proto = streaming(lines=3, baud=9600)
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
    proto = streaming(lines=1, ack_timeout=5.0, max_timeouts=2, probe_after=None)
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
    proto = streaming(lines=3, ack_timeout=5.0, probe_after=None)
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
    proto = streaming(lines=1, ack_timeout=2.0, busy_timeout=30.0, command="G28")
    assert proto.next_deadline() == 2.0
    proto.receive_data(b"echo:busy: processing\n", 1.5)
    assert meaning(proto) == [Busy("processing")]
    assert proto.next_deadline() == 31.5
    proto.handle_timeout(2.0)
    assert proto.data_to_send() == b""


def test_temperatures_are_progress_only_during_a_long_command() -> None:
    proto = streaming(lines=1, ack_timeout=2.0, command="M109 S210")
    proto.receive_data(b"T:180.1 E:0 W:?\n", 1.5)
    assert proto.next_deadline() == 3.5
    proto = streaming(lines=1, ack_timeout=2.0, command="G1 X1", probe_after=None)
    proto.receive_data(b"T:180.1 /0.0 B:20.0 /0.0\n", 1.5)
    assert proto.next_deadline() == 2.0


def test_wait_with_a_command_in_flight_acts_like_a_timeout() -> None:
    proto = streaming(lines=1, ack_timeout=10.0)
    proto.receive_data(b"wait\n", 1.0)
    assert [type(e) for e in meaning(proto)] == [ResendServed]
    assert proto.timeouts == 0
    idle = MarlinProtocol()
    idle.receive_data(b"wait\nwait\n", 1.0)
    assert meaning(idle) == []


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
