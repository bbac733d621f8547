"""The machine's state at a line and the preamble built from it (sans-IO, no Django)."""

from __future__ import annotations

import pytest

from jobs.resume.preamble import ResumePoint, build_preamble
from jobs.resume.state import MachineState, StateReader, offsets_lost


def state_after(*commands: str, firmware: str = "marlin") -> MachineState:
    reader = StateReader(firmware)
    for command in commands:
        reader.feed(command)
    return reader.state


def commands(point: ResumePoint) -> list[str]:
    return [line.split(" ;")[0] for line in build_preamble(point) if line[0] != ";"]


def test_positions_follow_relative_moves_g92_and_inches():
    state = state_after(
        "G90", "G1 X10 Y10 Z1", "G91", "G1 X5 Z0.5", "G90", "G92 X0", "G1 X2",
        "G20", "G1 Y1",
    )  # fmt: skip
    assert state.position[:3] == pytest.approx([2.0, 25.4, 1.5])
    assert state.inches and state.absolute


def test_relative_e_adds_up_and_g92_e_resets_it():
    state = state_after("M83", "G1 X1 E0.5", "G1 X2 E0.25", "G92 E0", "G1 X3 E0.1")
    assert state.position[3] == pytest.approx(0.1)
    assert not state.absolute_e and state.absolute


def test_g90_and_g91_set_e_on_a_printer_but_not_on_a_cnc():
    assert not state_after("M82", "G91").absolute_e
    assert state_after("G91", firmware="grbl").absolute_e  # GRBL has no E


def test_heaters_fans_and_settings_keep_their_last_values_by_heater_and_index():
    state = state_after(
        "M104 S200", "M104 T1 S180", "M109 S215", "M140 S55", "M190 R60",
        "M106 S100", "M106 P1 S255", "M107", "M204 P500", "T1", "M204 P800 T1500",
    )  # fmt: skip
    assert state.tool == 1  # M204's T is an acceleration, not a tool
    assert state.heaters == {"tool0": 215.0, "tool1": 180.0, "bed": 60.0}
    assert state.fans == {"0": 0.0, "1": 255.0}
    assert list(state.settings.values()) == ["M204 P800 T1500"]


def test_settings_for_other_tools_or_other_words_are_all_replayed_in_order():
    state = state_after(
        "M221 T0 S90", "M221 T1 S110", "M204 P800", "M204 T1500", "M572 D0 S0.05",
        "M572 D1 S0.07", "M221 T0 S95", "M204 P900",
    )  # fmt: skip
    assert list(state.settings.values()) == [
        "M221 T1 S110", "M204 T1500", "M572 D0 S0.05", "M572 D1 S0.07",
        "M221 T0 S95", "M204 P900",
    ]  # fmt: skip


def test_reprapfirmware_tool_temperatures_are_heaters_not_retractions():
    state = state_after(
        "M140 S60", "G10 P0 S215 R170", "G10", "G10 P1 S190", "M568 P2 S230",
    )  # fmt: skip
    assert state.heaters == {"bed": 60.0, "tool0": 215.0, "tool1": 190.0,
                             "tool2": 230.0}  # fmt: skip
    assert state.retracted  # the bare G10, which a later G10 P S leaves as it is


def test_a_grbl_block_applies_every_code_in_it():
    state = state_after(
        "G21 G91 G56", "S9000 M4", "M7", "M8", "G1 X1 F200", "X1", "M9",
        firmware="grbl",
    )  # fmt: skip
    assert (state.coordinate_system, state.spindle, state.spindle_speed) == (
        2, "M4", 9000.0,
    )  # fmt: skip
    assert state.position[0] == 2.0 and state.coolant == [] and state.motion == "G1"


def _point(state: MachineState, **options: object) -> ResumePoint:
    return ResumePoint(line=10, state=state, stop_z=state.position[2], **options)


def test_the_preamble_homes_x_and_y_only_and_never_probes_the_bed():
    state = state_after("M140 S60", "M104 S210", "G28", "G29", "G1 Z0.4 X5 Y6 E3")
    sent = commands(_point(state, lift=5.0))
    assert sent.index("G92 Z0.4") < sent.index("G1 Z5.4 F600") < sent.index("G28 X Y")
    assert "G29" not in sent and "M420 S1" in sent
    assert sent.index("M190 S60") > sent.index("G28 X Y")  # heats parked, not on it
    assert sent[-4:] == ["T0", "G1 X5 Y6 F3000", "G1 Z0.4 F600", "G92 E3"]


