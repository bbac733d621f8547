"""Streams whose printer does part of the work: SD card prints and uploads."""

from __future__ import annotations

from printers.protocol.marlin import MarlinProtocol
from printers.streaming import (
    CommandState,
    Line,
    PrinterSide,
    QueueState,
    Stream,
    StreamHost,
    StreamType,
    lines_from_text,
)
from tests.streaming.test_host import Wire, script


def make_host(**scripts: str) -> tuple[StreamHost, Wire]:
    host = StreamHost(
        MarlinProtocol(checksums="never", flow="ping_pong"), scripts=scripts
    )
    return host, Wire(host)


def sd_print(name: str = "PART.GCO") -> Stream:
    side = PrinterSide(
        runs_file=True, controls={"pause": "M25", "resume": "M24", "abort": "M524"}
    )
    return Stream(
        StreamType.SD_FILE_STREAM,
        lines_from_text(f"M23 {name}\nM24"),
        name=name,
        ref=7,
        printer_side=side,
    )


def sd_upload(count: int = 4, name: str = "PART.GCO") -> Stream:
    body = [Line(i + 1, f"G1 X{i}", (i + 1) * 10) for i in range(count)]
    lines = [Line(0, f"M28 {name}"), *body, Line(count + 1, "M29", count * 10)]
    side = PrinterSide(
        exclusive=True,
        hold_after=1,
        hold_reason="the printer did not open the file",
        controls={"abort": f"M29\nM30 {name}"},
        scripts=False,
        pausable=False,
        why_not="an upload cannot pause",
    )
    return Stream(StreamType.SD_FILE_STREAM, lines, name=name, ref=8, printer_side=side)


def test_sd_print_stays_printing_after_its_lines_until_the_printer_is_done():
    host, wire = make_host()
    stream = sd_print()
    host.submit(stream)

    wire.run(10)

    assert wire.sent == ["M23 PART.GCO", "M24"]
    assert stream.drained and stream.state is CommandState.WAIT_FOR_ACK
    assert host.queue_state is QueueState.PROCESSING

    host.printer_done(stream)
    wire.run(2)

    assert stream.outcome == "completed"
    assert host.queue_state is QueueState.IDLE


def test_sd_print_pause_resume_abort_send_the_printers_commands_around_scripts():
    host, wire = make_host(pause="G91", resume="G90", abort="M104 S0")
    stream = sd_print()
    host.submit(stream)
    wire.run(5)

    host.request_pause()
    wire.run(5)
    host.request_resume()
    wire.run(5)
    host.request_abort("stop")
    wire.run(5)

    assert wire.sent[2:] == ["M25", "G91", "G90", "M24", "M524", "M104 S0"]
    assert stream.outcome == "aborted"


def test_printer_paused_itself_gets_no_control_commands():
    host, wire = make_host(pause="G91")
    stream = sd_print()
    host.submit(stream)
    wire.run(5)

    host.request_pause(script=False)  # //action:paused: the printer already did
    wire.run(5)

    assert wire.sent == ["M23 PART.GCO", "M24"]
    assert host.queue_state is QueueState.PAUSED


def test_failed_sd_print_stops_the_printer_too():
    host, wire = make_host()
    stream = sd_print()
    host.submit(stream)
    wire.run(5)

    assert host.fail_stream("the firmware reported an error: boom")
    wire.run(5)

    assert wire.sent[-1] == "M524"
    assert stream.outcome == "failed"


def test_upload_holds_after_m28_until_the_printer_confirms():
    host, wire = make_host()
    stream = sd_upload()
    host.submit(stream)

    wire.turn(answer=False)  # M28 goes; its ok has not come yet
    wire.run(3)

    assert wire.sent == ["M28 PART.GCO"]
    assert stream.outcome == "failed"
    assert stream.message == "the printer did not open the file"


def test_released_upload_sends_every_line_then_m29():
    host, wire = make_host()
    stream = sd_upload()
    host.submit(stream)
    wire.turn(answer=False)
    host.release(stream)

    wire.run(20)

    assert wire.sent == ["M28 PART.GCO", *[f"G1 X{i}" for i in range(4)], "M29"]
    assert stream.outcome == "completed"
    assert stream.bytes_acked == 40


def test_nothing_else_goes_to_the_printer_while_an_upload_writes_the_file():
    host, wire = make_host()
    stream = sd_upload()
    host.submit(stream)
    wire.turn(answer=False)
    host.release(stream)
    wire.turn()

    host.submit(script("M105"))  # a temperature poll, a user's command...
    wire.run(20)

    assert wire.sent[-2:] == ["M29", "M105"]


def test_upload_refuses_pause_and_closes_then_deletes_the_file_on_abort():
    host, wire = make_host(abort="M104 S0")
    stream = sd_upload(count=50)
    host.submit(stream)
    wire.turn(answer=False)
    host.release(stream)
    wire.run(3)
    host.submit(script("M105"))

    assert host.request_pause() == "an upload cannot pause"
    host.request_abort("stopped")
    wire.run(10)

    assert stream.outcome == "aborted"
    assert wire.sent[-3:] == ["M29", "M30 PART.GCO", "M105"]  # no abort script
    assert "M104 S0" not in wire.sent


def test_upload_that_fails_after_opening_closes_the_file_first():
    host, wire = make_host()
    stream = sd_upload(count=50)
    host.submit(stream)
    wire.turn(answer=False)
    host.release(stream)
    wire.run(3)
    host.submit(script("M105"))

    assert host.fail_stream("the firmware reported an error: x")
    wire.run(10)

    assert wire.sent[-3:] == ["M29", "M30 PART.GCO", "M105"]
