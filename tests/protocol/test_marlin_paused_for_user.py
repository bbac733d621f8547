"""`busy: paused for user`: a firmware waiting for a person has no ack deadline."""

from __future__ import annotations

from printers.protocol.events import Ack, Busy, Event, LinkFailed
from printers.protocol.marlin import MarlinProtocol


def _streaming(command: str = "M600") -> MarlinProtocol:
    """N1 <command> and N2 written at t=0, ack_timeout 1 s, busy_timeout 2 s."""
    proto = MarlinProtocol(
        checksums="always", flow="buffered", ack_timeout=1.0, busy_timeout=2.0
    )
    proto.reset_line_numbers(0.0)
    proto.data_to_send()
    proto.receive_data(b"ok\n", 0.0)
    proto.send(command, 0.0, tag=1)
    proto.send("G1 X1", 0.0, tag=2)
    proto.data_to_send()
    _events(proto)
    return proto


def _events(proto: MarlinProtocol) -> list[Event]:
    out = []
    while (event := proto.next_event()) is not None:
        out.append(event)
    return out


def test_paused_for_user_has_no_deadline_however_long_the_user_takes() -> None:
    proto = _streaming()
    proto.receive_data(b"echo:busy: paused for user\n", 0.5)
    assert proto.next_deadline() is None
    proto.handle_timeout(3600.0)
    assert proto.data_to_send() == b""  # no re-send, no probe
    assert not any(isinstance(e, LinkFailed) for e in _events(proto))


def test_paused_for_input_has_no_deadline_either() -> None:
    proto = _streaming("M0")
    proto.receive_data(b"busy: paused for input\n", 0.5)
    assert proto.next_deadline() is None


def test_normal_timing_returns_once_the_oks_flow_again() -> None:
    proto = _streaming()
    proto.receive_data(b"echo:busy: paused for user\n", 0.5)
    proto.receive_data(b"ok\n", 600.0)  # the user answered ten minutes later
    assert [e for e in _events(proto) if isinstance(e, Ack)] == [Ack(1)]
    assert proto.next_deadline() == 601.0  # G1 X1: ack_timeout from the last ok


def test_busy_processing_keeps_its_bound() -> None:
    proto = _streaming("G28")
    proto.receive_data(b"echo:busy: processing\n", 0.5)
    assert [e for e in _events(proto) if isinstance(e, Busy)] == [Busy("processing")]
    assert proto.next_deadline() == 2.5


def test_a_processing_busy_after_the_user_answered_is_bounded_again() -> None:
    proto = _streaming()
    proto.receive_data(b"echo:busy: paused for user\n", 0.5)
    proto.receive_data(b"echo:busy: processing\n", 30.0)
    assert proto.next_deadline() == 32.0
