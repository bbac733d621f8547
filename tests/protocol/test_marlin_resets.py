"""Resets the firmware does not announce clearly (R7, `start` after junk): never replay."""

from __future__ import annotations

import pytest

from printers.protocol.checksum import format_line
from printers.protocol.events import Ack, FirmwareReset, ResendServed, Sent
from printers.protocol.marlin import MarlinProtocol
from tests.protocol.marlin_helpers import (
    CHECKSUM_ERROR,
    JOB,
    TinyMarlin,
    events,
    meaning,
    run,
)


def streamed(flow: str) -> tuple[MarlinProtocol, TinyMarlin]:
    proto, firmware = MarlinProtocol(checksums="always", flow=flow), TinyMarlin()
    run(proto, firmware, JOB)  # lines 1..30 acknowledged
    return proto, firmware


@pytest.mark.parametrize("flow", ["ping_pong", "buffered"])
def test_r7_resend_for_line_one_mid_job_is_a_reset(flow: str) -> None:
    proto, firmware = streamed(flow)
    firmware.last_n = 0  # it reset and printed nothing
    proto.send("G1 X99", 1.0, tag="next")
    proto.receive_data(firmware(proto.data_to_send()), 1.1)
    assert meaning(proto) == []  # once could be line noise: ignored, not served
    assert proto.data_to_send() == b""
    data = b""
    for _ in range(3):  # the hold after the Resend, then T6: a probe goes out
        proto.handle_timeout(proto.next_deadline() or 2.0)
        data = proto.data_to_send()
        if data:
            break
    assert data.startswith(b"N32 M105*")
    proto.receive_data(firmware(format_line(32, "M105").encode() + b"\n"), 2.1)
    log = events(proto)
    assert FirmwareReset("Resend: 1 after line 30 was acknowledged") in log
    assert not any(isinstance(e, ResendServed | Ack) for e in log)
    assert proto.data_to_send() == b""  # nothing replayed
    assert proto.in_flight == 0


def test_r7_one_garbled_request_far_back_is_ignored() -> None:
    proto, firmware = streamed("ping_pong")
    proto.send("G1 X99", 1.0, tag="next")
    proto.data_to_send()
    # "Last Line: 30 / Resend: 31" with a digit lost in both lines
    proto.receive_data(b"Error:checksum mismatch, Last Line: 3\nResend: 4\nok\n", 1.1)
    assert meaning(proto) == []
    proto.receive_data(f"{CHECKSUM_ERROR.format(30)}\nResend: 31\nok\n".encode(), 1.2)
    assert [type(e) for e in meaning(proto)] == [ResendServed]


def test_r7_leftover_resends_after_the_reset_are_ignored() -> None:
    proto, firmware = streamed("buffered")
    firmware.last_n = 0
    for i in range(3):
        proto.send(f"G1 X{90 + i}", 1.0, tag=i)
    proto.receive_data(firmware(proto.data_to_send()), 1.1)  # three Resend: 1
    resets = [e for e in events(proto) if isinstance(e, FirmwareReset)]
    assert len(resets) == 1
    proto.send("G28", 2.0, tag="after")  # renumbers from M110 N0 (F2)
    assert proto.data_to_send() == b"N0 M110 N0*125\n"


def test_r7_resend_just_behind_the_oldest_unacked_line_is_served() -> None:
    # An error's ok taken for line 29's (its Error and Resend lost to noise) made
    # the host count line 29 as done: the firmware may ask for it once more.
    proto, _ = streamed("ping_pong")
    proto.send("G1 X99", 1.0, tag="next")
    proto.data_to_send()
    proto.receive_data(b"Resend: 29\nok\n", 1.1)
    log = events(proto)
    assert not any(isinstance(e, FirmwareReset) for e in log)
    proto.handle_timeout(proto.next_deadline() or 2.0)
    assert proto.data_to_send().startswith(b"N29 ")
    assert [e.line_number for e in events(proto) if isinstance(e, Sent)] == [29]


@pytest.mark.parametrize(
    "banner", [b"\xfe\xff\x00start\n", b"\x00start\n", b"\xe0start\r\n", b"start\n"]
)
def test_start_after_boot_noise_is_a_reset(banner: bytes) -> None:
    proto, _ = streamed("buffered")
    proto.send("G1 X99", 1.0, tag="next")
    proto.data_to_send()
    proto.receive_data(banner + b"echo:Marlin 2.1.2.4\n", 1.1)
    assert meaning(proto)[0] == FirmwareReset("start")
    assert proto.in_flight == 0


@pytest.mark.parametrize("line", [b"echo:restart\n", b"xstart\n", b"ok start\n"])
def test_start_inside_ordinary_words_is_not_a_reset(line: bytes) -> None:
    proto, _ = streamed("buffered")
    proto.receive_data(line, 1.0)
    assert not any(isinstance(e, FirmwareReset) for e in events(proto))
