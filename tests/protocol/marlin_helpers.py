"""Helpers of MarlinProtocol's tests: a tiny in-test firmware and the events."""

from __future__ import annotations

from printers.protocol.checksum import parse_framed_line
from printers.protocol.events import Ack, Event, Received, Sent
from printers.protocol.marlin import MarlinProtocol

LINE_ERROR = "Error:Line Number is not Last Line Number+1, Last Line: {}"
CHECKSUM_ERROR = "Error:checksum mismatch, Last Line: {}"


class TinyMarlin:
    """Replies as Marlin would to each wire line, with no buffer limits and no flush.

    *damaged* holds line numbers whose first arrival is rejected as corrupt. Lines out
    of sequence get Marlin's Error/Resend/ok, the non-cooperation that makes hosts
    see a Resend per line in flight. With *repetier* they get `skip N` + ok instead.
    """

    def __init__(
        self,
        *,
        advanced: bool = False,
        damaged: tuple[int, ...] = (),
        repetier: bool = False,
    ) -> None:
        self.advanced, self.repetier = advanced, repetier
        self.damaged = set(damaged)
        self.last_n = 0
        self.executed: list[str] = []

    def __call__(self, data: bytes) -> bytes:
        replies = [r for line in data.decode().splitlines() for r in self.reply(line)]
        return "".join(f"{r}\n" for r in replies).encode()

    def reply(self, line: str) -> list[str]:
        number, command, good = parse_framed_line(line)
        if number is None:
            self.executed.append(command)
            return ["ok"]
        if command.startswith("M110"):
            self.last_n = number
            return [self.ok(number)]
        if number != self.last_n + 1:
            if self.repetier:
                return [f"skip {number}", "ok"]
            return self.resend(LINE_ERROR)
        if number in self.damaged or not good:
            self.damaged.discard(number)
            return self.resend(CHECKSUM_ERROR)
        self.last_n = number
        self.executed.append(command)
        return [self.ok(number)]

    def ok(self, number: int) -> str:
        return f"ok N{number} P15 B3" if self.advanced else "ok"

    def resend(self, error: str) -> list[str]:
        return [error.format(self.last_n), f"Resend: {self.last_n + 1}", "ok"]


def events(proto: MarlinProtocol) -> list[Event]:
    out = []
    while (event := proto.next_event()) is not None:
        out.append(event)
    return out


def meaning(proto: MarlinProtocol) -> list[Event]:
    """Events without the Sent/Received log."""
    return [e for e in events(proto) if not isinstance(e, Sent | Received)]


def exchange(proto: MarlinProtocol, firmware: TinyMarlin, now: float) -> bytes:
    """One round trip: what the protocol writes goes to the firmware and back."""
    data = proto.data_to_send()
    proto.receive_data(firmware(data), now)
    return data


def run(proto: MarlinProtocol, firmware: TinyMarlin, job: list[str]) -> list[Event]:
    """Stream *job* to the end, moving the clock 10 ms a turn; returns all events."""
    now, sent, log = 0.0, 0, []
    for _ in range(10_000):
        while sent < len(job) and proto.can_send(job[sent]):
            proto.send(job[sent], now, tag=sent)
            sent += 1
        exchange(proto, firmware, now)
        log += events(proto)
        if sent == len(job) and not proto.in_flight:
            return log
        now += 0.01
        deadline = proto.next_deadline()
        if deadline is not None and now >= deadline:
            proto.handle_timeout(now)
    raise AssertionError("job did not finish")


def acks(log: list[Event]) -> list[object]:
    return [e.tag for e in log if isinstance(e, Ack)]


def sent_lines(log: list[Event]) -> list[Sent]:
    return [e for e in log if isinstance(e, Sent)]


JOB = [f"G1 X{i} Y{i * 2} E{i / 10:.3f}" for i in range(1, 31)]


def streaming(
    *, lines: int, command: str = "G1 X{}", **options: object
) -> MarlinProtocol:
    """A protocol with lines N1..N<lines> written at t=0 and not yet answered."""
    proto = MarlinProtocol(checksums="always", flow="buffered", **options)  # type: ignore[arg-type]
    proto.reset_line_numbers(0.0)
    proto.data_to_send()
    proto.receive_data(b"ok\n", 0.0)
    for n in range(1, lines + 1):
        proto.send(command.format(n), 0.0, tag=n)
    proto.data_to_send()
    events(proto)
    return proto
