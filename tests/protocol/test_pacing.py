"""The pacer (P1-P3 in printers/protocol/pacing.py): when the worker may wait to read."""

from __future__ import annotations

import pytest

from printers.protocol import pacing
from printers.protocol.pacing import Pacer

BAUD = 250000
BYTE = 10 / BAUD


def test_p1_writes_queue_one_behind_the_other_at_the_baud_rate() -> None:
    pacer = Pacer(BAUD)
    pacer.wrote(100, 1.0)
    pacer.wrote(50, 1.001)  # while the first is still going out
    assert pacer.busy_until == pytest.approx(1.0 + 150 * BYTE)
    assert pacer.unsent(1.0 + 50 * BYTE) == pytest.approx(100)
    pacer.wrote(10, 5.0)  # long after the wire went idle
    assert pacer.busy_until == pytest.approx(5.0 + 10 * BYTE)


def test_p2_waits_until_the_wire_is_nearly_drained() -> None:
    pacer = Pacer(BAUD)
    pacer.wrote(120, 1.0)
    wake = pacer.read_at(1.0001, lines_in_flight=3)
    assert wake == pytest.approx(1.0 + 120 * BYTE - pacer.margin)
    assert wake > 1.0001


def test_p2_reads_at_once_on_an_idle_wire_or_with_nothing_in_flight() -> None:
    pacer = Pacer(BAUD)
    pacer.wrote(40, 1.0)
    assert pacer.read_at(1.0, lines_in_flight=0) == 1.0
    assert pacer.read_at(2.0, lines_in_flight=3) == 2.0  # sent long ago
    assert pacer.read_at(2.0, lines_in_flight=1) == 2.0


def test_p2_never_waits_longer_than_the_cap_on_a_slow_line() -> None:
    pacer = Pacer(1200)
    pacer.wrote(127, 0.0)  # about a second of wire at 1200 baud
    assert pacer.read_at(0.0, lines_in_flight=3) == pytest.approx(pacing.LONGEST_WAIT)


def test_p2a_the_margin_follows_the_workers_turnaround_within_bounds() -> None:
    pacer = Pacer(BAUD)
    now = 0.0
    for _ in range(100):  # every write comes 1.5 ms after the paced wake-up
        pacer.wrote(127, now)
        due = pacer.read_at(now, lines_in_flight=3)
        if due > now:
            now = due + 0.0015
        else:
            now += 0.01
    assert pacer.margin == pytest.approx(pacing.MARGIN_FACTOR * 0.0015, rel=0.05)
    assert pacer.margin <= pacing.MAX_MARGIN
    quick = Pacer(BAUD)
    assert quick.margin >= pacing.MIN_MARGIN


def test_p3_a_link_faster_than_its_baud_turns_waiting_off() -> None:
    pacer = Pacer(BAUD)
    now = 0.0
    for _ in range(pacing.EVIDENCE):
        pacer.wrote(120, now)
        # Every byte acknowledged a tenth of the way through the modelled send.
        pacer.acknowledged(0, now + 12 * BYTE)
        now += 1.0
    assert not pacer.modelled
    pacer.wrote(120, now)
    assert pacer.read_at(now, lines_in_flight=3) == now
    pacer.reset()  # a new connection: trusted again
    assert pacer.modelled


def test_p3_one_early_ok_is_no_proof() -> None:
    pacer = Pacer(BAUD)
    now = 0.0
    for _ in range(10):
        pacer.wrote(120, now)
        pacer.acknowledged(0, now + 12 * BYTE)  # a stale ok, or a misjudged write
        now += 1.0
        pacer.wrote(120, now)
        pacer.acknowledged(100, now + 12 * BYTE)  # the link as modelled
        now += 1.0
    assert pacer.modelled


def test_p3_every_sixteenth_wait_is_a_sample_read_at_once() -> None:
    pacer = Pacer(BAUD)
    waits = []
    for step in range(pacing.PROBE_EVERY * 2):
        now = float(step)
        pacer.wrote(120, now)
        waits.append(pacer.read_at(now, lines_in_flight=3) > now)
    assert waits.count(False) == 2
    assert waits[pacing.PROBE_EVERY - 1] is False


def test_no_baud_rate_means_never_waiting() -> None:
    pacer = Pacer(0)
    pacer.wrote(120, 1.0)
    assert pacer.read_at(1.0, lines_in_flight=3) == 1.0


def test_p4_a_cut_reply_is_awaited_for_as_long_as_recent_lines_take() -> None:
    pacer = Pacer(BAUD)
    for _ in range(20):  # whole replies of 16 bytes teach the line length
        pacer.received(b"ok N1234 P15 B3\n", 1.0)
    assert pacer.rest_at(1.0) is None
    pacer.received(b"ok", 2.0)  # the first 2 bytes of the next one
    assert pacer.rest_at(2.0) == pytest.approx(2.0 + (16 - 2 + 0.5) * BYTE, rel=0.05)
    pacer.received(b" N1235 P15 B3\n", 2.001)  # the rest: nothing cut any more
    assert pacer.rest_at(2.001) is None