def test_the_preamble_homes_every_axis_when_the_printer_says_so():
    state = state_after("G1 Z2 X1 Y1")
    sent = commands(_point(state, home_z=True))
    assert "G28" in sent and not any(c.startswith("G92 Z") for c in sent)


def test_the_file_modes_come_last_with_the_feedrate_in_its_units():
    state = state_after("G20", "G91", "M83", "G1 X1 F100")
    sent = commands(_point(state))
    assert sent[-3:] == ["G20", "G91", "G1 F100"]
    assert "G21" in sent  # the preamble's own moves are in millimetres


def test_a_cnc_preamble_climbs_above_the_work_and_spins_up_before_going_down():
    state = state_after(
        "G55", "M3 S12000", "M8", "G0 Z8", "G0 X1 Y1", "G1 Z-1 F300", "G1 X4 F900",
        firmware="grbl",
    )  # fmt: skip
    sent = commands(_point(state, lift=2.0))
    assert sent[:7] == ["G21", "G90", "G94", "G55", "G92.1", "G0 Z10", "G0 X4 Y1"]
    assert sent[7:10] == ["M3 S12000", "G4 P3", "M8"]
    assert sent[10:] == ["G1 Z-1 F900", "G1 F900"]


def test_a_cnc_resume_after_a_machine_coordinate_retract_does_not_plunge():
    """`G53 G0 Z-2` is 2 mm below the machine's top, not 2 mm into the work: read as
    a work Z, the preamble took the tool down to it, through the stock."""
    state = state_after(
        "G0 Z5", "G0 X1 Y1", "M3 S9000", "G1 Z-1 F300", "G1 X4 F900", "G53 G0 Z-2",
        firmware="grbl",
    )  # fmt: skip
    assert state.known[:3] == [True, True, False]
    sent = commands(_point(state, lift=2.0))
    assert "G0 Z7" in sent  # above the highest work Z (5), not the machine's -2
    assert not any(c.startswith("G1 Z") for c in sent)  # left to the file's next Z


def test_g28_and_g30_leave_the_axes_they_move_unplaced():
    assert state_after("G0 X1 Y2 Z3", "G28 G91 Z0", "G90", firmware="grbl").known[
        :3
    ] == [True, True, False]
    assert state_after("G0 X1 Y2 Z3", "G30", firmware="grbl").known[:3] == [False] * 3
    assert state_after("G0 X1 Y2 Z3", "G28.1", firmware="grbl").known[:3] == [True] * 3


def test_a_cnc_preamble_puts_the_files_g92_offset_back_over_the_point():
    state = state_after(
        "G0 X20 Y30 Z10", "G92 X0 Y0 Z0", "G1 Z-1 F200", "G1 X5 Y5 F800",
        firmware="grbl",
    )  # fmt: skip
    assert state.g92 == pytest.approx([20.0, 30.0, 10.0])
    sent = commands(_point(state, lift=2.0))
    # In the work coordinates alone (G92 cleared): up, over, then the offset again.
    at = sent.index("G92.1")
    assert sent[at + 1 : at + 4] == ["G0 Z12", "G0 X25 Y35", "G92 X5 Y5 Z2"]
    assert "G1 Z-1 F800" in sent
    assert state_after("G92 X1", "G92.1", firmware="grbl").g92 == [0.0, 0.0, 0.0]


def test_an_offset_that_cannot_be_set_again_is_told_apart():
    state = state_after("G0 Z5", "G53 G0 Z-1", "G92 Z0", firmware="grbl")
    assert state.g92[2] is None and state.g92[:2] == [0.0, 0.0]
    assert offsets_lost(state) == ["Z"]
    # An offset on X, with X unplaced at the line: the preamble cannot set it.
    state = state_after("G0 X5 Y5 Z5", "G92 X0", "G28 X0", firmware="grbl")
    assert offsets_lost(state) == ["X"]
    assert offsets_lost(state_after("G0 X5 Z5", "G92 X0", firmware="grbl")) == []


def test_work_offsets_the_file_sets_move_the_position_or_lose_it():
    assert state_after("G0 X5", "G10 L20 P0 X0", firmware="grbl").position[0] == 0
    assert not state_after("G0 X5", "G10 L2 P1 X3", firmware="grbl").known[0]
    assert state_after("G0 X5", "G10 L2 P2 X3", firmware="grbl").known[0]  # G55's
    assert state_after("G0 X5 Y5 Z5", "G55", firmware="grbl").known[:3] == [False] * 3
