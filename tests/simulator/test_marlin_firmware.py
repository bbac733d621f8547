"""The Marlin model, sans-IO: bytes in, bytes out, time driven by the test."""

from __future__ import annotations

import pytest

from printers.protocol.checksum import format_line
from printers.simulator.faults import FaultConfig, Faults
from printers.simulator.marlin import MarlinFirmware

BOOT = [
    "start",
    "echo:Marlin 2.1.2.4",
    "",
    "echo: Last Updated: 2024-06-20 | Author: (printhost simulator)",
    "echo:Compiled: Jun 20 2024",
    "echo: Free Memory: 2683  PlannerBufferBytes: 1600",
]


class Bench:
    """A firmware model on a test clock; returns what it printed, line by line."""

    def __init__(self, **options: object) -> None:
        options.setdefault("time_scale", 0.0)
        self.executed: list[str] = []
        self.fw = MarlinFirmware(on_execute=self.executed.append, **options)
        self.boot = self._lines()
        self.now = 0.0

    def send(self, data: str | bytes) -> list[str]:
        self.fw.receive(data.encode() if isinstance(data, str) else data, self.now)
        self.fw.step(self.now)
        return self._lines()

    def framed(self, n: int, command: str) -> list[str]:
        return self.send(format_line(n, command) + "\n")

    def advance(self, seconds: float) -> list[str]:
        """Step through every deadline up to now + seconds."""
        end = self.now + seconds
        out: list[str] = []
        while (deadline := self.fw.next_deadline()) is not None and deadline <= end:
            self.now = max(self.now, deadline)
            self.fw.step(self.now)
            out += self._lines()
        self.now = end
        self.fw.step(end)
        return out + self._lines()

    def _lines(self) -> list[str]:
        data = self.fw.data_to_send().decode()
        return data.split("\n")[:-1] if data else []


def test_boot_prints_start_and_the_banner():
    assert Bench().boot == BOOT


def test_numbered_line_gets_advanced_ok_with_its_number():
    bench = Bench()
    assert bench.framed(1, "G1 X10 F3000") == ["ok N1 P15 B3"]
    assert bench.send("G1 X20\n") == ["ok P15 B3"]


def test_plain_ok_without_advanced_ok():
    assert Bench(advanced_ok=False).framed(1, "G28") == [
        "X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0",
        "ok",
    ]


def test_line_number_is_checked_before_the_checksum():
    bench = Bench()
    assert bench.send("N5 G1 X1*0\n") == [
        "Error:Line Number is not Last Line Number+1, Last Line: 0",
        "Resend: 1",
        "ok",
    ]


def test_checksum_mismatch_asks_for_the_line_again_then_ok():
    bench = Bench()
    bench.framed(1, "G1 X1")
    assert bench.send("N2 G1 X2*0\n") == [
        "Error:checksum mismatch, Last Line: 1",
        "Resend: 2",
        "ok",
    ]
    assert bench.framed(2, "G1 X2") == ["ok N2 P15 B3"]


def test_numbered_line_without_checksum_is_an_error():
    assert Bench().send("N1 G1 X1\n") == [
        "Error:No Checksum with line number, Last Line: 0",
        "Resend: 1",
        "ok",
    ]


def test_line_error_flushes_what_waits_in_the_rx_ring():
    bench = Bench()
    good = format_line(2, "G1 X2") + "\n"
    assert bench.send("N1 G1 X1*0\n" + good) == [
        "Error:checksum mismatch, Last Line: 0",
        "Resend: 1",
        "ok",
    ]
    assert bench.executed == []


def test_lines_still_in_flight_after_an_error_each_get_their_own_error():
    # Marlin does not cooperate with pipelining: line 3 arrives after the flush.
    bench = Bench()
    bench.send("N1 G1 X1*0\n")
    assert bench.framed(2, "G1 X2")[0].startswith("Error:Line Number is not")


def test_m110_sets_the_line_counter_without_a_line_number_check():
    bench = Bench()
    bench.framed(1, "G1 X1")
    assert bench.framed(99, "M110 N41") == ["ok N99 P15 B3"]
    assert bench.framed(42, "G1 X2") == ["ok N42 P15 B3"]
    assert bench.send("M110 N0\n") == ["ok P15 B3"]
    assert bench.framed(1, "G1 X3") == ["ok N1 P15 B3"]


def test_unnumbered_lines_are_accepted_without_checks():
    bench = Bench()
    bench.framed(1, "G1 X1")
    assert bench.send("G1 X5\n") == ["ok P15 B3"]
    assert bench.executed[-1] == "G1 X5"


def test_a_checksum_without_line_number_is_refused_alone():
    # The tail of a line split by noise: refused (Prusa, Marlin 1.x), not run.
    bench = Bench()
    bench.framed(1, "G1 X1")
    assert bench.send("G1 X5*99\n") == [
        "Error:No Line Number with checksum, Last Line: 1"
    ]
    assert bench.executed[-1] == "G1 X1"


