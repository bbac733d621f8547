"""The analyser against real slicer files and against hand-made files whose answers
are worked out on paper (no Django, no database)."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

from jobs.analysis.analyser import Analyser
from jobs.analysis.limits import GRBL_DEFAULTS, BadProfile, MotionLimits
from jobs.analysis.planner import trapezoid_seconds
from jobs.analysis.result import Analysis

DATA = Path(__file__).resolve().parent.parent / "data"
PRUSA = DATA / "prusaslicer-2.5_box-and-cylinder.gcode"
CURA = DATA / "cura-4.13_box.gcode"


def analyse(
    text: str | bytes, limits: MotionLimits | None = None, **options: object
) -> Analysis:
    data = text.encode() if isinstance(text, str) else text
    analyser = Analyser(limits, **options)  # type: ignore[arg-type]
    # Odd chunk sizes: lines straddle chunks as they do when a file streams in.
    for start in range(0, len(data), 7777):
        analyser.feed(data[start : start + 7777])
    return analyser.finish()


def analyse_file(path: Path, limits: MotionLimits | None = None) -> Analysis:
    return analyse(path.read_bytes(), limits)


def slicer_comment(path: Path, pattern: str) -> str:
    match = re.search(pattern, path.read_text(), re.M)
    assert match, pattern
    return match.group(1)


# -- real slicer files ---------------------------------------------------------


def test_prusaslicer_estimate_agrees_within_3_percent() -> None:
    """PrusaSlicer's 'normal mode' models Marlin's planner with classic jerk; with the
    same cornering rule and the limits the file sets (M201-M205), our motion time
    agrees with its printed estimate within 3 %."""
    own = slicer_comment(PRUSA, r"estimated printing time \(normal mode\) = (.+)$")
    assert own == "15m 3s"
    result = analyse_file(PRUSA, MotionLimits(classic_jerk=True))
    assert result.slicer["estimated_seconds"] == 903
    assert abs(result.motion_seconds - 903) / 903 < 0.03, result.motion_seconds


def test_prusaslicer_estimate_with_junction_deviation_is_close_too() -> None:
    """A Marlin 2 profile (junction deviation, the default) corners differently from
    PrusaSlicer's jerk model; the difference stays small on this file."""
    result = analyse_file(PRUSA)
    assert abs(result.motion_seconds - 903) / 903 < 0.03, result.motion_seconds


def test_prusaslicer_filament_layers_objects_and_notes() -> None:
    result = analyse_file(PRUSA)
    own_mm = float(slicer_comment(PRUSA, r"^; filament used \[mm\] = (\S+)"))
    assert abs(result.filament_total - own_mm) / own_mm < 0.005
    own_g = float(slicer_comment(PRUSA, r"^; filament used \[g\] = (\S+)"))
    assert abs(result.filament_weight_g - own_g) / own_g < 0.005
    assert len(result.layers) == PRUSA.read_text().count(";LAYER_CHANGE") == 50
    assert [layer.z for layer in result.layers[:3]] == [0.2, 0.4, 0.6]
    assert result.layers[-1].z == 10.0
    assert result.objects == ["box.stl", "cylinder.stl"]
    assert result.slicer["slicer"] == "PrusaSlicer"
    assert result.slicer["slicer_version"] == "2.5.0"
    assert result.slicer["layer_height"] == 0.2
    assert result.slicer["nozzle_diameter"] == 0.4
    assert result.slicer["material"] == "PLA"
    assert result.bbox is not None
    assert result.bbox[0][2] == 0.2
    assert result.bbox[1][2] == 10.0
    # The cylinder (16 mm across) and the box (20 mm) side by side, plus the skirt.
    width = result.bbox[1][0] - result.bbox[0][0]
    assert 30 < width < 45
    assert result.print_distance > 1000
    assert result.travel_distance > 100
    assert result.notes == []


def test_each_layer_starts_where_the_file_moves_to_its_height() -> None:
    data = PRUSA.read_bytes()
    result = analyse(data)
    lines = data.split(b"\n")
    commands = [raw for raw in lines if raw.split(b";")[0].strip()]
    for layer in result.layers[1:]:
        start = commands[layer.line].decode()
        assert f"Z{layer.z:g}".replace("0.", ".") in start or f"Z{layer.z:g}" in start
        assert data[layer.offset :].startswith(commands[layer.line])
    times = [layer.time for layer in result.layers]
    assert times == sorted(times)
    assert times[0] >= result.heating_seconds  # heating comes before the first layer


