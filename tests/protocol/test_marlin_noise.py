"""Line noise, lost oks and other firmware's habits, sans-IO: R1b, R8, R9, T5, T6, W4."""

from __future__ import annotations

import pytest

from printers.protocol.events import Ack, ResendServed, Sent
from printers.protocol.marlin import MarlinProtocol
from printers.protocol.marlin_responses import split_merged
from printers.sample_gcode import commands_of, segments
from printers.simulator.faults import FaultConfig
from tests.protocol.marlin_helpers import CHECKSUM_ERROR, events, meaning
from tests.protocol.marlin_link import run_link

JOB = commands_of(segments(100))


def one_line(**options: object) -> MarlinProtocol:
    """N1 written at t=0 (after the M110), ping-pong, not answered yet."""
    proto = MarlinProtocol(checksums="always", flow="ping_pong", **options)  # type: ignore[arg-type]
    proto.reset_line_numbers(0.0)
    proto.data_to_send()
    proto.receive_data(b"ok\n", 0.0)
    proto.send("G1 X1", 0.0, tag=1)
    proto.data_to_send()
    events(proto)
    return proto


def settle(proto: MarlinProtocol, now: float, turns: int = 4) -> tuple[float, bytes]:
    """Play deadlines until something is written; returns (now, bytes)."""
    for _ in range(turns):
        deadline = proto.next_deadline()
        if deadline is None:
            break
        now = max(now, deadline)
        proto.handle_timeout(now)
        data = proto.data_to_send()
        if data:
            return now, data
    return now, b""


# -- whole jobs over a noisy link ------------------------------------------------------


@pytest.mark.parametrize("dialect", ["marlin", "prusa", "repetier"])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_noise_both_ways_loses_and_repeats_nothing(dialect: str, seed: int) -> None:
    noise = FaultConfig(seed=seed, noise_to_firmware=0.01, noise_to_host=0.01)
    run = run_link(JOB, faults=noise, firmware={"dialect": dialect})
    assert run.failures == []
    assert run.job_commands() == JOB
    assert run.acked == list(range(len(JOB)))


@pytest.mark.parametrize("flow", ["auto", "buffered"])
def test_noise_in_windowed_flow_loses_and_repeats_nothing(flow: str) -> None:
    noise = FaultConfig(seed=8, noise_to_firmware=0.01, noise_to_host=0.01)
    run = run_link(JOB, faults=noise, protocol={"flow": flow})
    assert run.failures == []
    assert run.job_commands() == JOB


@pytest.mark.parametrize("advanced_ok", [False, True])
def test_t6_lost_oks_cost_no_ack_timeout(advanced_ok: bool) -> None:
    lost = FaultConfig(seed=1, drop_ok_every=10)
    run = run_link(JOB, faults=lost, firmware={"advanced_ok": advanced_ok})
    assert run.job_commands() == JOB
    assert run.proto is not None and run.proto.timeouts == 0
    assert run.elapsed < 10.0  # ten lost oks used to cost 10 s each


def test_smoothieware_rs_without_ok_costs_no_timeout() -> None:
    damaged = FaultConfig(seed=3, corrupt=0.2)
    run = run_link(JOB, faults=damaged, firmware={"dialect": "smoothieware"})
    assert run.job_commands() == JOB
    assert run.proto is not None and run.proto.timeouts == 0
    assert run.proto.resends > 0


def test_ok_before_resend_costs_no_timeout() -> None:
    damaged = FaultConfig(seed=3, corrupt=0.1)
    for flow in ("auto", "buffered"):
        run = run_link(
            JOB,
            faults=damaged,
            firmware={"ok_before_resend": True},
            protocol={"flow": flow},
        )
        assert run.job_commands() == JOB
        assert run.proto is not None and run.proto.timeouts == 0


@pytest.mark.parametrize("style", ["echo", "raw"])
def test_echoed_lines_are_neither_acks_nor_errors(style: str) -> None:
    run = run_link(JOB, faults=FaultConfig(seed=2), firmware={"echo_lines": style})
    assert run.job_commands() == JOB
    assert run.proto is not None and run.proto.timeouts == run.proto.resends == 0


# -- the rules one by one --------------------------------------------------------------


def test_r1b_ok_before_resend_belongs_to_the_error() -> None:
    proto = one_line()
    proto.receive_data(f"{CHECKSUM_ERROR.format(0)}\nok\nResend: 1\n".encode(), 0.1)
    assert [type(e) for e in meaning(proto)] == [ResendServed]
    now, data = settle(proto, 0.1)
    assert data.startswith(b"N1 ")
    proto.receive_data(b"ok\n", now + 0.01)  # the re-sent line's ok is not swallowed
    assert meaning(proto) == [Ack(1)]


