"""Fault injection for the simulators: corrupted lines, lost oks, resets, stalls, closed ports."""

from __future__ import annotations

import math
import random
from dataclasses import dataclass

__all__ = ["RESET_BANNERS", "FaultConfig", "Faults"]

#: What a reset prints (FaultConfig.reset_banner).
RESET_BANNERS = ("start", "noise", "none")

#: Replacement bytes for a corrupted line: printable, never a line end, never one
#: of GRBL's realtime characters, so a corrupted line stays one (wrong) line.
_ALPHABET = b"0123456789ABCDEFGHJKLMNPQRSTUVWXYZ .-"


@dataclass
class FaultConfig:
    """What to break; zero or None switches a fault off."""

    #: Share (0..1) of received lines that get one byte replaced.
    corrupt: float = 0.0
    seed: int | None = None
    #: Share (0..1) of bytes garbled on the wire, towards the firmware and towards
    #: the host: a byte is replaced (sometimes by a line end) or lost, and a line
    #: end may be lost (two lines merge).
    noise_to_firmware: float = 0.0
    noise_to_host: float = 0.0
    #: Drop the ok of every Nth command.
    drop_ok_every: int = 0
    #: Drop this share (0..1) of oks at random.
    drop_ok_share: float = 0.0
    #: Reset the firmware once, after N executed commands ...
    reset_after: int = 0
    #: ... printing this banner: "start" (Marlin's), "noise" (bootloader bytes
    #: before `start`), "none" (a silent reset: nothing at all).
    reset_banner: str = "start"
    #: Stay busy (no ok, keepalives) for *busy_seconds* at the Nth command, once.
    busy_after: int = 0
    busy_seconds: float = 0.0
    #: Close the port once, after N executed commands ...
    close_after: int = 0
    #: ... and open it again this many seconds later (None: stay closed).
    reopen_after: float | None = None

    def validate(self) -> None:
        """Raise ValueError naming the first setting out of range."""
        for name in ("corrupt", "drop_ok_share", "noise_to_firmware", "noise_to_host"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be between 0 and 1")
        for name in ("drop_ok_every", "reset_after", "busy_after", "close_after"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must not be negative")
        if self.reset_banner not in RESET_BANNERS:
            raise ValueError(f"reset_banner must be one of {', '.join(RESET_BANNERS)}")
        if self.busy_seconds < 0 or (self.reopen_after or 0) < 0:
            raise ValueError("durations must not be negative")


class Faults:
    """The live fault state a firmware model and the runner consult.

    The firmware asks `corrupt_line` for each received line, `busy_for` before a
    command, `drop_ok` before an ok and `reset_due` after a command. The runner
    asks `close_due`. One-shot faults fire once; settings may change at any time.
    """

    def __init__(self, config: FaultConfig | None = None) -> None:
        self.config = config or FaultConfig()
        self.config.validate()
        self._random = random.Random(self.config.seed)
        self._oks = 0
        self._fired: set[str] = set()
        self.corrupted = 0
        self.dropped_oks = 0
        #: Bytes garbled on the wire (replaced, lost, line ends lost or made).
        self.garbled = 0

    def corrupt_line(self, line: bytes) -> bytes:
        """*line* (no line end), with one byte replaced for the configured share of lines.

        The leading `N` of a numbered line is spared: Marlin would run the result
        as an unnumbered, unchecked command, which tests the firmware's weakness,
        not the host's resend handling.
        """
        share = self.config.corrupt
        if not line or share <= 0 or self._random.random() >= share:
            return line
        first = 1 if line[:1] == b"N" and len(line) > 1 else 0
        position = self._random.randrange(first, len(line))
        choices = _ALPHABET.replace(line[position : position + 1], b"")
        replacement = choices[self._random.randrange(len(choices))]
        self.corrupted += 1
        return line[:position] + bytes((replacement,)) + line[position + 1 :]

    def garble(self, data: bytes, share: float, *, one_per_line: bool = False) -> bytes:
        """*data* as line noise leaves it: each byte hit with probability *share*.

        A hit byte is replaced by a random one (one time in eight by `\n`: the
        line splits), or lost one time in eight; a hit `\n` is lost (two lines
        merge). Hits are found by geometric skips, not a draw per byte.
        *one_per_line* skips to the next line end after a hit: two hits in one
        line can cancel out in the 8-bit XOR checksum, a weakness of the
        firmware's framing that no host can make up for.
        """
        if share <= 0 or not data:
            return data
        out = bytearray(data)
        rng = self._random
        position = -1
        log_miss = math.log1p(-share) if share < 1 else -math.inf
        while True:
            position += 1 + int(math.log(1.0 - rng.random()) / log_miss)
            if position >= len(out):
                return bytes(out)
            self.garbled += 1
            roll = rng.random()
            if out[position] == 0x0A or roll < 0.125:
                del out[position]
                position -= 1
            elif roll < 0.25:
                out[position] = 0x0A
            else:
                out[position] = (out[position] + rng.randrange(1, 256)) % 256
            if one_per_line:
                end = out.find(b"\n", position + 1)
                position = len(out) if end < 0 else end

    def drop_ok(self) -> bool:
        """True when the ok about to be sent should be lost."""
        self._oks += 1
        every = self.config.drop_ok_every
        drop = bool(every) and self._oks % every == 0
        share = self.config.drop_ok_share
        if not drop and share > 0:
            drop = self._random.random() < share
        if drop:
            self.dropped_oks += 1
        return drop

    def busy_for(self, count: int) -> float:
        """Seconds the firmware should stall before running command number *count*."""
        if self._once("busy", self.config.busy_after, count):
            return self.config.busy_seconds
        return 0.0

    def reset_due(self, count: int) -> bool:
        """True once, right after command number *count* = reset_after finished."""
        return self._once("reset", self.config.reset_after, count)

    def close_due(self, count: int) -> bool:
        """True once, when *count* executed commands reached close_after."""
        return self._once("close", self.config.close_after, count)

    def _once(self, name: str, threshold: int, count: int) -> bool:
        if threshold <= 0 or count < threshold or name in self._fired:
            return False
        self._fired.add(name)
        return True
