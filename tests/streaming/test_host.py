"""The stream host (ESP3D's queues and command states) driving a real MarlinProtocol."""

from __future__ import annotations

import pytest

from printers.protocol.errors import LocalProtocolError
from printers.protocol.events import Sent
from printers.protocol.marlin import MarlinProtocol
from printers.streaming import (
    CommandState,
    Line,
    QueueState,
    Stream,
    StreamHost,
    StreamType,
    lines_from_text,
)
from printers.streaming import host_events as hv


def file_stream(count: int, name: str = "job") -> Stream:
    lines = [Line(i, f"G1 X{i}", (i + 1) * 10) for i in range(count)]
    return Stream(StreamType.SD_FILE_STREAM, lines, name=name, ref=1)


def script(text: str) -> Stream:
    return Stream(StreamType.MULTIPLE_COMMANDS, lines_from_text(text), name="script")


class Wire:
    """Runs the host against the protocol, answering `ok` to every line, and records."""

    def __init__(self, host: StreamHost) -> None:
        self.host = host
        self.protocol = host.protocol
        self.sent: list[str] = []
        self.events: list[object] = []

    def turn(self, *, answer: bool = True) -> None:
        self.host.advance(0.0)
        self.protocol.data_to_send()
        self._collect()
        if answer and self.protocol.in_flight:
            self.protocol.receive_data(b"ok\n" * self.protocol.in_flight, 0.0)
            self._collect()

    def _collect(self) -> None:
        while (event := self.protocol.next_event()) is not None:
            if isinstance(event, Sent):
                self.sent.append(event.text)
            elif hasattr(event, "tag"):
                self.host.handle_ack(event.tag)
        while (event := self.host.next_event()) is not None:
            self.events.append(event)

    def run(self, turns: int = 200) -> None:
        for _ in range(turns):
            self.turn()


def make_host(**scripts: str) -> tuple[StreamHost, Wire]:
    host = StreamHost(
        MarlinProtocol(checksums="never", flow="ping_pong"), scripts=scripts
    )
    return host, Wire(host)


def test_file_stream_sends_every_line_then_ends_completed():
    host, wire = make_host()
    stream = file_stream(5)
    host.submit(stream)

    wire.run(20)

    assert wire.sent == [f"G1 X{i}" for i in range(5)]
    assert stream.outcome == "completed"
    assert stream.acked == 5
    assert stream.bytes_acked == 50
    assert host.queue_state is QueueState.IDLE
    assert isinstance(wire.events[0], hv.StreamStarted)
    assert isinstance(wire.events[-1], hv.StreamEnded)


def test_script_queue_runs_before_the_stream_queue():
    host, wire = make_host()
    host.submit(file_stream(3))
    host.submit(script("M105\nM114"))

    wire.run(20)

    assert wire.sent[:2] == ["M105", "M114"]
    assert wire.sent[2:] == ["G1 X0", "G1 X1", "G1 X2"]


def test_stream_is_held_while_a_script_arrives_mid_stream():
    host, wire = make_host()
    host.submit(file_stream(6))
    wire.turn()
    wire.turn()
    host.submit(script("M117 hello"))

    wire.run(20)

    assert wire.sent[:2] == ["G1 X0", "G1 X1"]
    assert wire.sent[2] == "M117 hello"
    assert wire.sent[3:] == ["G1 X2", "G1 X3", "G1 X4", "G1 X5"]


def test_pause_runs_pause_script_and_resume_continues_after_resume_script():
    host, wire = make_host(pause="G91\nG1 Z5\nG90", resume="G91\nG1 Z-5\nG90")
    stream = file_stream(6)
    host.submit(stream)
    wire.turn()
    wire.turn()

    assert host.request_pause() == ""
    wire.run(10)

    assert host.queue_state is QueueState.PAUSED
    assert stream.state is CommandState.PAUSED
    assert wire.sent[2:] == ["G91", "G1 Z5", "G90"]
    assert host.request_resume() == ""
    wire.run(20)
    assert wire.sent[5:8] == ["G91", "G1 Z-5", "G90"]
    assert wire.sent[8:] == ["G1 X2", "G1 X3", "G1 X4", "G1 X5"]
    assert stream.outcome == "completed"


