# ruff: noqa: RUF001 (reasons print sizes with the multiplication sign)
"""What a farm job asks of a printer, read and checked without Django."""

from __future__ import annotations

import pytest

from jobs.farm.requirements import (
    BadRequirement,
    Part,
    PrinterFacts,
    Requirements,
    box_of,
    fits,
    matching,
    parse_requirements,
    why_none_match,
)

MK3 = box_of({"min": [0, -4, 0], "max": [250, 210, 210]})
PART = Part(box=box_of([[10, 10, 0.2], [110, 60, 30]]), longest=20)


def test_requirements_are_read_from_form_fields_with_their_aliases() -> None:
    asked = parse_requirements(
        {"material": " PETG ", "color": "Signal  red", "nozzle_diameter": "0.60",
         "tags": "enclosed, hardened,,Enclosed", "profile": "MK4"}
    )  # fmt: skip
    assert asked == Requirements(
        material="PETG",
        colour="Signal red",
        nozzle=0.6,
        profile="MK4",
        tags=("enclosed", "hardened"),
    )
    assert (
        asked.describe()
        == "Signal red PETG, 0.6 mm nozzle, profile MK4, tags enclosed, hardened"
    )
    assert parse_requirements({}).describe() == "any printer"


@pytest.mark.parametrize(
    ("values", "message"),
    [
        ({"nozzle": "wide"}, "nozzle must be a diameter in mm"),
        ({"nozzle": "9"}, "between 0.05 and 5 mm"),
        ({"nozzle": "nan"}, "between 0.05 and 5 mm"),
        ({"material": "P" * 33}, "material is at most 32 characters"),
        ({"colour": "red\x00"}, "printable characters only"),
        ({"tags": "x" * 41}, "a tag is 1 to 40"),
        ({"tags": 5}, "tags must be a list"),
        ({"tags": ",".join(f"t{i}" for i in range(21))}, "at most 20 tags"),
        ({"tags": [1, {"a": 1}, None]}, "tags must be words"),
        ({"nozzle": 10**400}, "nozzle must be a diameter in mm"),
    ],
)
def test_bad_requirements_say_what_is_wrong(values: dict, message: str) -> None:
    with pytest.raises(BadRequirement, match=message):
        parse_requirements(values)


def test_a_part_fits_a_volume_only_with_every_corner_inside() -> None:
    assert fits(PART.box, MK3)
    assert fits(box_of([[0, -4, 0], [250.005, 210, 210]]), MK3)  # within 0.01 mm
    assert not fits(box_of([[0, -4.5, 0], [250, 210, 210]]), MK3)
    assert not fits(box_of([[0, 0, 0], [100, 100, 211]]), MK3)
    assert box_of({}) is None and box_of([[1, 2], [3, 4]]) is None


def printers() -> list[PrinterFacts]:
    return [
        PrinterFacts("mk3-a", material="PLA", colour="black", nozzle=0.4, volume=MK3,
                     command_limit=82),
        PrinterFacts("mk3-b", material="PETG", colour="orange", nozzle=0.4,
                     tags=("enclosed",), volume=MK3, command_limit=82),
        PrinterFacts("voron", material="petg", colour="Red", nozzle=0.6,
                     profile="Voron 2.4", volume=None, command_limit=82),
    ]  # fmt: skip


@pytest.mark.parametrize(
    ("asks", "reason"),
    [
        ({"material": "ASA"}, "no printer has ASA loaded"),
        ({"material": "PETG", "colour": "blue"},
         "no printer with PETG loaded has it in blue"),
        ({"colour": "white"}, "no printer has white loaded"),
        ({"material": "PETG", "nozzle": "0.8"},
         "no printer with PETG loaded has a 0.8 mm nozzle"),
        ({"material": "PLA", "profile": "MK4"},
         "no printer with PLA loaded has the profile MK4"),
        ({"nozzle": "0.4", "tags": "enclosed,hardened"},
         "no printer with a 0.4 mm nozzle has the tags enclosed, hardened"),
        ({"profile": "voron 2.4"},
         "no printer with the profile voron 2.4 has its build volume set (the part "
         "is 100×50×29.8 mm); set it in the printer's settings"),
    ],
)  # fmt: skip
def test_the_reason_names_the_first_requirement_no_printer_meets(
    asks: dict, reason: str
) -> None:
    asked = parse_requirements(asks)
    assert matching(asked, PART, printers()) == []
    assert why_none_match(asked, PART, printers()) == reason


def test_a_part_too_big_for_every_printer_says_its_size() -> None:
    big = Part(box=box_of([[0, 0, 0], [250, 210, 180]]), longest=20)
    wide = Part(box=box_of([[0, 0, 0], [260, 210, 180]]), longest=20)
    assert why_none_match(Requirements(), big, printers()) == ""
    assert (
        why_none_match(Requirements(), wide, printers())
        == "the part (260×210×180 mm) fits no printer's build volume"
    )
    assert why_none_match(Requirements(), wide, []) == (
        "no printer takes farm jobs (turn on “farm” on a printer)"
    )


def test_a_command_longer_than_every_firmware_takes_matches_no_printer() -> None:
    long = Part(box=PART.box, longest=90)
    assert why_none_match(Requirements(material="PLA"), long, printers()) == (
        "its longest command (90 characters) is longer than the firmware of any "
        "printer with PLA loaded takes"
    )


def test_matching_ignores_case_and_needs_every_tag() -> None:
    asked = parse_requirements(
        {"material": "petg", "colour": "ORANGE", "tags": "Enclosed"}
    )
    assert [p.slug for p in matching(asked, PART, printers())] == ["mk3-b"]
    assert [p.slug for p in matching(Requirements(), PART, printers())] == [
        "mk3-a",
        "mk3-b",
    ]


def test_tags_are_refused_at_the_first_one_too_many() -> None:
    """The count is checked as tags come, so a flood of them is not read to its
    end (each tag read is compared with those before it): the 21st tag stops it,
    before the bad one further on is even looked at."""
    tags = [f"t{i}" for i in range(21)] + ["x" * 41] + [f"u{i}" for i in range(9)]
    with pytest.raises(BadRequirement, match="at most 20 tags"):
        parse_requirements({"tags": tags})
