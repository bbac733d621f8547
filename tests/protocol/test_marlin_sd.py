"""The SD card dialogue: Marlin's words about its card, as events."""

from __future__ import annotations

import pytest

from printers.protocol.marlin_sd import (
    SdCardState,
    SdDeleted,
    SdDeleteFailed,
    SdDialogue,
    SdDone,
    SdFile,
    SdFileOpened,
    SdListed,
    SdNotPrinting,
    SdOpenFailed,
    SdProgress,
    SdSaved,
    SdWriting,
    short_name,
)


def feed(dialogue: SdDialogue, *lines: str) -> list[object]:
    return [e for e in (dialogue.receive(line) for line in lines) if e is not None]


def test_a_file_list_is_gathered_into_one_event_with_sizes_and_long_names():
    dialogue = SdDialogue()
    events = feed(
        dialogue,
        "Begin file list",
        "CUBE.GCO 1024",
        "PARTHO~1.GCO 55123 part holder v2.gcode",
        "/SUBDIR/DEEP.GCO 7",
        "End file list",
    )
    assert events == [
        SdListed(
            (
                SdFile("CUBE.GCO", 1024),
                SdFile("PARTHO~1.GCO", 55123, "part holder v2.gcode"),
                SdFile("/SUBDIR/DEEP.GCO", 7),
            )
        )
    ]
    assert not dialogue.listing


def test_lines_inside_a_listing_are_not_read_as_other_events():
    dialogue = SdDialogue()
    assert feed(dialogue, "Begin file list", "Done printing file") == []
    assert dialogue.listing
    assert feed(dialogue, "End file list") == [SdListed(())]


@pytest.mark.parametrize(
    ("line", "event"),
    [
        ("SD printing byte 120/1234", SdProgress(120, 1234)),
        ("Not SD printing", SdNotPrinting()),
        ("Done printing file", SdDone()),
        ("File opened: CUBE.GCO Size: 1024", SdFileOpened("CUBE.GCO", 1024)),
        ("echo:open failed, File: NOPE.GCO.", SdOpenFailed("NOPE.GCO")),
        ("Writing to file: CUBE.GCO", SdWriting("CUBE.GCO")),
        ("Done saving file.", SdSaved()),
        ("File deleted:CUBE.GCO", SdDeleted("CUBE.GCO")),
        ("Deletion failed, File: CUBE.GCO.", SdDeleteFailed("CUBE.GCO")),
        ("echo:SD card ok", SdCardState(present=True, message="SD card ok")),
        ("echo:No SD card", SdCardState(present=False, message="No SD card")),
        ("echo:SD init fail", SdCardState(present=False, message="SD init fail")),
    ],
)
def test_each_sd_answer_becomes_its_event(line: str, event: object):
    assert SdDialogue().receive(line) == event


@pytest.mark.parametrize("line", ["ok", "T:210.0 /210.0", "echo:busy: processing"])
def test_lines_about_other_things_are_not_sd_events(line: str):
    assert SdDialogue().receive(line) is None


def test_progress_share_is_bounded():
    assert SdProgress(50, 200).share == 0.25
    assert SdProgress(0, 0).share == 0.0
    assert SdProgress(300, 200).share == 1.0


@pytest.mark.parametrize(
    ("name", "taken", "short"),
    [
        ("cube.gcode", set(), "CUBE.GCO"),
        ("part holder v2.gcode", set(), "PARTHO~1.GCO"),
        ("part holder v2.gcode", {"PARTHO~1.GCO"}, "PARTHO~2.GCO"),
        ("cube.gcode", {"CUBE.GCO"}, "CUBE~1.GCO"),
        ("Grüße.g", set(), "GRUSSE.G"),
        ("...", set(), "FILE"),
        ("noext", set(), "NOEXT"),
        ("cube (1).gcode", set(), "CUBE1.GCO"),  # a name the host can send
    ],
)
def test_short_names_fit_eight_dot_three_and_avoid_taken_names(name, taken, short):
    assert short_name(name, taken) == short


def test_m20s_ok_ends_a_file_list_whose_end_line_was_lost():
    dialogue = SdDialogue()
    events = feed(dialogue, "Begin file list", "CUBE.GCO 1024", "ok", "T:20 /0")
    assert events == [SdListed((SdFile("CUBE.GCO", 1024),))]
    assert not dialogue.listing


def test_file_names_that_look_like_replies_do_not_disturb_the_flow():
    from printers.protocol.events import Ack, FirmwareReset, Received
    from printers.protocol.marlin import MarlinProtocol

    proto = MarlinProtocol(checksums="never", flow="ping_pong")
    proto.send("M20 L", 0.0, tag="list")
    proto.data_to_send()
    names = ["REND.GCO 12", "SKIP.GCO 3", "RESEND.GCO 5", "START 1", "RS 1"]
    reply = "\n".join(["Begin file list", *names, "End file list", "ok", ""])
    proto.receive_data(reply.encode(), 0.1)

    events = []
    while (event := proto.next_event()) is not None:
        events.append(event)
    received = [e.text for e in events if isinstance(e, Received)]
    assert received == ["Begin file list", *names, "End file list", "ok"]
    assert [e for e in events if isinstance(e, Ack)] == [Ack("list")]
    assert not [e for e in events if isinstance(e, FirmwareReset)]
    assert proto.in_flight == 0


@pytest.mark.parametrize("echo", ["", "echo:"])
def test_replies_are_read_with_or_without_marlins_echo_prefix(echo):
    # Marlin 2.1 prints some of these through SERIAL_ECHO_MSG ("echo:..."), older
    # builds and Prusa's firmware print them bare.
    dialogue = SdDialogue()
    lines = {
        "File opened: A.GCO Size: 12": SdFileOpened("A.GCO", 12),
        "open failed, File: B.GCO.": SdOpenFailed("B.GCO"),
        "Done printing file": SdDone(),
        "Writing to file: C.GCO": SdWriting("C.GCO"),
        "Done saving file.": SdSaved(),
        "File deleted:C.GCO": SdDeleted("C.GCO"),
        "SD printing byte 6/12": SdProgress(6, 12),
        "Not SD printing": SdNotPrinting(),
        "No media": SdCardState(False, "No media"),
    }
    for line, event in lines.items():
        assert dialogue.receive(echo + line) == event, line


def test_oks_and_reports_are_never_about_the_card():
    dialogue = SdDialogue()
    for line in ("ok", "ok N12 P15 B3", " T:21.0 /0.0 B:20.9 /0.0", "wait", "busy:"):
        assert dialogue.receive(line) is None