def test_cura_layers_and_filament_and_the_estimate_it_models_more_crudely() -> None:
    """Cura's own estimate uses its machine defaults (4000 mm/s², 20 mm/s jerk) and
    a simpler planner; with Marlin 2's defaults ours lands within 5 % of it. Its
    filament figure is the engine's extruded volume (1.75 mm filament)."""
    result = analyse_file(CURA)
    assert len(result.layers) == 50 == int(slicer_comment(CURA, r"^;LAYER_COUNT:(\d+)"))
    assert result.slicer["slicer"] == "Cura"
    own_seconds = float(slicer_comment(CURA, r"^;TIME:(\d+)"))
    assert result.slicer["estimated_seconds"] == own_seconds
    assert abs(result.motion_seconds - own_seconds) / own_seconds < 0.05
    own_mm = float(slicer_comment(CURA, r"^;Filament used: ([\d.]+)m")) * 1000
    assert abs(result.filament_total - own_mm) / own_mm < 0.005
    assert result.slicer["object_height"] == 10


def test_the_timeline_gives_time_and_filament_at_any_line() -> None:
    result = analyse_file(PRUSA)
    assert result.seconds_at(0) == 0
    assert result.seconds_at(result.commands) == pytest.approx(result.total_seconds)
    marks = [result.seconds_at(line) for line in range(0, result.commands, 97)]
    assert marks == sorted(marks)
    halfway = result.seconds_at(result.commands // 2)
    assert 0.3 * result.total_seconds < halfway < 0.7 * result.total_seconds
    assert result.filament_at(result.commands) == pytest.approx(result.filament_total)
    # A few KB per MB of G-code.
    size = len(str(result.timeline.seconds) + str(result.timeline.filament))
    assert size < 8 * PRUSA.stat().st_size / 1000
    assert result.layer_at(result.layers[3].line) == 3
    assert result.layer_at(0) == -1


def test_a_long_timeline_thins_itself_and_still_answers(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    full = analyse(PRUSA.read_bytes(), stride=16)
    monkeypatch.setattr("jobs.analysis.result.MAX_MARKS", 40)
    thin = analyse(PRUSA.read_bytes(), stride=16)
    assert len(full.timeline.seconds) > 500
    assert len(thin.timeline.seconds) <= 40 and thin.timeline.stride >= 256
    for line in range(0, full.commands, 997):
        assert thin.seconds_at(line) == pytest.approx(full.seconds_at(line), abs=15)
        assert thin.filament_at(line) == pytest.approx(full.filament_at(line), abs=25)


def test_an_analysis_goes_to_json_and_back() -> None:
    result = analyse_file(PRUSA)
    again = Analysis.from_dict(result.as_dict())
    assert again == result
    assert again.seconds_at(500) == result.seconds_at(500)


# -- the motion model on paper -------------------------------------------------


def test_a_lone_move_is_a_trapezoid() -> None:
    """100 mm at 100 mm/s with 1000 mm/s²: 0.1 s up, 0.9 s cruise, 0.1 s down."""
    limits = MotionLimits(print_acceleration=1000, travel_acceleration=1000)
    result = analyse("G1 X100 F6000\n", limits)
    assert result.motion_seconds == pytest.approx(1.1, abs=0.002)
    assert trapezoid_seconds(100, 1000, 0, 100**2, 0) == pytest.approx(1.1)


def test_a_short_move_never_reaches_its_speed() -> None:
    """2 mm with 1000 mm/s²: a triangle, twice sqrt(2 * 1 mm / 1000 mm/s²)."""
    limits = MotionLimits(travel_acceleration=1000)
    result = analyse("G1 X2 F6000\n", limits)
    assert result.motion_seconds == pytest.approx(2 * math.sqrt(2 / 1000), rel=0.01)


def test_straight_moves_in_a_row_keep_their_speed() -> None:
    """Ten 10 mm moves on one line take as long as one 100 mm move."""
    limits = MotionLimits(travel_acceleration=1000)
    steps = "".join(f"G1 X{10 * i}\n" for i in range(1, 11))
    many = analyse("G1 F6000\n" + steps, limits)
    one = analyse("G1 X100 F6000\n", limits)
    assert many.motion_seconds == pytest.approx(one.motion_seconds, rel=0.01)


def test_a_square_corner_slows_the_head_more_with_less_deviation() -> None:
    square = "G1 F6000\nG1 X50\nG1 Y50\nG1 X0\nG1 Y0\n"
    loose = analyse(square, MotionLimits(junction_deviation=0.1))
    tight = analyse(square, MotionLimits(junction_deviation=0.001))
    straight = analyse("G1 F6000\nG1 X200\n", MotionLimits())
    assert tight.motion_seconds > loose.motion_seconds > straight.motion_seconds


def test_the_file_changes_the_limits_as_the_firmware_would() -> None:
    slow = analyse("M204 P100 T100\nG1 X100 F6000\n")
    fast = analyse("M204 P10000 T10000\nG1 X100 F6000\n")
    assert slow.motion_seconds > fast.motion_seconds + 0.5
    capped = analyse("M203 X10\nG1 X100 F6000\n")  # 10 mm/s at most
    assert capped.motion_seconds == pytest.approx(10, rel=0.02)
    halved = analyse("M220 S50\nG1 X100 F600\n", MotionLimits(travel_acceleration=1e6))
    assert halved.motion_seconds == pytest.approx(20, rel=0.01)
    reprap = analyse(
        "M203 X600\nG1 X100 F6000\n", MotionLimits(), firmware="reprap"
    )  # RepRapFirmware's M203 is mm/min: 10 mm/s
    assert reprap.motion_seconds == pytest.approx(10, rel=0.02)


def test_dwell_and_heating_are_kept_apart_from_moves() -> None:
    limits = MotionLimits(hotend_heat_rate=2.0, bed_heat_rate=0.5, ambient=20)
    result = analyse("M190 S60\nM104 S200\nG4 S3\nG4 P500\nM109 S200\n", limits)
    assert result.dwell_seconds == pytest.approx(3.5)
    assert result.motion_seconds == pytest.approx(3.5)
    # Bed 40 °C at 0.5 °C/s = 80 s; the hotend heats 180 °C at 2 °C/s = 90 s, of
    # which 3.5 s passed in the dwells.
    assert result.heating_seconds == pytest.approx(80 + 90 - 3.5)


def test_relative_moves_inches_and_g92() -> None:
    limits = MotionLimits(travel_acceleration=1e7, max_acceleration=(1e7,) * 4)
    result = analyse("G20\nG91\nG1 X1 F600\nG1 X1\nG90\nG92 X0\nG1 X1\n", limits)
    # 3 inches at 600 inches per minute = 76.2 mm at 254 mm/s.
    assert result.motion_seconds == pytest.approx(3 * 25.4 / 254, rel=0.01)
    assert result.travel_distance == pytest.approx(76.2)


def test_extrusion_counts_net_filament_per_extruder_with_flow() -> None:
    text = "M83\nG1 X10 E5 F1200\nG1 E-1\nG1 E1\nT1\nG1 X20 E2\nM221 S50\nG1 X30 E4\n"
    result = analyse(text)
    assert result.filament_mm == [5.0, 4.0]
    assert len(result.layers) == 1


def test_arcs_are_timed_and_bounded_by_their_length() -> None:
    limits = MotionLimits(
        print_acceleration=1e7, travel_acceleration=1e7, max_acceleration=(1e7,) * 4
    )
    result = analyse("G1 X10 Y0 F600\nM83\nG2 X10 Y0 I-10 J0 E10\n", limits)
    # A full circle of radius 10 at 10 mm/s, plus the 1 s move to its start.
    assert result.motion_seconds == pytest.approx(1 + 2 * math.pi, rel=0.01)
    assert result.bbox == [[-10, -10, 0], [10, 10, 0]]


def test_grbl_files_are_read_as_cnc() -> None:
    text = (
        "G21 G90\nT2 M6\nM3 S12000\nG0 X10 Y10\nG1 Z-1 F100\nG1 X20 F300\n"
        "G3 X20 Y10 I0 J5\nM5\n"
    )
    result = analyse(text, GRBL_DEFAULTS, firmware="grbl")
    assert result.kind == "cnc"
    assert result.filament_mm == []
    assert result.tools == [2]
    assert result.spindle_max == 12000
    assert result.bbox is not None
    assert result.bbox[1][0] == pytest.approx(20 + 5, abs=0.01)  # the arc's far side
    assert result.travel_distance == pytest.approx(math.hypot(10, 10), abs=0.01)
    # Rapids run at $110 (500 mm/min), cuts at their F: never faster than the rate.
    assert result.motion_seconds > 14.14 / (500 / 60) + 1 / (100 / 60) + 10 / 5


def test_layer_markers_win_over_heights_in_vase_mode() -> None:
    """A spiral climbs on every move; the slicer's markers say where layers are."""
    lines = ["M83", ";LAYER_CHANGE", "G1 Z0.2 F600"]
    for layer in range(3):
        if layer:
            lines.append(";LAYER_CHANGE")
        lines += [
            f"G1 X{i % 2 * 10} Z{0.2 + layer * 0.2 + i * 0.05} E1" for i in range(4)
        ]
    result = analyse("\n".join(lines) + "\n")
    assert len(result.layers) == 3


def test_a_file_without_moves_says_so() -> None:
    result = analyse("M117 hello\nM105\n")
    assert result.notes == ["the file has no moves: nothing to time or draw"]
    assert result.motion_seconds == 0
    assert result.commands == 2


def test_comments_in_parentheses_and_lowercase_count_like_the_stream() -> None:
    text = b"(header)\ng1 x10 (move) f600\n; only a comment\n\n  \nG1 X0\r\n"
    result = analyse(text, MotionLimits(travel_acceleration=1e7))
    assert result.commands == 2
    assert result.motion_seconds == pytest.approx(2.0, rel=0.01)


@pytest.mark.parametrize(
    ("profile", "message"),
    [
        ({"jerk": [1, 2, 3]}, "four numbers"),
        ({"print_acceleration": -1}, "0 or more"),
        ({"print_acceleration": "fast"}, "a number"),
        ({"classic_jerk": 1}, "true or false"),
        ({"warp_speed": 9}, "not a motion setting"),
    ],
)
def test_a_bad_profile_is_refused_with_its_key(profile: dict, message: str) -> None:
    with pytest.raises(BadProfile, match=message):
        MotionLimits.from_profile(profile)


def test_a_profile_overrides_only_what_it_names() -> None:
    limits = MotionLimits.from_profile({"classic_jerk": True, "jerk": [8, 8, 0.4, 2]})
    assert limits.classic_jerk
    assert limits.jerk == (8, 8, 0.4, 2)
    assert limits.print_acceleration == MotionLimits().print_acceleration
    assert MotionLimits.from_profile(limits.as_profile()) == limits


def test_object_labels_in_each_firmwares_wording() -> None:
    text = (
        "EXCLUDE_OBJECT_DEFINE NAME=cube_id_0 CENTER=100,100\n"
        "EXCLUDE_OBJECT_DEFINE NAME='round one'\n"
        "M486 T2\nM486 S0\nM486 AShelf bracket\n"
        "; printing object gear.stl id:3 copy 0\nG1 X1\n"
    )
    assert analyse(text).objects == [
        "cube_id_0",
        "round one",
        "Shelf bracket",
        "gear.stl",
    ]


def test_a_line_too_long_to_hold_is_skipped_and_the_rest_is_read() -> None:
    """A comment of 6 MB without a line end (no upload check limits comments) is
    skipped in pieces instead of being held whole; the moves after it count."""
    analyser = Analyser(
        MotionLimits(travel_acceleration=1e7, max_acceleration=(1e7,) * 4)
    )
    analyser.feed(b"G1 X10 F600\n; ")
    for _ in range(6):
        analyser.feed(b"x" * (1 << 20))
        assert len(analyser._buffer) <= 5 << 20
    analyser.feed(b"\nG1 X20\n")
    result = analyser.finish()
    assert result.commands == 2
    assert result.motion_seconds == pytest.approx(2.0, rel=0.01)
    assert result.notes == ["a line over 4 MB was skipped"]
