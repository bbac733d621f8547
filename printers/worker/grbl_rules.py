"""What a user may send GRBL while a job runs (the worker's requests ask)."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from printers.streaming import Line
    from printers.worker.loop import PrinterWorker

__all__ = ["refused_mid_job"]

#: What may be sent to GRBL while a job runs: commands that only look.
LOOKS = frozenset({"$$", "$#", "$G", "$I", "$N"})


def refused_mid_job(worker: PrinterWorker, lines: list[Line]) -> str:
    """Why these lines of a request may not go now ("" when they may).

    GRBL has one modal state and one set of offsets: a `G91`, `G20`, `G10 L20` or
    `$100=` typed mid-job applies to the job's lines after it (and a setting waits
    for GRBL to be idle, holding the job with the tool in the work). While a job
    runs (or is paused) only looking goes: `$$`, `$#`, `$G`, `$I`, `$N`, and
    printhost's own `[ESPxxx]`; overrides are realtime bytes and go at once anyway.
    """
    stream = worker.host.current_stream
    if not worker.printer.is_grbl or stream is None:
        return ""
    for line in lines:
        text = line.text.strip().upper()
        if text not in LOOKS and not text.startswith("[ESP"):
            return (
                f"{line.text[:30]!r} would change what GRBL does with job "
                f"{stream.ref}'s lines: wait for it to end, or abort it (while a "
                "job runs only $$, $#, $G, $I and $N go)"
            )
    return ""
