"""GrblProtocol's host rules: EEPROM writes wait for Idle, the RX budget from `$I`,
check mode, grblHAL's name."""

from __future__ import annotations

import pytest

from printers.protocol.errors import LocalProtocolError
from printers.protocol.events import Ack, FirmwareInfo, LinkFailed, Received, Sent
from printers.protocol.grbl import GrblProtocol
from printers.protocol.grbl_events import BuildOptions, CheckMode
from tests.protocol.grbl_helpers import EEPROM_WRITES, drain, fill, make


def answer_all(protocol: GrblProtocol, now: float) -> None:
    protocol.data_to_send()
    protocol.receive_data(b"ok\r\n" * protocol.in_flight, now)
    drain(protocol)


@pytest.mark.parametrize("text", EEPROM_WRITES)
def test_an_eeprom_write_waits_for_an_idle_report_after_the_last_answer(
    text: str,
) -> None:
    protocol = make()
    protocol.send("G1X100F100", 0.0, tag="move")
    protocol.receive_data(b"<Idle|MPos:0,0,0>\r\n", 0.0)  # before the move: stale
    answer_all(protocol, 0.1)
    # Every line answered, but the machine may still be moving: hold the write.
    assert not protocol.can_send(text)
    with pytest.raises(LocalProtocolError, match="waits until GRBL reports Idle"):
        protocol.send(text, 0.1)
    # It polls for the report by itself, although this protocol polls nothing else.
    assert protocol.data_to_send() == b"?"
    protocol.receive_data(b"<Run|MPos:5,0,0>\r\n", 0.15)
    assert not protocol.can_send(text)
    assert protocol.next_deadline() == pytest.approx(0.2)
    protocol._now = 0.2
    assert protocol.data_to_send() == b"?"
    protocol.receive_data(b"<Idle|MPos:100,0,0>\r\n", 0.25)
    assert protocol.can_send(text)
    protocol.send(text, 0.25, tag="eeprom")
    assert protocol.data_to_send().endswith(b"\n")
    assert protocol.next_deadline() == pytest.approx(0.25 + protocol.ack_timeout)


@pytest.mark.parametrize("state", ["Idle", "Alarm", "Check"])
def test_an_eeprom_write_goes_when_nothing_can_move(state: str) -> None:
    protocol = make()
    protocol.receive_data(f"<{state}|MPos:0,0,0>\r\n".encode(), 0.0)
    assert protocol.can_send("$100=250")


@pytest.mark.parametrize("state", ["Run", "Hold:0", "Jog", "Home", "Door:1", "Sleep"])
def test_an_eeprom_write_waits_while_the_machine_may_move(state: str) -> None:
    protocol = make()
    protocol.receive_data(f"<{state}|MPos:0,0,0>\r\n".encode(), 0.0)
    assert not protocol.can_send("G10L2P1X0")


def test_other_lines_never_wait_for_a_report() -> None:
    protocol = make()
    assert fill(protocol, "G1X1") == 25
    assert protocol.data_to_send() == b"G1X1\n" * 25


def test_a_dropped_eeprom_write_stops_the_extra_polls() -> None:
    protocol = make()
    assert not protocol.can_send("$N0=G21")
    assert protocol.next_deadline() == 0.0 or protocol.next_deadline() is None
    protocol.receive_data(b"", 0.0)
    assert protocol.data_to_send() == b"?"
    protocol.abandon()  # the command's stream failed: nothing waits any more
    protocol.receive_data(b"", 5.0)
    assert protocol.data_to_send() == b""
    assert protocol.next_deadline() is None


def test_build_options_set_the_rx_budget() -> None:
    protocol = make()
    protocol.receive_data(b"[OPT:VNMSL,35,1024,3,0]\r\n", 0.0)
    assert [e for e in drain(protocol) if not isinstance(e, Received)] == [
        BuildOptions("VNMSL", 35, 1024, {"OPT": "VNMSL,35,1024,3,0"})
    ]
    assert protocol.rx_buffer == 1023  # the ring keeps one byte free
    assert fill(protocol, "G1X1") == 204  # 204 * 5 = 1020 bytes in flight
    protocol.abandon()
    protocol.receive_data(b"[OPT:V,15,128]\r\n", 0.0)
    assert protocol.rx_buffer == 127
    assert fill(protocol, "G1X1") == 25


