"""The Marlin simulator's M190/M109 wait with motion timing on (found by the farm test).

The simulator's runner steps the firmware at exactly the deadline it asked for. A
heater stepped to its computed reach time can land a rounding error short of its
target's window (58.999999999999545 for a 60 °C bed and a 1 °C window); the gap
left, divided by the heating rate, was below the clock's resolution, so the wait
asked for the time it was at, for ever (the simulator spun at 100 % CPU and
answered nothing). A heater within `SLACK` of its window is in it.
"""

from __future__ import annotations

import pytest

from printers.simulator._heaters import Heater
from printers.simulator.marlin import MarlinFirmware


def test_a_heater_short_of_its_window_reaches_it_at_a_later_time():
    bed = Heater(20.0, 10.0, 1000.0)  # --time-scale 0.05: 1 °C/s times 20
    bed.set_target(60.0, 1000.0)
    bed.update(1001.0)  # a temperature report a second in
    bed.update(bed.reach_time())  # stepped to exactly the time it asked for
    assert bed.reached(heating_only=True) or bed.reach_time() > 1001.9


@pytest.mark.timeout(10)
def test_m190_ends_when_the_firmware_is_stepped_at_its_own_deadlines():
    firmware = MarlinFirmware(time_scale=0.05, now=1000.0)
    firmware.receive(b"M140 S60\nM190 S60\n", 1000.0)
    now, out = 1000.0, b""
    for _ in range(100):  # as printers.simulator.runner steps it
        deadline = firmware.next_deadline()
        now = max(now, deadline if deadline is not None else now + 1.0)
        firmware.step(now)
        out += firmware.data_to_send()
        if out.count(b"ok") >= 2:
            break
    assert out.count(b"ok") >= 2, "M190 never ended"


def test_instant_waits_end_heat_ups_and_homing_at_once_while_moves_keep_their_time():
    """`--instant-waits` (the farm bench): heat-ups and homing are the firmware's
    time, not the host's, and how long they take depends on where the last job left
    the printer (warm heaters, a head left high)."""
    firmware = MarlinFirmware(time_scale=1.0, now=1000.0, instant_waits=True)
    firmware.receive(b"M140 S60\nM190 S60\nM104 S215\nM109 S215\n", 1000.0)
    firmware.step(1000.0)
    assert firmware.data_to_send().count(b"ok") == 4  # no wait, not even a second
    firmware.receive(b"G92 X200 Z50\nG28\n", 1000.0)  # 16.5 s to home otherwise
    firmware.step(1000.0)
    assert firmware.data_to_send().count(b"ok") == 2

    firmware.receive(b"G1 X100 F600\nM400\n", 1000.0)  # 10 s at 10 mm/s
    firmware.step(1000.0)
    assert firmware.data_to_send().count(b"ok") <= 1  # M400 waits for the move
    deadline = firmware.next_deadline()
    assert deadline is not None and deadline > 1000.0
