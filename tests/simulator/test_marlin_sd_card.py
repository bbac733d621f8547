"""The simulated SD card speaks Marlin's words, and the host's dialogue parser reads them."""

from __future__ import annotations

from printers.protocol.marlin_sd import (
    SdDialogue,
    SdDone,
    SdFile,
    SdFileOpened,
    SdListed,
    SdProgress,
)
from printers.simulator._marlin_sd import SdCard


def card() -> tuple[SdCard, list[str]]:
    said: list[str] = []
    return SdCard(said.append), said


def run(sd: SdCard, command: str, now: float = 0.0) -> None:
    code, _, args = command.partition(" ")
    sd.handlers()[code](args, now)


def test_a_file_written_with_m28_lists_opens_and_prints_to_its_end():
    sd, said = card()
    run(sd, "M28 CUBE.GCO")
    for line in ("G28", "G1 X10 ; first move", "", "G1 X20"):
        assert sd.capture(line)
    assert sd.capture("M29")
    assert not sd.capture("G1 X30"), "M29 closed the file"
    run(sd, "M20 L")
    run(sd, "M23 cube.gco")
    run(sd, "M24")
    commands = []
    while (command := sd.next_command()) is not None:
        commands.append(command)
    assert commands == ["G28", "G1 X10", "G1 X20"]

    dialogue = SdDialogue()
    events = [e for e in map(dialogue.receive, said) if e is not None]
    size = len(b"G28\nG1 X10 ; first move\n\nG1 X20\n")
    assert SdListed((SdFile("CUBE.GCO", size, "cube.gco"),)) in events
    assert SdFileOpened("CUBE.GCO", size) in events
    assert events[-1] == SdDone()


def test_progress_is_reported_on_m27_and_every_s_seconds():
    sd, said = card()
    sd.files["A.GCO"] = b"G1 X1\nG1 X2\n"
    run(sd, "M23 A.GCO")
    run(sd, "M24")
    sd.next_command()
    run(sd, "M27")
    assert said[-1] == "SD printing byte 6/12"
    run(sd, "M27 S2", now=10.0)
    sd.tick(11.0)
    assert said[-1] == "SD printing byte 6/12"
    sd.tick(12.0)
    assert SdDialogue().receive(said[-1]) == SdProgress(6, 12)
    assert len(said) == 5


def test_pause_stops_reading_and_abort_forgets_the_file():
    sd, said = card()
    sd.files["A.GCO"] = b"G1 X1\nG1 X2\n"
    run(sd, "M23 A.GCO")
    run(sd, "M24")
    assert sd.next_command() == "G1 X1"
    run(sd, "M25")
    assert sd.next_command() is None
    run(sd, "M24")
    assert sd.next_command() == "G1 X2"
    run(sd, "M524")
    run(sd, "M27")
    assert said[-1] == "Not SD printing"


def test_missing_files_are_refused_in_marlins_words():
    sd, said = card()
    run(sd, "M23 NOPE.GCO")
    run(sd, "M30 NOPE.GCO")
    assert said == [
        "echo:open failed, File: NOPE.GCO.",
        "Deletion failed, File: NOPE.GCO.",
    ]
