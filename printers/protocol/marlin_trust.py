"""Which Resend requests MarlinProtocol believes (R7, R9): line noise garbles numbers too."""

from __future__ import annotations

from typing import TYPE_CHECKING

from printers.protocol.marlin_responses import ReplyKind

if TYPE_CHECKING:
    from printers.protocol.marlin_responses import Reply

__all__ = ["RESET_GAP", "agrees", "far_back", "is_noise"]

#: R7: how far behind the oldest unacknowledged line a Resend may legitimately
#: point. Only oks taken for the wrong line (an error's ok whose Error and
#: Resend lines were both lost to line noise) make the firmware ask for a line
#: the host counts as acknowledged, one line per such ok.
RESET_GAP = 16
_LINE_ERRORS = (ReplyKind.LINE_NUMBER_ERROR, ReplyKind.CHECKSUM_ERROR)


def is_noise(n: int, next_n: int, previous: Reply | None) -> bool:
    """R9: a Resend that cannot be right: ignored.

    It names a line never sent, or contradicts the line error just before it
    (`Last Line: k` asks for k+1): one of the two lines was garbled.
    """
    if n > next_n:
        return True
    last = previous.number if previous and previous.kind in _LINE_ERRORS else None
    return last is not None and n != last + 1


def agrees(n: int, previous: Reply | None) -> bool:
    """R7: the line error just before a Resend for n names n - 1 as its last."""
    return (
        previous is not None
        and previous.kind in _LINE_ERRORS
        and previous.number == n - 1
    )


def far_back(n: int, oldest: int, first: int) -> bool:
    """R7: n was acknowledged, and is the first line after the M110 or far back.

    A small step back (an error's ok taken for a line's) is served instead: the
    firmware checks the sequence, so nothing it has runs twice.
    """
    return n < oldest and (n <= first + 1 or oldest - n > RESET_GAP)
