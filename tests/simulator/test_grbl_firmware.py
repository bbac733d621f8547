"""The GRBL model, sans-IO: bytes in, bytes out, time driven by the test."""

from __future__ import annotations

import pytest

from printers.simulator.faults import FaultConfig, Faults
from printers.simulator.grbl import GrblFirmware

BANNER = ["", "Grbl 1.1h ['$' for help]"]


class Bench:
    """A GRBL model on a test clock; returns what it printed, line by line (CRLF)."""

    def __init__(self, **options: object) -> None:
        options.setdefault("time_scale", 1.0)
        self.executed: list[str] = []
        self.fw = GrblFirmware(on_execute=self.executed.append, **options)
        self.boot = self._lines()
        self.now = 0.0

    def send(self, data: str | bytes) -> list[str]:
        self.fw.receive(
            data.encode("latin-1") if isinstance(data, str) else data, self.now
        )
        self.fw.step(self.now)
        return self._lines()

    def advance(self, seconds: float) -> list[str]:
        end = self.now + seconds
        out: list[str] = []
        while (deadline := self.fw.next_deadline()) is not None and deadline <= end:
            self.now = max(self.now, deadline)
            self.fw.step(self.now)
            out += self._lines()
        self.now = end
        self.fw.step(end)
        return out + self._lines()

    def status(self) -> str:
        (report,) = self.send("?")
        return report

    def _lines(self) -> list[str]:
        data = self.fw.data_to_send().decode("latin-1")
        assert not data or data.endswith("\r\n")
        return data.split("\r\n")[:-1] if data else []


def moves(count: int, start: int = 1, feed: int = 600) -> str:
    """*count* 10 mm moves at *feed* mm/min (one second each at 600)."""
    return "".join(f"G1 X{(start + i) * 10} F{feed}\n" for i in range(count))


def test_boot_prints_the_welcome_banner():
    assert Bench().boot == BANNER


def test_idle_status_report():
    assert (
        Bench().status()
        == "<Idle|MPos:0.000,0.000,0.000|Bf:15,128|FS:0,0|WCO:0.000,0.000,0.000>"
    )


def test_each_line_gets_one_ok():
    bench = Bench(time_scale=0.0)
    assert bench.send("G21 G90\nG1 X1 F100\n\nG0 Y2\n") == ["ok"] * 4


@pytest.mark.parametrize(
    ("line", "error"),
    [
        ("G5", 20),  # unsupported command
        ("Q1", 20),
        ("%", 1),  # expected command letter
        ("GX", 2),  # bad number format
        ("G1 X10", 22),  # undefined feed rate
        ("G0 G1 X1", 21),  # modal group violation
        ("G1 X1 X2 F1", 25),  # word repeated
        ("G1.5 X1", 23),  # not an integer
        ("G4", 28),  # value word missing
        ("G0 I5 X1", 36),  # unused word
        ("G2 X1 F100", 35),  # no offsets in plane
        ("G1 F-1 X1", 4),  # negative value
        ("X" * 80, 11),  # line overflow
    ],
)
def test_bad_lines_get_grbl_error_codes(line, error):
    bench = Bench()
    assert bench.send(line + "\n") == [f"error:{error}"]
    assert bench.executed == []


def test_ok_is_withheld_while_the_planner_is_full():
    bench = Bench()
    out = bench.send(moves(16))
    assert out == ["ok"] * 15
    assert bench.status().startswith("<Run|MPos:0.000,0.000,0.000|Bf:0,")
    assert bench.advance(0.99) == []
    assert bench.advance(0.01) == ["ok"]


def test_status_shows_rx_bytes_waiting_behind_a_blocked_line():
    bench = Bench()
    bench.send(moves(16))  # the 16th line blocks
    waiting = moves(2, start=17)
    bench.send(waiting)
    assert f"Bf:0,{128 - len(waiting)}|" in bench.status()


def test_realtime_bytes_never_enter_the_line():
    bench = Bench(time_scale=0.0)
    out = bench.send("G0 X?5\n")
    assert out[0].startswith("<Idle|")
    assert out[1] == "ok"
    assert bench.executed == ["G0 X5"]


def test_feed_hold_stops_motion_and_cycle_start_resumes_it():
    bench = Bench()
    bench.send(moves(3))
    bench.advance(0.5)
    assert bench.send("!") == []
    assert bench.status().startswith("<Hold:0|MPos:5.000,")
    bench.advance(10)
    assert bench.status().startswith("<Hold:0|MPos:5.000,")
    assert bench.send("G1 X40\n") == [
        "ok"
    ]  # lines still flow while the planner has room
    bench.send("~")
    bench.advance(0.5)
    assert bench.status().startswith("<Run|MPos:10.000,")
    bench.advance(10)
    assert bench.status().startswith("<Idle|MPos:40.000,")


