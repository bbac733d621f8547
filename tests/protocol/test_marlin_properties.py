"""Property tests: MarlinProtocol against a Marlin-like peer over a lossy, slow link."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from itertools import cycle

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from printers.protocol.checksum import parse_framed_line
from printers.protocol.events import Ack, LinkFailed
from printers.protocol.marlin import MarlinProtocol

RX_SIZE = 128
BUFSIZE = 4
PRINTABLE = [c for c in range(33, 127) if c != ord("*")]


class SimMarlin:
    """Just enough Marlin: a 128-byte RX ring, strict N/checksum, BUFSIZE queue.

    A bad line makes it print Marlin's three lines (Error, Resend, ok) and flush the
    RX ring; every command is "executed" after exec_time and then answered with ok
    (or ADVANCED_OK's `ok N<n> P<p> B<b>`, B counting the command itself).
    """

    def __init__(
        self,
        *,
        advanced: bool,
        exec_time: float,
        last_n: int,
        lost_oks: frozenset[int] = frozenset(),
        ok_after_resend: bool = True,
    ) -> None:
        self.advanced = advanced
        self.exec_time = exec_time
        self.last_n = last_n
        self.lost_oks = lost_oks  # the k-th oks of executed commands that get lost
        self.ok_after_resend = ok_after_resend  # False: Marlin 2.0.x builds
        self.finished = 0
        self.rx = bytearray()
        self.overflows = 0
        self.queue: deque[tuple[int | None, str]] = deque()
        self.started = 0.0
        self.executed: list[str] = []

    def deliver(self, writes: list[bytes], now: float) -> list[str]:
        """Take each write in turn, reading lines between them while there is room."""
        replies: list[str] = []
        for data in writes:
            for byte in data:
                if len(self.rx) >= RX_SIZE:
                    self.overflows += 1  # the UART drops it, as the AVR ring does
                else:
                    self.rx.append(byte)
            replies += self.run(now)
        return replies

    def run(self, now: float) -> list[str]:
        replies: list[str] = []
        while True:
            if self.queue and now >= self.started + self.exec_time:
                ok = self._finish()
                if self.finished not in self.lost_oks:
                    replies.append(ok)
                self.started = now
            elif len(self.queue) < BUFSIZE and b"\n" in self.rx:
                raw, _, rest = self.rx.partition(b"\n")
                self.rx = bytearray(rest)
                if not self.queue:
                    self.started = now
                self._read(raw.decode("ascii", "replace"), replies)
            else:
                return replies

    def next_time(self) -> float | None:
        return self.started + self.exec_time if self.queue else None

    def _finish(self) -> str:
        self.finished += 1
        free = BUFSIZE - len(self.queue)
        number, command = self.queue.popleft()
        if not command.startswith("M110"):
            self.executed.append(command)
        if not self.advanced:
            return "ok"
        echo = f" N{number}" if number is not None else ""
        return f"ok{echo} P15 B{free}"

    def _read(self, line: str, replies: list[str]) -> None:
        line = line.strip()
        if not line:
            return
        if not line.startswith("N"):
            self.queue.append((None, line))
            return
        number, command, good = parse_framed_line(line)
        if "M110" in line:  # Marlin takes the number from M110's own N, unchecked
            second = line.find("N", 4)
            number = strtol(line[second + 1 :]) if second > 0 else number
        elif number != self.last_n + 1:
            self._error("Line Number is not Last Line Number+1", replies)
            return
        if "*" not in line:
            self._error("No Checksum with line number", replies)
            return
        if not good:
            self._error("checksum mismatch", replies)
            return
        self.last_n = number
        self.queue.append((number, command))

    def _error(self, message: str, replies: list[str]) -> None:
        replies.append(f"Error:{message}, Last Line: {self.last_n}")
        replies.append(f"Resend: {self.last_n + 1}")
        if self.ok_after_resend:
            replies.append("ok")
        self.rx.clear()


def strtol(text: str) -> int:
    """C's strtol(text, NULL, 10) for our purposes: leading digits, else 0."""
    digits = ""
    for char in text:
        if not char.isdigit():
            break
        digits += char
    return int(digits or 0)


@dataclass
class Link:
    """A FIFO wire delivering each write after a delay taken in turn from *delays*."""

    delays: list[float]
    items: deque[tuple[float, bytes]] = field(default_factory=deque)
    last: float = 0.0

    def __post_init__(self) -> None:
        self._delays = cycle(self.delays)

    def put(self, now: float, data: bytes) -> None:
        self.last = max(self.last, now + next(self._delays))
        self.items.append((self.last, data))

    def take(self, now: float) -> list[bytes]:
        out = []
        while self.items and self.items[0][0] <= now:
            out.append(self.items.popleft()[1])
        return out

    def next_time(self) -> float | None:
        return self.items[0][0] if self.items else None


@dataclass
class Faults:
    """What goes wrong on the way to the firmware, by index of the line written."""

    corrupt: dict[int, tuple[int, int]] = field(default_factory=dict)
    drop: frozenset[int] = frozenset()
    written: int = 0

    def apply(self, data: bytes) -> bytes:
        out = []
        for line in data.split(b"\n")[:-1]:
            index = self.written
            self.written += 1
            if index in self.drop:
                continue
            if index in self.corrupt:
                line = corrupt(line, *self.corrupt[index])
            out.append(line + b"\n")
        return b"".join(out)


def corrupt(line: bytes, where: int, value: int) -> bytes:
    """Change one byte after the leading N into another printable byte (not `*`).

    The leading N and the newline are spared: without its N Marlin would run the
    rest as an unnumbered command, which no host can prevent.
    """
    position = 1 + where % (len(line) - 1)
    choices = [c for c in PRINTABLE if c != line[position]]
    damaged = bytearray(line)
    damaged[position] = choices[value % len(choices)]
    return bytes(damaged)


@dataclass
class Wire:
    """Both directions of the link and the faults on the way out."""

    out: Link
    back: Link
    faults: Faults = field(default_factory=Faults)


@dataclass
class Outcome:
    acks: list[object] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)
    max_bytes: int = 0


