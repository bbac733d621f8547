"""MarlinProtocol's probes for late oks (T5, T6): a numbered M105 asks where the firmware is."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from printers.protocol.marlin_window import LineWindow

__all__ = ["LONG_RUNNING", "PROBE", "PROBE_AFTER", "Prober"]

#: Commands that may hold their ok for long (moves, heat-ups, waits): no probe.
LONG_RUNNING = frozenset(
    {"M109", "M190", "M191", "M303", "G28", "G29", "M400", "G4", "M0", "M1", "M600"}
)
#: T6: a line whose ok is this late (plus four round trips) gets a probe.
PROBE_AFTER = 0.5
#: T6: the probe, a numbered no-op whose ok carries temperatures (T5).
PROBE = "M105"
#: T6: probes live at once (a probe's own ok may be lost too).
MAX_PROBES = 3


class Prober:
    """When to probe a late ok, and which live probe an `ok T:..` answers.

    A numbered probe is safe only with a firmware that checks the line sequence:
    if the late line never arrived, the probe brings a Resend for it; if its ok
    was lost, the probe's own ok proves the line ran (Marlin runs lines in order).
    """

    def __init__(self, window: LineWindow, after: float | None) -> None:
        self._window, self._after = window, after
        #: False for firmware that does not check the sequence (RepRapFirmware).
        self.probing = True
        #: True while the firmware writes every line into a file (M28): a probe
        #: would land in the file.
        self.writing_file = False
        #: Statistics: probes sent.
        self.probes = 0
        self._probed_at: float | None = None

    def deadline(self, *, since: float, rtt: float, busy: bool) -> float | None:
        """T6: when to probe; None while a long command or busy: may hold the ok."""
        window, after = self._window, self._after
        live = window.live
        if (
            after is None
            or not self.probing
            or self.writing_file
            or not live
            or busy
            or window.queued
        ):
            return None
        oldest = live[0]
        if (
            oldest.sent_at is None
            or oldest.number is None
            or oldest.word in LONG_RUNNING
            or (
                len(live) >= MAX_PROBES
                and sum(line.text.upper() == PROBE for line in live) >= MAX_PROBES
            )
        ):
            return None
        return max(since, oldest.sent_at, self._probed_at or 0.0) + after + 4 * rtt

    def send(self) -> None:
        """T6: a numbered M105 goes out (or, during a re-send, the next line)."""
        self._probed_at = self._window.clock
        self.probes += 1
        if self._window.rewinding:
            self._window.push_next()  # the next line to re-send asks the same
        else:
            self._window.add_probe(PROBE)

    def answered(self) -> int | None:
        """T5: index of the newest live probe behind numbered lines only, or None."""
        newest = None
        for index, line in enumerate(self._window.live):
            if not line.numbered or line.number is None:
                break
            if line.text.upper() == PROBE:
                newest = index  # an older probe's ok was lost too: newest wins
        return newest
