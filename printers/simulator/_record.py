"""The record of executed commands: one per line, appended, flushed every 50 ms."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from pathlib import Path

__all__ = ["RECORD_INTERVAL", "Recorder"]

#: The record is written at least this often while commands are executed.
RECORD_INTERVAL = 0.05


class Recorder:
    """Appends executed commands to a file, one per line, in batches."""

    def __init__(self, path: Path) -> None:
        self._file = path.open("a", encoding="utf-8")
        self._lines: list[str] = []
        self._flushed_at = 0.0

    def add(self, command: str) -> None:
        self._lines.append(command)

    def deadline(self) -> float | None:
        return self._flushed_at + RECORD_INTERVAL if self._lines else None

    def flush(self, now: float, *, force: bool = False) -> None:
        if self._lines and (force or now >= self._flushed_at + RECORD_INTERVAL):
            self._file.write("\n".join(self._lines) + "\n")
            self._file.flush()
            self._lines.clear()
            self._flushed_at = now

    def close(self) -> None:
        self.flush(0.0, force=True)
        self._file.close()


def state_text(firmware: object) -> str:
    """The firmware's state as `--record-state` and `stats` give it: X Y Z E for
    Marlin; GRBL's work position, `$G` modes and machine position (`MPos:`)."""
    gcode = getattr(firmware, "gcode", None)
    if gcode is not None:
        work = [p - o for p, o in zip(gcode.position, gcode.work_offset(), strict=True)]
        machine = ",".join(f"{v:.4f}" for v in gcode.position)
        return " ".join(f"{v:.4f}" for v in work) + f" {gcode.modes()} MPos:{machine}"
    return " ".join(f"{v:.5f}" for v in firmware.machine.position)  # type: ignore[attr-defined]