def run_job(
    job: list[str],
    proto: MarlinProtocol,
    peer: SimMarlin,
    wire: Wire,
    *,
    offer: bool = False,
) -> Outcome:
    """Stream *job* through *wire* to *peer*, jumping the clock from event to event.

    *offer*: each line goes as the stream host sends it, `offer` (asked again until
    it is taken), which must take it exactly when `can_send` says it may go.
    """
    outcome = Outcome()
    now, next_line = 0.0, 0
    for _ in range(50_000):
        proto.receive_data(b"".join(wire.back.take(now)), now)
        while (event := proto.next_event()) is not None:
            if isinstance(event, Ack):
                outcome.acks.append(event.tag)
            elif isinstance(event, LinkFailed):
                outcome.failures.append(event.message)
        if outcome.failures:
            return outcome
        while next_line < len(job):
            fits = proto.can_send(job[next_line])
            if offer:
                assert proto.offer(job[next_line], now, tag=next_line) == fits
            elif fits:
                proto.send(job[next_line], now, tag=next_line)
            if not fits:
                break
            next_line += 1
            outcome.max_bytes = max(outcome.max_bytes, proto.bytes_in_flight)
        if data := proto.data_to_send():
            wire.out.put(now, wire.faults.apply(data))
        deadline = proto.next_deadline()
        if deadline is not None and now >= deadline:
            proto.handle_timeout(now)
            continue
        if replies := peer.deliver(wire.out.take(now), now) + peer.run(now):
            wire.back.put(now, "".join(f"{r}\n" for r in replies).encode())
        idle = not (peer.queue or peer.rx or wire.out.items or wire.back.items)
        if len(outcome.acks) == len(job) and not proto.in_flight and idle:
            return outcome
        times = [wire.out.next_time(), wire.back.next_time(), peer.next_time()]
        later = [t for t in [*times, deadline] if t is not None and t > now]
        if not later:
            return outcome
        now = min(later)
    raise AssertionError("the simulation did not settle")


