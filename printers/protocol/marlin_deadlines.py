"""MarlinProtocol's deadlines: ack timeouts, late-ok probes, overdue Resends (T1,
T1a, T2, T6, R8), a mixin of Recovery (marlin_recovery.py); the rules are in
marlin.py."""

from __future__ import annotations

from typing import TYPE_CHECKING

from printers.protocol.marlin_trust import RESET_GAP

if TYPE_CHECKING:
    from printers.protocol.marlin_recovery import Recovery

#: R8: how long after a line error its Resend (or, R1b, the Resend after its ok)
#: may take before the host acts without it, on top of two round trips.
ERROR_WAIT = 0.05


class Deadlines:
    """When the oldest live line, a probe or a line error's Resend is overdue, and
    what the recovery does then."""

    def next_deadline(self: Recovery) -> float | None:
        """The first of T1, T6 and R1b/R8 (None: none is due), asked every turn."""
        first = None if self._error_at is None else self.error_deadline()
        if self._window.live and not self.user_wait:
            for deadline in (self.deadline(), self.probe_deadline()):
                if deadline is not None and (first is None or deadline < first):
                    first = deadline
        return first

    def probe_deadline(self: Recovery) -> float | None:
        """T6: when the oldest live line's ok is late enough to send a probe."""
        if self.user_wait:
            return None
        return self.prober.deadline(
            since=self._last_progress, rtt=self.rtt, busy=self._busy_seen
        )

    def error_deadline(self: Recovery) -> float | None:
        """R1b, R8: when a line error's Resend is overdue."""
        if self._error_at is None:
            return None
        return self._error_at + ERROR_WAIT + 2 * self.rtt

    def error_timeout(self: Recovery, *, printing: bool) -> None:
        """R8: no Resend came: re-send from the oldest live line (R6 sorts it out).

        A held ok is dropped, not applied: it may be the error's own (its Resend
        lost); if it was a line's, the firmware's answer to the copy proves it.
        """
        self._held_ok = None
        self._error_at = None
        window = self._window
        live = window.live
        if live and live[0].number is not None and live[0].sent_at is not None:
            self.timeout(printing=printing, counted=False)
            return
        # Nothing live: an ok was taken for a line the error says is missing.
        last = self._error_last
        oldest = window.oldest_unacked()
        if (
            last is not None
            and window.history.first < last + 1 < oldest
            and oldest - (last + 1) <= RESET_GAP
            and not window.rewinding
        ):
            self._rewind(last + 1, f"line error without Resend: line {last + 1}")
            self._after_timeout = True

    def deadline(self: Recovery) -> float | None:
        """T1: when the oldest live line is overdue; None with nothing written."""
        live = self._window.live
        if not live or live[0].sent_at is None or self.user_wait:
            return None
        base = max(self._last_progress, live[0].sent_at)
        return base + (self._busy_timeout if self._busy_seen else self._ack_timeout)

    def timeout(self: Recovery, *, printing: bool, counted: bool = True) -> None:
        """T1 (T2 when not *counted*): re-send, assume the ok lost, or give up."""
        oldest = self._window.live[0]
        waited = self._window.clock - (oldest.sent_at or self._window.clock)
        if counted:
            self.timeouts += 1
            self._consecutive_timeouts += 1
            if self._consecutive_timeouts > self._max_timeouts:
                self._fail(
                    f"no answer to {oldest.wire!r} after {waited:.1f} s and "
                    f"{self._consecutive_timeouts} timeouts: is the printer alive?"
                )
                return
        self.progress()
        self._busy_seen = False
        if oldest.number is not None:
            if oldest.number != self._n:
                self._repeats = 0
            self._rewind(
                oldest.number,
                f"no answer to line {oldest.number} in {waited:.1f} s",
                timed_out=True,
            )
            self._after_timeout = True
        elif not printing:
            self._acknowledge(self._window.live.popleft())
        else:
            self._fail(
                f"no answer to {oldest.wire!r} after {waited:.1f} s; an unnumbered "
                "line cannot be retried safely while printing"
            )
