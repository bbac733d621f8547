"""MarlinProtocol's acknowledgements and resend requests (R1-R7, T3-T5); its deadlines
(T1, T2, T6, R8) are marlin_deadlines.py."""

from __future__ import annotations

from typing import TYPE_CHECKING

from printers.protocol.events import Ack, ResendServed
from printers.protocol.marlin_deadlines import Deadlines
from printers.protocol.marlin_probe import LONG_RUNNING, PROBE_AFTER, Prober
from printers.protocol.marlin_responses import ReplyKind
from printers.protocol.marlin_trust import agrees, far_back, is_noise

if TYPE_CHECKING:
    from collections import deque
    from collections.abc import Callable

    from printers.protocol.events import Event
    from printers.protocol.marlin_responses import Reply
    from printers.protocol.marlin_window import Line, LineWindow

__all__ = ["Recovery"]

_RESEND_ERRORS = (ReplyKind.LINE_NUMBER_ERROR, ReplyKind.CHECKSUM_ERROR)
_RTT_START = 0.05
_RTT_CAP = 1.0
#: T1a: busy: messages of a firmware waiting for a person (M600, M0, host prompts).
USER_WAIT = ("paused for user", "paused for input")


class Recovery(Deadlines):
    """Which live lines an ok, a Resend, a skip or a timeout settles (see marlin.py).

    Acts on the protocol's LineWindow and event queue; a broken link goes to *fail*,
    which must abandon everything (this recovery included, through reset()).
    """

    def __init__(
        self,
        window: LineWindow,
        events: deque[Event],
        fail: Callable[[str], None],
        reset: Callable[[str], None],
        *,
        max_resends: int,
        max_timeouts: int,
        ack_timeout: float,
        busy_timeout: float,
        probe_after: float | None = PROBE_AFTER,
    ) -> None:
        self._window, self._events, self._fail = window, events, fail
        self._reset_seen = reset
        self._max_resends, self._max_timeouts = max_resends, max_timeouts
        self._ack_timeout, self._busy_timeout = ack_timeout, busy_timeout
        #: T5, T6: numbered M105 probes for late oks.
        self.prober = Prober(window, probe_after)
        #: Statistics: genuine resend requests served, ack timeouts, lines
        #: acknowledged (by their ok, or proven received by a later Resend).
        self.resends = self.timeouts = self.acked = 0
        #: Round trip send -> ok (EWMA); sizes the drain delay and T2.
        self.rtt = _RTT_START
        self.reset()

    def reset(self) -> None:
        """Forget any recovery in progress (abandon())."""
        #: R1: the next ok answers a bad line, not a live one.
        self.awaiting_ok = False
        self._n: int | None = None
        self._dup_budget = self._repeats = self._consecutive_timeouts = 0
        self._after_timeout = self._busy_seen = False
        #: T1a: the last busy: said the firmware waits for the user.
        self.user_wait = False
        self._last_progress = self._window.clock
        #: R8: when the last line error came that no Resend has answered yet.
        self._error_at: float | None = None
        #: R8: the last good line the unanswered error named.
        self._error_last: int | None = None
        #: R1b: an ok that came right after a line error, held back (its number).
        self._held_ok: tuple[int | None] | None = None
        #: R7: a Resend for an acknowledged line, seen once, not yet believed.
        self._suspect: int | None = None
        #: R7: this firmware prints its line errors (not only Resend/rs).
        self._worded_errors: bool = getattr(self, "_worded_errors", False)
        #: Statistics: Resends ignored as line noise.
        self.noise: int = getattr(self, "noise", 0)

    @property
    def recovering(self) -> bool:
        """W4: a line asked for again is not acknowledged yet."""
        return self._n is not None

    def settled_live(self) -> int:
        """W4: live lines before the one asked for again (the firmware has them)."""
        n = self._n
        return sum(
            1
            for line in self._window.live
            if n is not None and line.number is not None and line.number < n
        )

    # -- replies ---------------------------------------------------------------------

    def ok(self, n: int | None, *, temperatures: bool = False) -> None:
        """`ok` or `ok N<n>`: T3, R1, R1b, T5, then acknowledge what it answers."""
        self.progress()
        self._consecutive_timeouts = 0
        settled = not self.awaiting_ok and self._held_ok is None
        if temperatures and settled and self._ack_through_probe():
            return
        if self.awaiting_ok:
            self.awaiting_ok = False
            return
        if self._error_at is not None and self._held_ok is None:
            self._held_ok = (n,)  # R1b: the error's own ok if a Resend follows
            return
        self._apply_ok(n)

    def _ack_through_probe(self) -> bool:
        """T5: `ok T:..` answers the newest live M105: the lines before it ran."""
        newest = self.prober.answered()
        if newest is None:
            return False
        live = self._window.live
        for _ in range(newest + 1):
            self._acknowledge(live.popleft())
        self._error_at = None
        return True

    def line_error(self, last: int | None = None) -> None:
        """A line error (checksum, line number): its Resend should follow (R8).

        *last* is the firmware's last good line, as the error names it.
        """
        self._worded_errors = True
        self.release_held_ok()
        self._error_at = self._window.clock
        self._error_last = last

    def release_held_ok(self) -> None:
        """R1b: no Resend followed the held ok: it answers a live line after all."""
        held, self._held_ok = self._held_ok, None
        if held is not None:
            self._apply_ok(held[0])

    def _apply_ok(self, n: int | None) -> None:
        live = self._window.live
        if live:
            self._error_at = None  # a line got through since the error
            if n is None or (not self._ack_through(n) and not self._is_stale(n)):
                self._acknowledge(live.popleft())
        elif self._after_timeout and self._window.m110_next():
            self._ack_unsent_before(self._window.rewind_next + 1)  # T4: late, not lost

    def resend(self, reply: Reply, previous: Reply | None) -> None:
        """`Resend: n` / `rs n` (F3, R2-R6); *previous* is the line before it."""
        self.progress()
        ok_came_first = self._held_ok is not None
        self._held_ok = self._error_at = None
        self.awaiting_ok = not ok_came_first  # R1, R1b
        window, n = self._window, reply.number
        window.hold(self.rtt)
        if n is None:
            self._error_at = window.clock  # R9: unreadable; R8 recovers
            return
        if window.need_m110:
            return  # nothing numbered since the last reset: not ours
        if window.m110_next():
            return  # F3: the M110 goes again anyway, this is a leftover
        m110 = next(
            (line.number for line in window.live if line.m110 is not None), None
        )
        if m110 is not None:  # F3: about the M110 itself, whatever number it names
            self._genuine_resend(m110, _context(reply, previous))
            return
        if self._is_noise(n, previous):
            self.noise += 1
            if previous is not None and previous.kind in _RESEND_ERRORS:
                self._error_at = window.clock  # R8 still watches its error
            return
        behind = self._behind(n, previous)
        if behind == "ignore":
            return
        if behind == "reset":
            oldest = window.oldest_unacked()
            self._reset_seen(f"{reply.text} after line {oldest - 1} was acknowledged")
            self.awaiting_ok = True  # R1 still holds for the ok that follows
            return
        copies = self._ack_received(n) if self._after_timeout else 0
        self._after_timeout = False
        if copies:
            self._n, self._dup_budget, self._repeats = n, copies - 1, 0
        elif self._is_duplicate(n, previous):
            self._dup_budget -= 1
            return
        if n == window.next_n:
            self._n, self._repeats = n, 0
            return
        self._genuine_resend(n, _context(reply, previous))

    def _is_noise(self, n: int, previous: Reply | None) -> bool:
        """R9 (see marlin_trust.is_noise)."""
        return is_noise(n, self._window.next_n, previous)

    def _behind(self, n: int, previous: Reply | None) -> str | None:
        """R7: "reset" for an acknowledged line 1 or one far back, "ignore", or None.

        Believed only when the same request comes twice in a row (and, from a
        firmware that words its line errors, with the error line agreeing each
        time): line noise can garble one number, hardly the same way twice.
        """
        window = self._window
        if not far_back(n, window.oldest_unacked(), window.history.first):
            self._suspect = None
            return None
        self.noise += 1
        if self._worded_errors and not agrees(n, previous):
            return "ignore"
        if self._suspect == n:
            return "reset"
        self._suspect = n
        return "ignore"

    def _is_duplicate(self, n: int, previous: Reply | None) -> bool:
        kind = previous.kind if previous else None
        return (
            n == self._n
            and kind is ReplyKind.LINE_NUMBER_ERROR
            and self._dup_budget > 0
        )

    def skip(self, n: int | None) -> None:
        """Repetier's `skip n`: a duplicate (R3), after a timeout R6, else R8.

        A skip nobody expects answers a line whose number noise turned into an
        old one: like a line error without Resend, the oldest live line goes again.
        """
        self.progress()
        if self._after_timeout and n is not None:
            self._ack_received(n + 1)
            self._after_timeout = False
        elif self._dup_budget > 0:
            self._dup_budget -= 1
        else:
            self.line_error()
        self.awaiting_ok = True

    def wait(self, *, printing: bool) -> None:
        """`wait` (T2)."""
        self.progress()
        live = self._window.live
        sent_at = live[0].sent_at if live else None
        if sent_at is not None and self._window.clock - sent_at > 2 * self.rtt:
            self.timeout(printing=printing, counted=False)

    def busy(self, message: str = "") -> None:
        """`busy:`: progress, and busy_timeout applies (T1).

        `busy: paused for user` / `paused for input` (M600, M0, a host prompt): the
        firmware waits for a person, for as long as they take; no deadline at all
        until an ok (or any other progress but another busy) ends the wait (T1a).
        """
        self.progress()
        self._busy_seen = True
        self.user_wait = message.lower().startswith(USER_WAIT)

    def temperature(self) -> None:
        """A temperature report is progress while a long command is oldest (T1)."""
        live = self._window.live
        if live and live[0].word in LONG_RUNNING:
            self.progress()

    def progress(self) -> None:
        self._last_progress = self._window.clock

    # -- acknowledgements and resends ------------------------------------------------

    def _acknowledge(self, line: Line) -> None:
        self.acked += 1
        if line.sent_at is not None:
            elapsed = min(self._window.clock - line.sent_at, _RTT_CAP)
            self.rtt += 0.2 * (elapsed - self.rtt)
        self._busy_seen = self._after_timeout = self.user_wait = False
        if not line.internal:
            self._events.append(Ack(line.tag))
        recovery = self._n
        if recovery is not None and line.number is not None and line.number >= recovery:
            self._end_recovery()

    def _is_stale(self, n: int | None) -> bool:
        """ok N<n> for a line acked already (a second copy of an M110): ignore it."""
        if n is None:
            return False
        oldest = next(
            (line.number for line in self._window.live if line.number is not None),
            None,
        )
        first = self._window.history.first
        return oldest is not None and first <= n < oldest

    def _ack_through(self, n: int) -> bool:
        """ok N<n>: ack live lines through line n; False when n is not live."""
        live = self._window.live
        for index, line in enumerate(live):
            if line.number == n:
                for _ in range(index + 1):
                    self._acknowledge(live.popleft())
                return True
        return False

    def _ack_received(self, m: int) -> int:
        """R6: the firmware holds every line before m; returns re-sent copies acked."""
        live = self._window.live
        last = -1
        for index, line in enumerate(live):
            if line.number is not None and line.number < m:
                last = index
        copies = 0
        for _ in range(last + 1):
            line = live.popleft()
            copies += line.resend and line.sent_at is not None
            self._acknowledge(line)
        self._ack_unsent_before(m)
        return copies

    def _ack_unsent_before(self, m: int) -> None:
        """Lines waiting to be re-sent that the firmware proved it has: skip, ack."""
        for old in self._window.skip_unsent_before(m):
            self.acked += 1
            if not old.internal:
                self._events.append(Ack(old.tag))

    def _genuine_resend(self, n: int, message: str) -> None:
        self._repeats = self._repeats + 1 if n == self._n else 1
        if self._repeats > self._max_resends:
            self._fail(
                f"firmware keeps asking for line {n} ({self._repeats} times in a row): "
                "check the cable, its shielding and the baud rate"
            )
            return
        self.resends += 1
        self._rewind(n, message)

    def _rewind(self, n: int, message: str, *, timed_out: bool = False) -> None:
        """R2: lines >= n die and go again from the history, after a drain delay."""
        self._ack_unsent_before(n)
        died = self._window.rewind(n, self.rtt)
        # The oldest dead line brought the request being served: only lines
        # behind it can bring leftovers (a budget too high would ignore a
        # genuine request; one too low only re-sends a line the firmware refuses).
        if died and not timed_out:
            died -= 1
        self._dup_budget = died + (self._dup_budget if n == self._n else 0)
        self._n = n
        self._events.append(ResendServed(n, message))

    def _end_recovery(self) -> None:
        self._n = None
        self._dup_budget = self._repeats = 0


def _context(reply: Reply, previous: Reply | None) -> str:
    """The error line that came with a Resend, for ResendServed's message."""
    if previous and previous.kind in _RESEND_ERRORS:
        return previous.text
    return reply.text
