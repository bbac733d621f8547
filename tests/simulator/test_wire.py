"""The wire model: latency, baud/10 bytes per second, FIFO, wake-up points."""

from __future__ import annotations

import pytest

from printers.simulator.link import Wire


def test_unthrottled_wire_delivers_at_once():
    wire = Wire(None)
    wire.put(b"hello\n", 5.0)

    assert wire.next_arrival() == 5.0
    assert wire.take(5.0) == b"hello\n"
    assert wire.next_arrival() is None


def test_latency_delays_every_byte():
    wire = Wire(None, latency=0.25)
    wire.put(b"ok\n", 1.0)

    assert wire.take(1.2) == b""
    assert wire.take(1.25) == b"ok\n"


def test_baud_paces_bytes_at_a_tenth_of_the_baud_rate():
    wire = Wire(9600)
    wire.put(b"x" * 960, 0.0)

    assert len(wire.take(0.5)) == 480
    assert wire.take(0.999) == b"x" * 479
    assert wire.take(1.0) == b"x"


def test_later_writes_queue_behind_earlier_ones():
    wire = Wire(1000)  # 100 bytes/s
    wire.put(b"a" * 100, 0.0)
    wire.put(b"b", 0.5)  # the line is busy until t=1.0

    assert wire.take(1.0) == b"a" * 100
    assert wire.next_arrival() == pytest.approx(1.01)
    assert wire.take(1.01) == b"b"


def test_a_write_after_a_pause_starts_at_its_own_time():
    wire = Wire(1000)
    wire.put(b"a", 0.0)
    wire.put(b"b", 5.0)

    assert wire.take(0.01) == b"a"
    assert wire.take(5.009) == b""
    assert wire.take(5.01) == b"b"


def test_latency_adds_to_transmission_time():
    wire = Wire(1000, latency=0.1)
    wire.put(b"ab", 0.0)

    assert wire.take(0.1) == b""
    assert wire.take(0.11) == b"a"
    assert wire.take(0.12) == b"b"


def test_next_arrival_without_wake_bytes_is_the_next_byte():
    wire = Wire(1000)
    wire.put(b"abc\n", 0.0)

    assert wire.next_arrival() == pytest.approx(0.01)
    wire.take(0.02)
    assert wire.next_arrival() == pytest.approx(0.03)


def test_next_arrival_with_wake_bytes_is_the_next_line_end():
    wire = Wire(1000, wake=b"\n")
    wire.put(b"abc\ndef\n", 0.0)

    assert wire.next_arrival() == pytest.approx(0.04)
    assert wire.take(wire.next_arrival()) == b"abc\n"
    assert wire.next_arrival() == pytest.approx(0.08)


def test_next_arrival_without_a_wake_byte_pending_is_the_last_byte():
    wire = Wire(1000, wake=b"\n")
    wire.put(b"abc", 0.0)

    assert wire.next_arrival() == pytest.approx(0.03)


def test_take_at_the_announced_arrival_gets_the_line_on_a_large_clock():
    # Monotonic clocks run for days; float rounding must not hold the line back.
    wire = Wire(250000, wake=b"\n")
    for now in (1504.216894, 987654.321, 12345678.9):
        wire.put(b"N1 G1 X1 Y2 E0.1*97\n", now)
        assert wire.take(wire.next_arrival()) == b"N1 G1 X1 Y2 E0.1*97\n"
        assert wire.next_arrival() is None


def test_clear_loses_what_is_in_flight():
    wire = Wire(1000)
    wire.put(b"abc", 0.0)
    wire.clear()

    assert wire.take(10.0) == b""
    assert wire.pending == 0


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="baud"):
        Wire(0)
    with pytest.raises(ValueError, match="latency"):
        Wire(9600, latency=-1)