def test_lines_longer_than_95_characters_are_cut():
    bench = Bench()
    line = "M117 " + "x" * 200
    bench.send(line + "\n")
    assert bench.executed == [line[:95]]


def test_comments_and_empty_lines_are_ignored():
    bench = Bench()
    assert bench.send("\n  \n; just a comment\nG1 X1 ; move\r\n") == ["ok P15 B3"]
    assert bench.executed == ["G1 X1"]


def test_unknown_command_is_echoed_and_acknowledged():
    assert Bench().send("G99 X1\n") == ['echo:Unknown command: "G99 X1"', "ok P15 B3"]


def test_m105_reports_temperatures_in_its_ok():
    assert Bench().send("M105\n") == [
        "ok T:21.00 /0.00 B:21.00 /0.00 T0:21.00 /0.00 @:0 B@:0"
    ]


def test_m114_reports_the_position():
    bench = Bench()
    bench.send("G1 X10 Y-2.5 Z0.3 E1 F600\n")
    assert (
        bench.send("M114\n")[0]
        == "X:10.00 Y:-2.50 Z:0.30 E:1.00 Count X:800 Y:-200 Z:120"
    )


@pytest.mark.parametrize("parser", [True, False])
def test_m115_names_the_firmware_and_its_capabilities(parser):
    reply = Bench(emergency_parser=parser).send("M115\n")
    assert reply[0].startswith("FIRMWARE_NAME:Marlin 2.1.2.4 (printhost simulator) ")
    assert (
        "PROTOCOL_VERSION:1.0 MACHINE_TYPE:printhost-sim EXTRUDER_COUNT:1 UUID:"
        in reply[0]
    )
    for cap in (
        "EEPROM:1",
        "AUTOREPORT_TEMP:1",
        "HOST_ACTION_COMMANDS:1",
        "PROMPT_SUPPORT:1",
    ):
        assert f"Cap:{cap}" in reply
    assert f"Cap:EMERGENCY_PARSER:{int(parser)}" in reply
    assert reply[-1] == "ok P15 B3"


def test_ok_of_a_move_is_withheld_while_the_planner_is_full():
    bench = Bench(time_scale=1.0)
    replies = []
    for n in range(1, 17):  # 10 mm at 600 mm/min: one second each
        replies += bench.framed(n, f"G1 X{n * 10} F600")
    assert replies[-1] == "ok N15 P0 B3"
    assert len(replies) == 15
    assert bench.advance(0.99) == []
    assert bench.advance(0.01) == ["ok N16 P0 B3"]


def test_queue_slots_count_the_command_being_acknowledged():
    bench = Bench(time_scale=1.0)
    bench.send("G4 S1\n")
    for n in range(1, 4):
        assert bench.send(f"M117 {n}\n") == []
    assert bench.advance(1.0) == ["ok P15 B0", "ok P15 B1", "ok P15 B2", "ok P15 B3"]


def test_full_queue_leaves_bytes_in_the_ring_and_drops_the_rest():
    bench = Bench(time_scale=1.0)
    bench.send("G4 S1\nM117 1\nM117 2\nM117 3\n")  # the queue is full
    lines = "".join(f"M117 {n:04}\n" for n in range(20))  # 200 bytes, 10 a line
    bench.send(lines)

    assert bench.fw.dropped_bytes == 200 - 128
    assert len(bench.advance(1.0)) == 1 + 3 + 12  # G4, the queued three, the ring
    assert bench.executed[-1] == "M117 0011"  # 12 lines fitted, the 13th is cut
    bench.send("\n")
    assert bench.executed[-1] == "M117 001"


def test_keepalive_while_one_command_blocks():
    bench = Bench(time_scale=1.0)
    bench.send("G4 S5\n")
    out = bench.advance(5.0)
    assert out == ["echo:busy: processing", "echo:busy: processing", "ok P15 B3"]


def test_keepalive_interval_follows_m113():
    bench = Bench(time_scale=1.0)
    bench.send("M113 S1\n")
    bench.send("G4 S2.5\n")
    assert bench.advance(2.5).count("echo:busy: processing") == 2


def test_m109_reports_every_second_until_the_target_is_reached():
    bench = Bench(time_scale=1.0)
    assert bench.send("M109 S30\n") == [
        " T:21.00 /30.00 B:21.00 /0.00 T0:21.00 /30.00 @:127 B@:0 W:?"
    ]
    out = bench.advance(3.0)
    assert out[0].startswith(" T:25.00 /30.00")
    assert out[-1] == "ok P15 B3"
    assert "echo:busy: processing" in out