# -- P5: one line in flight ----------------------------------------------------------


def test_p5_a_lone_line_is_read_when_its_reply_can_be_whole() -> None:
    pacer = Pacer(BAUD)
    pacer.wrote(40, 1.0)
    reply = pacing.FIRST_REPLY_BYTES * BYTE
    assert pacer.read_at(1.0, lines_in_flight=1) == pytest.approx(
        1.0 + 40 * BYTE + reply
    )


def test_p5_a_cut_reply_teaches_how_long_the_firmware_takes_to_answer() -> None:
    pacer = Pacer(BAUD)
    lags = []
    for n in range(12):
        now = float(n)
        pacer.wrote(40, now)
        on_wire = now + 40 * BYTE
        assert pacer.read_at(now, lines_in_flight=1) > now  # a wait, not a sample
        # The reply started 0.5 ms after the line left: 3 bytes of it are in.
        pacer.received(b"ok ", on_wire + 0.0005 + 3 * BYTE)
        pacer.received(b"N1 P15 B3\n", now + 0.01)  # only the first read teaches
        lags.append(pacer.lag)
    assert lags[0] == pytest.approx(pacing.LAG_RISE * 0.0005)
    assert lags == sorted(lags)  # each cut read moves it on, never past the answer
    assert 0.00047 < lags[-1] < 0.0005
    pacer.wrote(40, 20.0)
    wake = pacer.read_at(20.0, lines_in_flight=1)
    assert wake == pytest.approx(20.0 + 40 * BYTE + pacer.reply_bytes * BYTE + lags[-1])


def test_p5_a_long_command_teaches_nothing() -> None:
    pacer = Pacer(BAUD)
    pacer.wrote(10, 1.0)  # G28
    pacer.read_at(1.0, lines_in_flight=1)
    pacer.received(b"o", 21.0)  # its ok, 20 s later
    assert pacer.lag == 0.0


def test_p5_waits_do_not_hide_a_link_faster_than_its_baud_rate() -> None:
    pacer = Pacer(BAUD)  # a native USB port: each ok comes 0.3 ms after its line
    now = 0.0
    for _ in range(40):
        pacer.wrote(40, now)
        wake = pacer.read_at(now, lines_in_flight=1)
        now = max(wake, now + 0.0003)
        pacer.received(b"ok N1 P15 B3\n", now)
        if pacer.sampling(now):  # as the worker asks after every read
            pacer.acknowledged(0, now)
    pacer.wrote(40, now)
    assert pacer.read_at(now, lines_in_flight=1) == now


@pytest.mark.parametrize("answer_delay", [0.0, 0.0003, 0.002])
def test_p5_a_ping_pong_line_costs_about_one_wake_up(answer_delay: float) -> None:
    """A firmware answering each line *answer_delay* after it arrived, and a worker
    whose sleeps end up to 0.1 ms late: P5 and P4 wake it about once a line,
    where reading at once (select, then P4 for the rest) woke it twice."""
    pacer = Pacer(BAUD)
    reply = b"ok N1234 P15 B3\n"
    now, wakes, lines = 0.0, 0, 300
    for n in range(lines):
        pacer.wrote(38, now)
        first = pacer.busy_until + answer_delay  # the reply's first byte comes
        whole = first + len(reply) * BYTE
        late = 0.00005 * (n % 3)
        read = pacer.read_at(now, lines_in_flight=1)
        if read > now:
            wakes += 1  # slept (P5)
            read += late
        if read < first:
            wakes += 1  # select() waits for the first byte
            read = first + BYTE
        got = reply[: min(len(reply), int((read - first) / BYTE))]
        pacer.received(got, read)
        if len(got) < len(reply):
            wakes += 1  # P4 sleeps for the rest
            pacer.received(reply[len(got) :], whole + late)
        now = max(read, whole + late)
    assert wakes / lines <= 1.3


def test_p5_one_slow_answer_is_forgotten_at_the_next_sample() -> None:
    pacer = Pacer(BAUD)
    now = 0.0
    pacer.wrote(38, now)
    pacer.read_at(now, lines_in_flight=1)
    pacer.received(b"o", pacer.busy_until + 0.02)  # one answer 20 ms late, cut
    # It moves the wait a quarter of the way: the lines after it are not all
    # held back by 20 ms for one slow answer.
    assert pacer.lag == pytest.approx(pacing.LAG_RISE * 0.02, abs=BYTE)
    for _ in range(pacing.PROBE_EVERY):  # then answers 0.2 ms after each line
        now += 0.05
        pacer.wrote(38, now)
        sent = pacer.busy_until
        if pacer.read_at(now, lines_in_flight=1) == now:  # P3's sample, at once
            pacer.received(b"o", sent + 0.0002 + BYTE)
        else:
            pacer.received(b"ok N1 P15 B3\n", sent + 0.021)
    assert pacer.lag == pytest.approx(0.0002)