def test_soft_reset_during_motion_raises_alarm_3_and_locks_gcode():
    bench = Bench()
    bench.send(moves(2))
    bench.advance(0.5)
    assert bench.send(b"\x18") == ["ALARM:3", *BANNER, "[MSG:'$H'|'$X' to unlock]"]
    assert bench.status().startswith("<Alarm|MPos:5.000,")
    assert bench.send("G0 X0\n") == ["error:9"]
    assert bench.send("$X\n") == ["[MSG:Caution: Unlocked]", "ok"]
    assert bench.send("G0 X0\n") == ["ok"]


def test_soft_reset_when_idle_just_restarts():
    bench = Bench()
    bench.send("G1 X1 F100\n")
    bench.advance(5)
    assert bench.send(b"\x18") == BANNER
    assert bench.status().startswith("<Idle|MPos:1.000,")
    assert bench.send("$G\n")[0] == "[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]"


def test_soft_reset_drops_what_waits_in_the_ring():
    bench = Bench()
    bench.send(moves(16) + moves(3, start=17))
    bench.send(b"\x18")
    assert bench.advance(30) == []
    assert bench.executed[-1] == "G1 X160 F600"


def test_eeprom_write_loses_bytes_that_arrive_during_it():
    bench = Bench()
    assert bench.send("$100=200\n") == []  # the write runs for 20 ms
    bench.now += 0.001
    assert bench.send("$101=200\n") == []  # lost
    assert bench.advance(0.1) == ["ok"]
    assert bench.fw.dropped_bytes == len("$101=200\n")
    assert bench.fw.settings[100] == 200.0
    assert bench.fw.settings[101] == 250.0


def test_eeprom_writes_sent_ping_pong_all_arrive():
    bench = Bench()
    for setting in (100, 101, 102):
        bench.send(f"${setting}=200\n")
        assert bench.advance(0.1) == ["ok"]
    assert bench.fw.dropped_bytes == 0


def test_settings_listing():
    out = Bench().send("$$\n")
    assert out[0] == "$0=10"
    assert "$10=3" in out
    assert "$110=500.000" in out
    assert out[-1] == "ok"


@pytest.mark.parametrize(
    ("line", "error"),
    [("$999=1", 3), ("$100=-1", 4), ("$0=2", 6), ("$1=x", 2), ("$GX", 3)],
)
def test_bad_settings_are_refused(line, error):
    assert Bench().send(line + "\n") == [f"error:{error}"]


def test_build_info_and_parser_state():
    bench = Bench()
    assert bench.send("$I\n") == ["[VER:1.1h.20190825:]", "[OPT:V,15,128]", "ok"]
    bench.send("G91 G20 M3 S1000 F10\n")
    assert bench.send("$G\n") == [
        "[GC:G0 G54 G17 G20 G91 G94 M3 M9 T0 F10 S1000]",
        "ok",
    ]


def test_parameters_report():
    bench = Bench(time_scale=0.0)
    bench.send("G10 L2 P2 X1 Y2 Z3\n")
    out = bench.send("$#\n")
    assert out[1] == "[G55:1.000,2.000,3.000]"
    assert out[-2] == "[PRB:0.000,0.000,0.000:0]"


def test_check_mode_parses_without_moving_and_resets_on_exit():
    bench = Bench()
    assert bench.send("$C\n") == ["[MSG:Enabled]", "ok"]
    assert bench.send("G1 X100 F10\n") == ["ok"]
    assert bench.send("G5\n") == ["error:20"]
    assert bench.status().startswith("<Check|MPos:0.000,")
    assert bench.send("$C\n") == ["[MSG:Disabled]", "ok", *BANNER]


def test_homing_takes_time_then_idles_at_zero():
    bench = Bench()
    bench.send("G0 X5\n")
    bench.advance(5)
    assert bench.send("$H\n") == []
    assert bench.status().startswith("<Home|")
    assert bench.advance(2.0) == ["ok"]
    assert bench.status().startswith("<Idle|MPos:0.000,0.000,0.000|")


def test_jog_runs_and_jog_cancel_stops_it():
    bench = Bench()
    assert bench.send("$J=G91 X10 F600\n") == ["ok"]
    bench.advance(0.3)
    assert bench.status().startswith("<Jog|MPos:3.000,")
    assert bench.send("G1 X1 F10\n") == ["error:9"]
    bench.send(b"\x85")
    assert bench.status().startswith("<Idle|MPos:3.000,")
    assert bench.send("$J=X5\n") == ["error:22"]


