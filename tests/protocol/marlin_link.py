"""MarlinProtocol against the Marlin simulator over two paced wires, on a test clock.

Sans-IO on both sides, so a whole job with line noise runs in milliseconds and the
same seed gives the same run. Used by the protocol's noise and lost-ok tests.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from printers.protocol.events import (
    Ack,
    FirmwareError,
    FirmwareHalted,
    FirmwareReset,
    LinkFailed,
    Received,
    Sent,
)
from printers.protocol.marlin import MarlinProtocol
from printers.simulator.faults import FaultConfig, Faults
from printers.simulator.link import Wire
from printers.simulator.marlin import MarlinFirmware


@dataclass
class LinkRun:
    """What happened: commands the firmware ran, acks, failures, the host's log."""

    executed: list[str] = field(default_factory=list)
    acked: list[object] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)
    log: list[str] = field(default_factory=list)
    elapsed: float = 0.0
    proto: MarlinProtocol | None = None
    firmware: MarlinFirmware | None = None
    faults: Faults | None = None

    def job_commands(self) -> list[str]:
        """G and M commands the firmware ran (junk from split lines is no command)."""
        return [
            c
            for c in self.executed
            if c.startswith(("G", "M")) and not c.startswith(("M110", "M105"))
        ]


def run_link(
    job: list[str],
    *,
    faults: FaultConfig | None = None,
    firmware: dict[str, object] | None = None,
    protocol: dict[str, object] | None = None,
    baud: int = 115200,
    latency: float = 0.001,
    limit: float = 600.0,
    trace: bool = False,
) -> LinkRun:
    """Stream *job* to its end (or a failure, or *limit* seconds of test clock)."""
    run = LinkRun()
    run.faults = Faults(faults or FaultConfig(seed=1))
    options = {"advanced_ok": False, "emergency_parser": False, "time_scale": 0.0}
    options.update(firmware or {})
    fw = MarlinFirmware(faults=run.faults, on_execute=run.executed.append, **options)
    fw.data_to_send()  # the boot banner went out long ago
    proto = MarlinProtocol(baud=baud, **(protocol or {}))
    run.proto, run.firmware = proto, fw
    proto.printing = True
    to_fw, to_host = Wire(baud, latency, wake=b"\n"), Wire(baud, latency, wake=b"\n")
    config = run.faults.config
    now, sent = 0.0, 0
    while now < limit:
        while sent < len(job) and proto.can_send(job[sent]):
            proto.send(job[sent], now, tag=sent)
            sent += 1
        data = proto.data_to_send()
        if data:
            noise = config.noise_to_firmware
            to_fw.put(run.faults.garble(data, noise, one_per_line=True), now)
        while (event := proto.next_event()) is not None:
            if isinstance(event, Ack):
                run.acked.append(event.tag)
            elif isinstance(
                event, LinkFailed | FirmwareReset | FirmwareError | FirmwareHalted
            ):  # the worker stops the job on each of these
                run.failures.append(repr(event))
            elif trace and isinstance(event, Sent | Received):
                run.log.append(
                    f"{now:9.4f} {'>>' if isinstance(event, Sent) else '<<'} {event.text}"
                )
        if run.failures or (sent == len(job) and not proto.in_flight):
            break
        times = [
            to_fw.next_arrival(),
            to_host.next_arrival(),
            fw.next_deadline(),
            proto.next_deadline(),
        ]
        pending = [t for t in times if t is not None and t > now]
        now = min(pending) if pending else now + 0.01
        incoming = to_fw.take(now)
        if incoming:
            fw.receive(incoming, now)
        else:
            fw.step(now)
        out = fw.data_to_send()
        if out:
            to_host.put(run.faults.garble(out, config.noise_to_host), now)
        proto.receive_data(to_host.take(now), now)
        deadline = proto.next_deadline()
        if deadline is not None and now >= deadline:
            proto.handle_timeout(now)
    run.elapsed = now
    return run
