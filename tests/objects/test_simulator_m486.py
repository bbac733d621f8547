"""The Marlin simulator's CANCEL_OBJECTS mode (`--cancel-objects`), sans-IO."""

from __future__ import annotations

from printers.simulator.marlin import MarlinFirmware


class Bench:
    """A firmware on a test clock; each command sent unnumbered, then run."""

    def __init__(self, **options: object) -> None:
        self.fw = MarlinFirmware(time_scale=0.0, **options)
        self.fw.data_to_send()
        self.now = 0.0

    def run(self, *commands: str) -> list[str]:
        out: list[str] = []
        for command in commands:
            self.fw.receive(f"{command}\n".encode(), self.now)
            for _ in range(50):
                self.now += 0.01
                self.fw.step(self.now)
            out += self.fw.data_to_send().decode().splitlines()
        return [line for line in out if not line.startswith("ok")]


def test_m115_reports_cancel_objects_only_when_it_is_on():
    assert "Cap:CANCEL_OBJECTS:1" in Bench(cancel_objects=True).run("M115")
    assert not any("CANCEL_OBJECTS" in line for line in Bench().run("M115"))


def test_a_cancelled_objects_moves_stay_put_and_e_only_counts():
    bench = Bench(cancel_objects=True)
    bench.run("G90", "M82", "G92 E0", "M486 T2", "M486 P1")
    bench.run("M486 S0", "G1 X10 Y10 E1 F1200", "M486 S1", "G1 X50 Y50 Z0.4 E2")
    assert bench.fw.machine.position == [10.0, 10.0, 0.0, 2.0]
    assert bench.fw.objects.skipped_moves == 1
    bench.run("M486 S-1", "G1 X20 Y20 E3")
    assert bench.fw.machine.position == [20.0, 20.0, 0.0, 3.0]
    assert bench.run("M486") == ["echo:Canceled: 1"]


def test_m486_c_cancels_the_running_object_and_u_takes_it_back():
    bench = Bench(cancel_objects=True)
    bench.run("M486 S0", "M486 C")
    assert bench.run("M486") == ["echo:Active Object: 0", "echo:Canceled: 0"]
    bench.run("M486 U0", "G1 X5 Y5")
    assert bench.fw.machine.position[:2] == [5.0, 5.0]


def test_without_the_option_m486_is_an_unknown_command():
    assert Bench().run("M486 S0") == ['echo:Unknown command: "M486 S0"']