def test_a_tiny_reported_buffer_shortens_the_longest_line() -> None:
    protocol = make()
    protocol.receive_data(b"[OPT:V,15,64]\r\n", 0.0)
    assert (protocol.rx_buffer, protocol.max_line_length) == (63, 62)
    assert protocol.can_send("G1X" + "1" * 70)  # so that send() says why not
    with pytest.raises(Exception, match="at most 62"):
        protocol.send("G1X" + "1" * 70, 0.0)


def test_options_without_sizes_keep_the_budget() -> None:
    protocol = make(rx_buffer=100)
    protocol.receive_data(b"[OPT:VL]\r\n", 0.0)
    assert protocol.rx_buffer == 100


def test_grblhal_is_named_with_its_version() -> None:
    protocol = make()
    protocol.receive_data(
        b"[VER:1.1f.20231210:]\r\n[OPT:VNMSL,35,1024,3,0]\r\n[FIRMWARE:grblHAL]\r\n",
        0.0,
    )
    infos = [e for e in drain(protocol) if isinstance(e, FirmwareInfo)]
    assert [i.name for i in infos] == ["Grbl 1.1f.20231210", "grblHAL 1.1f.20231210"]
    assert infos[1].fields == {"FIRMWARE": "grblHAL", "VER": "1.1f.20231210"}


def test_check_mode_follows_messages_reports_and_resets() -> None:
    protocol = make()
    protocol.send("$C", 0.0, tag="c")
    protocol.data_to_send()
    protocol.receive_data(b"[MSG:Enabled]\r\nok\r\n", 0.1)
    assert CheckMode(enabled=True) in drain(protocol)
    assert protocol.check_mode
    protocol.receive_data(b"<Check|MPos:0,0,0>\r\n", 0.2)
    assert protocol.check_mode
    protocol.receive_data(b"[MSG:Disabled]\r\n", 0.3)
    assert not protocol.check_mode
    protocol.receive_data(b"<Check|MPos:0,0,0>\r\n", 0.4)
    assert protocol.check_mode
    protocol.receive_data(b"Grbl 1.1h ['$' for help]\r\n", 0.5)
    assert not protocol.check_mode


def test_jog_cancel_is_uncounted_and_goes_ahead_of_queued_lines() -> None:
    protocol = make()
    protocol.receive_data(b"<Idle|MPos:0,0,0>\r\n", 0.0)
    count = fill(protocol, "$J=G91X1F100")
    protocol.send_emergency("\x85", 0.1)
    wire = protocol.data_to_send()
    assert wire == b"\x85" + b"$J=G91X1F100\n" * count
    assert Sent("<0x85 jog cancel>") in drain(protocol)
    assert protocol.in_flight == count
    protocol.receive_data(b"ok\r\n", 0.2)
    assert Ack(0) in drain(protocol)


def test_a_grbl_that_never_reports_fails_the_link_while_a_write_waits() -> None:
    protocol = make(ack_timeout=5.0)
    protocol.receive_data(b"", 0.0)
    assert not protocol.can_send("$100=250")
    assert protocol.data_to_send() == b"?"
    now = 0.0
    failures = []
    while now < 12.0:
        now = max(now + 0.05, protocol.next_deadline() or now)
        protocol.handle_timeout(now)
        protocol.data_to_send()  # asks again now and then
        failures += [e for e in drain(protocol) if isinstance(e, LinkFailed)]
    assert len(failures) == 1
    assert "no status poll within 5 s" in failures[0].message


def test_reports_keep_a_waiting_write_from_failing_the_link() -> None:
    protocol = make(ack_timeout=5.0)
    protocol.receive_data(b"", 0.0)
    assert not protocol.can_send("$100=250")
    for step in range(200):  # 20 s of Hold: the write waits, the link is fine
        now = step * 0.1
        protocol.handle_timeout(now)
        if protocol.data_to_send() == b"?":
            protocol.receive_data(b"<Hold:0|MPos:0,0,0>\r\n", now)
        assert not any(isinstance(e, LinkFailed) for e in drain(protocol))
    assert not protocol.can_send("$100=250")