moves = st.lists(
    st.builds(
        "G1 X{}.{} Y{} E{:.4f}".format,
        st.integers(0, 250),
        st.integers(0, 999),
        st.integers(0, 250),
        st.floats(0, 5),
    ),
    min_size=1,
    max_size=40,
)
delays = st.lists(st.floats(0.0, 0.1), min_size=1, max_size=5)
indices = st.frozensets(st.integers(0, 60), max_size=3)
damage = st.dictionaries(
    st.integers(0, 60),
    st.tuples(st.integers(0, 10_000), st.integers(0, 10_000)),
    max_size=6,
)
PROPERTY = settings(
    max_examples=200,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.too_slow],
)


@st.composite
def setups(draw: st.DrawFn) -> tuple[MarlinProtocol, SimMarlin, Wire]:
    flow = draw(st.sampled_from(["ping_pong", "buffered", "auto"]))
    proto = MarlinProtocol(checksums="always", flow=flow, ack_timeout=0.5)
    peer = SimMarlin(
        advanced=draw(st.booleans()),
        exec_time=draw(st.floats(0.0005, 0.02)),
        last_n=draw(st.integers(0, 500)),  # left over from an earlier session
        lost_oks=draw(indices),
        ok_after_resend=draw(st.booleans()),
    )
    wire = Wire(
        Link(draw(delays)), Link(draw(delays)), Faults(draw(damage), draw(indices))
    )
    return proto, peer, wire


@PROPERTY
@given(job=moves, setup=setups())
def test_every_line_runs_once_in_order_over_a_bad_link(
    job: list[str], setup: tuple[MarlinProtocol, SimMarlin, Wire]
) -> None:
    proto, peer, wire = setup
    outcome = run_job(job, proto, peer, wire)
    assert outcome.failures == []
    assert peer.executed == job  # none lost, none repeated, in order
    assert outcome.acks == list(range(len(job)))  # every tag once, in order
    assert outcome.max_bytes <= 127  # the protocol's own accounting
    assert peer.overflows == 0  # and the firmware's ring agrees


#: Lines of any length a window takes, to meet the byte budget's edge.
messages = st.lists(
    st.text("abcxyz0123456789", min_size=1, max_size=70).map("M117 {}".format),
    min_size=1,
    max_size=40,
)


@PROPERTY
@given(job=st.one_of(moves, messages), setup=setups())
def test_offer_takes_a_line_exactly_when_can_send_says_it_may_go(
    job: list[str], setup: tuple[MarlinProtocol, SimMarlin, Wire]
) -> None:
    proto, peer, wire = setup
    outcome = run_job(job, proto, peer, wire, offer=True)
    assert outcome.failures == []
    assert peer.executed == job
    assert outcome.acks == list(range(len(job)))
    assert outcome.max_bytes <= 127
    assert peer.overflows == 0


@PROPERTY
@given(
    job=moves,
    exec_time=st.floats(0.0005, 0.02),
    out=delays,
    back=delays,
)
def test_a_clean_link_needs_no_resend(
    job: list[str], exec_time: float, out: list[float], back: list[float]
) -> None:
    proto = MarlinProtocol(checksums="always", ack_timeout=0.5)
    peer = SimMarlin(advanced=True, exec_time=exec_time, last_n=0)
    outcome = run_job(job, proto, peer, Wire(Link(out), Link(back)))
    assert peer.executed == job
    assert outcome.acks == list(range(len(job)))
    assert proto.lines_sent == len(job) + 1  # the job's lines and one M110
    assert (proto.resends, proto.timeouts) == (0, 0)
