"""The simulator process: ports, two paced Wires and one firmware model in one selectors loop.

Flow of bytes: host -> pty/TCP -> `to_firmware` Wire -> firmware -> `to_host`
Wire -> pty/TCP -> host. The loop never busy-waits: it sleeps until the next fd
event or the next deadline of a wire, the firmware, the record or a fault, then
plays every due event in time order (so a late wake-up changes nothing but
when bytes reach the host).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import selectors
import signal
import socket
import sys
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

from printers.simulator import _control
from printers.simulator._port_events import PortEvents
from printers.simulator._ports import ControlServer, PtyPort, SetupError, TcpPort
from printers.simulator._record import Recorder
from printers.simulator.link import Wire

if TYPE_CHECKING:
    from pathlib import Path

    from printers.simulator.faults import Faults

__all__ = ["Firmware", "Recorder", "RunnerConfig", "SetupError", "Simulator"]

#: Safety valve: events played per loop turn before the loop looks at its fds again.
MAX_EVENTS_PER_TURN = 10000
#: Events exactly at the horizon wait for the next turn (a new byte may tie them).
HORIZON_MARGIN = 1e-9


class Firmware(Protocol):
    """What the runner needs of MarlinFirmware and GrblFirmware."""

    WAKE_BYTES: bytes
    executed_count: int
    dropped_bytes: int

    def receive(self, data: bytes, now: float) -> None: ...
    def step(self, now: float) -> None: ...
    def data_to_send(self) -> bytes: ...
    def next_deadline(self) -> float | None: ...
    def reset(self, now: float) -> None: ...
    def halt(self, now: float) -> None: ...
    def stall(self, now: float, seconds: float) -> None: ...


@dataclass
class RunnerConfig:
    link: Path | None = None
    tcp: tuple[str, int] | None = None
    baud: int | None = 115200
    latency: float = 0.0
    record: Path | None = None
    control: Path | None = None


class Simulator(PortEvents):
    """One firmware behind a pty and/or TCP port, with faults, record and control socket."""

    def __init__(
        self,
        firmware: Firmware,
        config: RunnerConfig,
        faults: Faults,
        recorder: Recorder | None = None,
    ) -> None:
        self.firmware = firmware
        self.config = config
        self.faults = faults
        self.recorder = recorder
        self.to_firmware = Wire(config.baud, config.latency, wake=firmware.WAKE_BYTES)
        self.to_host = Wire(config.baud, config.latency, wake=b"\n")
        self.selector = selectors.SelectSelector()  # epoll rounds timeouts up to 1 ms
        self.pty: PtyPort | None = None
        self.tcp: TcpPort | None = None
        self.control: ControlServer | None = None
        self.closed = False
        self._reopen_at: float | None = None
        self._clock = time.monotonic()
        self._stopping = False
        self._listening = True
        self._last_read = self._clock
        self._masks: dict[object, int] = {}
        self._wakeup_r, self._wakeup_w = socket.socketpair()

    # -- life cycle ------------------------------------------------------------------

    def start(self) -> dict[str, object]:
        """Open the ports; returns the ready line's content. Raises SetupError."""
        try:
            if self.config.link is not None:
                self.pty = PtyPort(self.config.link)
                self.pty.open()
            if self.config.tcp is not None:
                self.tcp = TcpPort(*self.config.tcp)
                self.selector.register(
                    self.tcp.listener, selectors.EVENT_READ, self._on_accept
                )
            if self.config.control is not None:
                self.control = ControlServer(self.config.control)
                self.selector.register(
                    self.control.listener, selectors.EVENT_READ, self._on_control_accept
                )
        except SetupError:
            self.close()
            raise
        self._boot_output()
        self._install_signals()
        return {
            "ready": True,
            "pty": str(self.config.link) if self.pty else None,
            "tcp": self.tcp.address if self.tcp else None,
            "pid": os.getpid(),
        }

    def run(self) -> None:
        """Serve until SIGTERM/SIGINT (or `stop()`)."""
        while not self._stopping:
            now = time.monotonic()
            if not self._listening:
                self._read_ports(self._last_read)
            self._last_read = now
            self._simulate(now)
            self._deliver(now)
            if self.recorder is not None:
                self.recorder.flush(now)
            now = time.monotonic()
            self._listening = self.to_firmware.busy_until <= now
            self._update_interest()
            for key, mask in self.selector.select(self._timeout(now)):
                key.data(mask)

    def stop(self, *_: object) -> None:
        self._stopping = True

    def close(self) -> None:
        """Remove the link and the control socket, flush the record."""
        if self.pty is not None:
            self.pty.close()
        if self.tcp is not None:
            self.tcp.close()
        if self.control is not None:
            self.control.close()
        if self.recorder is not None:
            self.recorder.close()
        self.selector.close()
        self._wakeup_r.close()
        self._wakeup_w.close()

    def _boot_output(self) -> None:
        """What the firmware printed at power-up is already in the pty when we say ready.

        A host that opens the port with pyserial flushes its input and never sees
        it, like a board that booted long before; one that wants a banner resets
        the firmware (control `reset`). This keeps the boot from racing the open.
        """
        boot = self.firmware.data_to_send()
        if self.pty is not None and boot:
            self.pty.queue(boot)
            self.pty.flush()

    def _install_signals(self) -> None:
        self._wakeup_w.settimeout(0.0)
        signal.set_wakeup_fd(self._wakeup_w.fileno(), warn_on_full_buffer=False)
        for signum in (signal.SIGTERM, signal.SIGINT):
            signal.signal(signum, self.stop)
        self.selector.register(self._wakeup_r, selectors.EVENT_READ, self._on_wakeup)

    def _on_wakeup(self, mask: int) -> None:
        with contextlib.suppress(OSError):
            self._wakeup_r.recv(64)

    # -- the simulation --------------------------------------------------------------

    def _simulate(self, now: float) -> None:
        """Play every wire arrival and firmware deadline that is already settled.

        Bytes the host writes from *now* on cannot reach the firmware before the
        inbound wire's horizon, so everything before it can run now, even ahead
        of the clock: what the firmware prints still reaches the host only when
        the outbound wire says so. Events are played oldest first.
        """
        firmware = self.firmware
        horizon = self.to_firmware.horizon(now)
        limit = now if horizon <= now else horizon - HORIZON_MARGIN
        for _ in range(MAX_EVENTS_PER_TURN):
            arrival = self.to_firmware.next_arrival()
            deadline = firmware.next_deadline()
            due = math.inf if arrival is None else arrival
            if deadline is not None and deadline < due:
                due = deadline
            if due > limit:
                break
            due = max(due, self._clock)
            self._clock = due
            data = b""
            if arrival is not None and arrival <= due:
                data = self.to_firmware.take(due)
            if data:
                firmware.receive(data, due)  # it steps to *due* first
            else:
                firmware.step(due)
            self._emit(due)
            self._check_close(due)
        self._clock = max(self._clock, now)
        self._emit(self._clock)
        if self._reopen_at is not None and now >= self._reopen_at:
            self.reopen_ports(now)

    def _emit(self, now: float) -> None:
        out = self.firmware.data_to_send()
        if out and not self.closed:
            out = self.faults.garble(out, self.faults.config.noise_to_host)
            self.to_host.put(out, now)

    def _deliver(self, now: float) -> None:
        data = self.to_host.take(now)
        for _, port in self._open_ports():
            if data:
                port.queue(data)
            if port.pending:
                port.flush()

    def _timeout(self, now: float) -> float | None:
        times = [
            self.to_firmware.next_arrival(),
            self.firmware.next_deadline(),
            self.to_host.next_arrival(),
            self._reopen_at,
            self.recorder.deadline() if self.recorder else None,
            None if self._listening else self.to_firmware.busy_until,
        ]
        pending = [t for t in times if t is not None]
        return max(0.0, min(pending) - now) if pending else None

    def _check_close(self, now: float) -> None:
        """The close-after fault: what reached the host by *now* still gets there."""
        if self.closed or not self.faults.close_due(self.firmware.executed_count):
            return
        self._deliver(now)
        self.close_ports()
        reopen = self.faults.config.reopen_after
        if reopen is not None:
            self._reopen_at = now + reopen

    def handle_control(self, line: str) -> str:
        """Run one control command; returns `ok ...` or `error: ...`."""
        self._simulate(time.monotonic())
        now = self._clock  # the firmware may run ahead of the clock (see _simulate)
        try:
            reply = _control.run(self, line, now)
        except ValueError as error:
            return f"error: {error}"
        self._emit(now)
        return reply


def write_ready_line(info: dict[str, object]) -> None:
    """The one JSON line a parent process waits for."""
    sys.stdout.write(json.dumps(info) + "\n")
    sys.stdout.flush()