def test_m108_cancels_a_heating_wait_through_the_emergency_parser():
    bench = Bench(time_scale=1.0)
    bench.send("M109 S200\nM117 a\nM117 b\nM117 c\n")  # queue full
    out = bench.send("M108\n")
    # M109 ends (B counts the four queued), the queue drains, then M108's own ok.
    assert out == ["ok P15 B0", "ok P15 B1", "ok P15 B2", "ok P15 B3", "ok P15 B3"]
    assert bench.executed[-1] == "M108"


def test_m108_without_the_parser_waits_for_a_queue_slot():
    bench = Bench(time_scale=1.0, emergency_parser=False)
    bench.send("M109 S200\nM117 a\nM117 b\nM117 c\n")
    assert bench.send("M108\n") == []
    assert bench.advance(2.0)[-1].startswith(" T:")


def test_m112_kills_at_once_even_with_the_queue_full():
    bench = Bench(time_scale=1.0)
    bench.send("G4 S10\nM117 a\nM117 b\nM117 c\n")
    assert bench.send("M112\n") == [
        "Error:Printer halted. kill() called!",
        "//action:kill",
    ]
    assert bench.send("M105\n") == []
    assert bench.advance(20) == []


def test_reset_after_a_kill_boots_again_and_forgets_line_numbers():
    bench = Bench()
    bench.framed(1, "G1 X1")
    bench.send("M112\n")
    bench.fw.reset(bench.now)
    assert bench.advance(0.0) == BOOT
    assert bench.framed(1, "G1 X1") == ["ok N1 P15 B3"]


def test_m410_drops_the_planned_moves():
    bench = Bench(time_scale=1.0)
    for n in range(1, 17):
        bench.framed(n, f"G1 X{n * 10} F600")
    out = bench.send("M410\n")
    assert out[0] == "ok N16 P15 B3"  # the waiting move is refused
    assert bench.fw.planner.idle()


def test_m155_reports_temperatures_automatically():
    bench = Bench(time_scale=1.0)
    bench.send("M155 S2\n")
    out = bench.advance(4.0)
    assert out == [" T:21.00 /0.00 B:21.00 /0.00 T0:21.00 /0.00 @:0 B@:0"] * 2
    bench.send("M155 S0\n")
    assert bench.advance(10.0) == []


def test_time_scale_zero_makes_waits_instant():
    bench = Bench(time_scale=0.0)
    out = bench.send("M109 S210\nM190 S60\nG28\nG4 S30\nM400\n")
    assert out.count("ok P15 B3") == 5


def test_executed_commands_are_reported_in_order_without_framing():
    bench = Bench()
    bench.framed(1, "G1 X1")
    bench.send("N2 G1 X2*0\n")  # rejected: not executed
    bench.framed(2, "G1 X2")
    bench.send("M105\n")
    assert bench.executed == ["G1 X1", "G1 X2", "M105"]
    assert bench.fw.executed_count == 3


# -- faults -------------------------------------------------------------------------


def make_faults(**config: object) -> Faults:
    return Faults(FaultConfig(seed=1, **config))


def test_corrupted_lines_fail_their_checksum_and_are_asked_again():
    bench = Bench(faults=make_faults(corrupt=1.0))
    out = bench.framed(1, "G1 X10 Y20")
    assert out[0].startswith(
        ("Error:checksum mismatch", "Error:Line Number", "Error:No Checksum")
    )
    assert out[1:] == ["Resend: 1", "ok"]
    assert bench.executed == []


def test_corruption_spares_the_leading_n():
    faults = make_faults(corrupt=1.0)
    for _ in range(200):
        assert faults.corrupt_line(b"N12 G1 X1*99").startswith(b"N")


def test_every_nth_ok_is_dropped():
    bench = Bench(faults=make_faults(drop_ok_every=3))
    replies = [bench.framed(n, "G1 X1") for n in range(1, 7)]
    assert replies == [
        ["ok N1 P15 B3"],
        ["ok N2 P15 B3"],
        [],
        ["ok N4 P15 B3"],
        ["ok N5 P15 B3"],
        [],
    ]


def test_reset_after_n_commands_prints_the_banner():
    bench = Bench(faults=make_faults(reset_after=2))
    bench.framed(1, "G1 X1")
    out = bench.framed(2, "G1 X2")
    assert out == ["ok N2 P15 B3", *BOOT]
    assert bench.framed(3, "G1 X3")[0].startswith("Error:Line Number")


def test_busy_at_the_nth_command_withholds_its_ok_with_keepalives():
    bench = Bench(faults=make_faults(busy_after=2, busy_seconds=5.0))
    bench.framed(1, "G1 X1")
    assert bench.framed(2, "G1 X2") == []
    out = bench.advance(5.0)
    assert out == ["echo:busy: processing", "echo:busy: processing", "ok N2 P15 B3"]


def test_stall_from_the_control_socket_holds_everything():
    bench = Bench()
    bench.fw.stall(bench.now, 3.0)
    assert bench.send("M105\n") == []
    assert bench.advance(3.0)[-1].startswith("ok T:")