def test_feed_override_changes_execution_speed():
    bench = Bench()
    bench.send(bytes([0x91] * 10))  # +100 %: double speed
    bench.send("G1 X10 F600\n")
    bench.advance(0.25)
    assert (
        bench.status()
        == "<Run|MPos:5.000,0.000,0.000|Bf:14,128|FS:1200,0|Ov:200,100,100>"
    )
    bench.send(bytes([0x90]))  # back to 100 %
    bench.advance(0.25)
    assert bench.status().startswith("<Run|MPos:7.500,")


def test_spindle_change_waits_for_the_planner():
    bench = Bench()
    bench.send("G1 X10 F600\n")
    assert bench.send("M3 S1000\n") == []
    assert bench.advance(1.0) == ["ok"]


def test_dwell_waits_for_motion_then_the_time():
    bench = Bench()
    bench.send("G1 X10 F600\n")
    bench.send("G4 P0.5\n")
    assert bench.advance(1.4) == []
    assert bench.advance(0.1) == ["ok"]


def test_program_end_reports():
    assert Bench(time_scale=0.0).send("M2\n") == ["[MSG:Pgm End]", "ok"]


def test_ring_overflows_while_a_line_blocks():
    bench = Bench()
    bench.send(moves(16))
    bench.send("".join(f"G1 X{n:03}\n" for n in range(40)))  # 8 bytes each
    assert bench.fw.dropped_bytes == 40 * 8 - 128


def test_halt_locks_until_a_soft_reset():
    bench = Bench()
    bench.fw.halt(bench.now)
    assert bench.send("") == ["ALARM:1", "[MSG:Reset to continue]"]
    assert bench.send("G0 X1\n$X\n") == []
    assert bench.status().startswith("<Alarm|")
    assert bench.send(b"\x18") == [*BANNER, "[MSG:'$H'|'$X' to unlock]"]
    assert bench.send("$X\n") == ["[MSG:Caution: Unlocked]", "ok"]


def test_faults_drop_oks_and_stall_lines():
    bench = Bench(time_scale=0.0, faults=Faults(FaultConfig(drop_ok_every=2)))
    assert bench.send("G0 X1\nG0 X2\nG0 X3\n") == ["ok", "ok"]
    bench = Bench(faults=Faults(FaultConfig(busy_after=1, busy_seconds=2.0)))
    assert bench.send("G0 X1\n") == []
    assert bench.advance(2.0) == ["ok"]


def test_grblhal_variant_has_its_banner_build_info_and_a_big_ring():
    bench = Bench(variant="grblhal")
    assert bench.boot == ["", "GrblHAL 1.1f ['$' or '$HELP' for help]"]
    assert bench.send("$I\n") == [
        "[VER:1.1f.20231210:]",
        "[OPT:VNMSL,15,1024,3,0]",
        "[NEWOPT:ENUMS,RT+,HOME,SED]",
        "[FIRMWARE:grblHAL]",
        "ok",
    ]
    bench.send(moves(16))  # the planner is full: the ring fills
    waiting = "".join(f"G1 X{n:03}\n" for n in range(100))  # 800 bytes
    bench.send(waiting)
    assert bench.fw.dropped_bytes == 0
    assert "|Bf:0,224|" in bench.status()


def test_an_unknown_variant_is_refused():
    with pytest.raises(ValueError, match="unknown GRBL variant 'smoothie'"):
        GrblFirmware(variant="smoothie")


@pytest.mark.parametrize("line", ["$100=200", "$N0=G21", "$I=router", "$RST=$"])
def test_eeprom_commands_are_refused_while_the_machine_moves(line):
    bench = Bench()
    assert bench.send(moves(2)) == ["ok", "ok"]
    assert bench.send(line + "\n") == ["error:8"]
    bench.advance(3)
    bench.send(line + "\n")  # Idle now: the write runs
    assert "ok" in bench.advance(0.1)


def test_coordinate_writes_wait_for_the_planner_to_empty():
    bench = Bench()
    assert bench.send(moves(2)) == ["ok", "ok"]
    assert bench.send("G10 L20 P1 X0\n") == []  # its ok waits for the moves
    assert bench.advance(1.5) == []
    assert bench.advance(1.0) == ["ok"]


def test_the_cli_refuses_a_variant_for_marlin(capsys):
    from printers.simulator.cli import main

    assert main(["marlin", "--variant", "grblhal", "--tcp", "127.0.0.1:0"]) == 2
    assert "--variant is for grbl only" in capsys.readouterr().err