def test_r1_resend_without_ok_then_the_copy_is_acknowledged() -> None:
    proto = one_line()
    proto.receive_data(b"rs N1\n", 0.1)  # Smoothieware: no error line, no ok
    now, data = settle(proto, 0.1)
    assert data.startswith(b"N1 ")
    proto.receive_data(b"ok\n", now + 0.01)
    assert Ack(1) in meaning(proto)


def test_r8_line_error_without_resend_sends_the_line_again_soon() -> None:
    proto = one_line()
    proto.receive_data(b"Error:No Line Number with checksum, Last Line: 0\n", 0.1)
    now, data = settle(proto, 0.1)
    assert data.startswith(b"N1 ")
    assert now < 1.0  # not the 10 s ack timeout
    assert proto.timeouts == 0


def test_r8_line_error_naming_an_acknowledged_line_sends_it_again() -> None:
    proto = one_line()
    proto.receive_data(b"ok\n", 0.05)  # taken for N1, but it was the error's
    assert meaning(proto) == [Ack(1)]
    proto.receive_data(b"Error:checksum mismatch, Last Line: 0\nResend: 1?\n", 0.1)
    _, data = settle(proto, 0.1)
    assert data.startswith(b"N1 ")


def test_r9_a_garbled_resend_swallows_its_ok() -> None:
    proto = one_line()
    proto.receive_data(b"Error:checksum mismatch, Last Line: 0\nR?send: 1\nok\n", 0.1)
    assert not any(isinstance(e, Ack) for e in events(proto))


def test_t5_an_ok_with_temperatures_answers_the_probe() -> None:
    proto = one_line()
    now, data = settle(proto, 0.0)  # T6: N1's ok is late
    assert data.startswith(b"N2 M105*")
    assert now < 1.0
    proto.receive_data(b"ok T:21.0 /0.0 B:21.0 /0.0\n", now + 0.01)
    acks = [e for e in meaning(proto) if isinstance(e, Ack)]
    assert acks == [Ack(1)]  # N1's ok was lost; nothing is sent twice
    assert proto.in_flight == 0
    assert not [e for e in events(proto) if isinstance(e, Sent)]


def test_t6_no_probe_while_a_long_command_may_hold_the_ok() -> None:
    proto = MarlinProtocol(checksums="always", flow="ping_pong")
    proto.reset_line_numbers(0.0)
    proto.data_to_send()
    proto.receive_data(b"ok\n", 0.0)
    proto.send("M109 S210", 0.0, tag="heat")
    proto.data_to_send()
    assert proto.next_deadline() == 10.0  # the ack timeout only


def test_t6_no_probe_on_reprapfirmware_which_does_not_check_the_sequence() -> None:
    proto = one_line()
    proto.receive_data(b"FIRMWARE_NAME: RepRapFirmware for Duet 3 MB6HC\n", 0.01)
    assert proto.next_deadline() == 10.0


def test_t6_no_probe_while_the_firmware_writes_lines_into_a_file() -> None:
    proto = one_line()
    proto.writing_file = True  # M28: an M105 would be written to the SD card
    assert proto.next_deadline() == 10.0
    proto.writing_file = False
    assert proto.next_deadline() < 1.0


def test_w4_a_line_asked_again_goes_alone() -> None:
    proto = MarlinProtocol(checksums="always", flow="buffered")
    proto.reset_line_numbers(0.0)
    proto.data_to_send()
    proto.receive_data(b"ok\n", 0.0)
    for n in range(1, 4):
        proto.send(f"G1 X{n}", 0.0, tag=n)
    proto.data_to_send()
    proto.receive_data(f"{CHECKSUM_ERROR.format(0)}\nResend: 1\nok\n".encode(), 0.1)
    now, data = settle(proto, 0.1)
    assert data.count(b"\n") == 1
    proto.receive_data(b"ok\n", now + 0.01)
    assert proto.data_to_send().count(b"\n") == 2


@pytest.mark.parametrize(
    ("line", "parts"),
    [
        ("okok T:21.0 /0.0", ["ok", "ok T:21.0 /0.0"]),
        ("okResend: 5", ["ok", "Resend: 5"]),
        ("Resend: 5ok", ["Resend: 5", "ok"]),
        ("Error:checksum mismatch, Last Line: 4Resend: 5", [
            "Error:checksum mismatch, Last Line: 4", "Resend: 5"]),
        ("echo:Unknown command: \"book\"", ["echo:Unknown command: \"book\""]),
        ("ok", ["ok"]),
    ],
)  # fmt: skip
def test_replies_merged_by_a_lost_line_end_are_split(
    line: str, parts: list[str]
) -> None:
    assert split_merged(line) == parts