def test_a_pause_and_resume_the_printer_did_itself_run_no_scripts():
    host, wire = make_host(pause="G1 Z5", resume="G1 Z-5")
    stream = file_stream(6)
    host.submit(stream)
    wire.turn()
    wire.turn()

    assert host.request_pause(script=False) == ""
    wire.run(10)
    assert stream.state is CommandState.PAUSED
    assert host.request_resume(script=False) == ""
    wire.run(20)
    assert "G1 Z5" not in wire.sent and "G1 Z-5" not in wire.sent
    assert stream.outcome == "completed"


def test_a_resume_before_the_pause_was_applied_keeps_the_stream_going():
    host, wire = make_host(pause="G1 Z5")
    stream = file_stream(6)
    host.submit(stream)
    wire.turn()

    assert host.request_pause(script=False) == ""
    assert host.request_resume(script=False) == ""  # //action:paused, resumed at once
    wire.run(20)
    assert stream.outcome == "completed"
    assert "G1 Z5" not in wire.sent


def test_abort_runs_abort_script_and_sends_no_more_stream_lines():
    host, wire = make_host(abort="M104 S0\nM84")
    stream = file_stream(100)
    host.submit(stream)
    wire.turn()

    assert host.request_abort("stopped by test") == ""
    wire.run(10)

    assert stream.outcome == "aborted"
    assert stream.message == "stopped by test"
    assert wire.sent == ["G1 X0", "M104 S0", "M84"]


def test_pause_with_nothing_running_is_refused_with_a_reason():
    host, _ = make_host()
    assert host.request_pause() == "no stream is running"
    assert host.request_resume() == "no stream is paused"


def test_esp_line_in_a_stream_becomes_an_event_not_a_gcode_line():
    host, wire = make_host()
    lines = [Line(0, "G28"), Line(1, "[ESP701]action=PAUSE"), Line(2, "G1 X1")]
    host.submit(Stream(StreamType.SD_FILE_STREAM, lines, ref=1))

    wire.run(10)

    assert "[ESP701]action=PAUSE" not in wire.sent
    esp = [e for e in wire.events if isinstance(e, hv.EspCommand)]
    assert [e.text for e in esp] == ["[ESP701]action=PAUSE"]


def test_a_rejected_line_fails_the_stream_with_its_line_number():
    host, wire = make_host()
    lines = [Line(0, "G28"), Line(1, "G1 X" + "9" * 200)]
    stream = Stream(StreamType.SD_FILE_STREAM, lines, ref=1)
    host.submit(stream)

    wire.run(10)

    assert stream.outcome == "failed"
    assert stream.message.startswith("line 2:")
    assert wire.sent == ["G28"]


def test_fail_all_ends_every_stream_with_the_reason():
    host, wire = make_host()
    job = file_stream(50)
    host.submit(job)
    host.submit(script("M105"))
    wire.turn(answer=False)

    host.fail_all("firmware reset", outcome="interrupted")
    wire.turn(answer=False)

    assert job.outcome == "interrupted"
    assert job.message == "firmware reset"
    assert host.active_stream is None


def test_invalid_stream_type_is_refused():
    host, _ = make_host()
    with pytest.raises(ValueError, match="cannot be streamed"):
        host.submit(Stream(StreamType.INVALID, []))


def test_state_table_refuses_a_move_it_does_not_list():
    stream = file_stream(1)
    with pytest.raises(LocalProtocolError, match="can't go from start to paused"):
        stream.move(CommandState.PAUSED)


def test_window_lets_several_lines_fly_before_the_first_ack():
    protocol = MarlinProtocol(
        checksums="never", flow="buffered", bufsize=4, rx_buffer=127
    )
    host = StreamHost(protocol)
    stream = file_stream(10)
    host.submit(stream)

    host.advance(0.0)

    assert protocol.in_flight == 4
    assert stream.state is CommandState.WAIT_FOR_ACK
