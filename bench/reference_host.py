"""The least a Python host does per line: the floor `make bench` holds the worker to.

It streams the same file to the same simulator over the same pty as the worker
does, and does only what no host can leave out: number and checksum each line,
keep Marlin's window (one line ping-pong; else four commands within the 127-byte
receive buffer) or GRBL's 127-byte character count, read the `ok`s, keep a log
entry for every line each way, and sleep until the wire is nearly empty before
reading (the worker's pacing, P2 in printers/protocol/pacing.py, with a fixed
margin). No
resends, timeouts, database, stream states or object filter: a line it loses is
lost. It lives in bench/ only, so the worker's CPU per 1,000 lines is judged beside
real code on the same machine in the same run, rather than against a number.
"""

from __future__ import annotations

import re
import time
from collections import deque
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from pathlib import Path

    from printers.transport import SerialTransport

#: How long before the wire runs dry the loop reads (s): the worker's smallest
#: margin but one, for a loop this short.
MARGIN = 0.0005
RX_BUFFER = 127
#: Marlin's command slots (BUFSIZE): lines in flight at most, windowed.
BUFSIZE = 4
#: `ok`, or ADVANCED_OK's `ok N<n> P<p> B<b>` (through line n); GRBL's `ok`.
_OK = re.compile(rb"ok(?: N(\d+))?[^\n]*\n")


def stream(link: Path, commands: list[str], *, firmware: str, mode: str, baud: int,
           max_seconds: float) -> dict[str, Any]:  # fmt: skip
    """Stream *commands* until done or *max_seconds*: lines acked, seconds, CPU
    seconds, wake-ups and bytes written."""
    from bench.case import cpu_split
    from printers.protocol.checksum import checksum
    from printers.transport import SerialTransport

    port = SerialTransport.open(str(link), baud)
    grbl = firmware == "grbl"
    byte_time = 10.0 / baud
    most = 1 if mode == "ping_pong" else len(commands) if grbl else BUFSIZE
    if not grbl:
        _ask(port, b"N0 M110 N0*125\n")
    live: deque[tuple[int, int]] = deque()  # (line number, bytes)
    log: list[tuple[float, bytes]] = []
    used = index = acked = wakes = written = 0
    number = 1
    busy_until = 0.0
    rest = b""
    started, cpu0, split0 = time.perf_counter(), time.process_time(), cpu_split()
    deadline = started + max_seconds
    try:
        while acked < len(commands) and time.perf_counter() < deadline:
            wakes += 1
            now = time.monotonic()
            if len(live) >= 2 and busy_until - MARGIN > now:
                time.sleep(busy_until - MARGIN - now)
            data = port.read(0.05)  # the worker's read: select, then os.read
            if data:
                data = rest + data
                end = data.rfind(b"\n") + 1
                rest = data[end:]
                for match in _OK.finditer(data, 0, end):
                    log.append((time.time(), match[0]))
                    # A plain ok answers the oldest line; ADVANCED_OK names its line.
                    oldest = live[0][0] if live else 0
                    through = int(match[1]) if match[1] else oldest
                    while live and live[0][0] <= through:
                        used -= live.popleft()[1]
                        acked += 1
            out = []
            while index < len(commands):
                if grbl:
                    wire = commands[index].replace(" ", "").encode() + b"\n"
                else:
                    body = f"N{number} {commands[index]}"
                    wire = f"{body}*{checksum(body)}\n".encode()
                if live and (used + len(wire) > RX_BUFFER or len(live) >= most):
                    break
                live.append((number, len(wire)))
                used += len(wire)
                out.append(wire)
                log.append((time.time(), wire))
                number += 1
                index += 1
            if out:
                data = b"".join(out)
                busy_until = max(time.monotonic(), busy_until) + len(data) * byte_time
                port.write(data)
                written += len(data)
    finally:
        port.close()
    user, system = (
        after - before for after, before in zip(cpu_split(), split0, strict=True)
    )
    return {
        "lines": acked,
        "seconds": time.perf_counter() - started,
        "cpu": time.process_time() - cpu0,
        "user": user,
        "system": system,
        "wakes": wakes,
        "bytes": written,
    }


def _ask(port: SerialTransport, line: bytes) -> None:
    """Write *line* and wait (a bounded while) for its ok."""
    port.write(line)
    reply, end = b"", time.monotonic() + 5
    while b"ok" not in reply and time.monotonic() < end:
        reply += port.read(0.5)
