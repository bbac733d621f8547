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


def test_p2_reads_at_once_with_one_line_in_flight_or_an_idle_wire() -> None:
    pacer = Pacer(BAUD)
    pacer.wrote(40, 1.0)
    assert pacer.read_at(1.0, lines_in_flight=1) == 1.0  # ping-pong
    assert pacer.read_at(2.0, lines_in_flight=3) == 2.0  # sent long ago


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
