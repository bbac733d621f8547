"""The control socket's commands: faults and resets a test can trigger at run time."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

from printers.simulator._record import state_text

if TYPE_CHECKING:
    from printers.simulator.runner import Simulator

__all__ = ["COMMANDS", "run"]

COMMANDS = (
    "reset",
    "close",
    "reopen",
    "busy <seconds>",
    "corrupt <share>",
    "drop-ok <every_n>",
    "halt",
    "stats",
    "flush",
    "click",
    "action <text>",
    "say <text>",
    "sd",
    "sd-stop",
)


def run(sim: Simulator, line: str, now: float) -> str:
    """Apply one command line; returns the answer. Raises ValueError for bad input."""
    name, *args = line.split()
    name = name.lower()
    if name == "action":
        return _action(sim, line.split(None, 1)[1:], now)
    if name == "say":
        return _say(sim, line.split(None, 1)[1:])
    if name in ("sd", "sd-stop"):
        return _card(sim, stop=name == "sd-stop", args=args)
    if name in ("reset", "close", "reopen", "halt", "stats", "flush", "click") and args:
        raise ValueError(f"{name} takes no argument")
    if name == "reset":
        sim.firmware.reset(now)
    elif name == "close":
        sim.close_ports()
    elif name == "reopen":
        sim.reopen_ports(now)
    elif name == "halt":
        sim.firmware.halt(now)
    elif name == "click":
        return _click(sim, now)
    elif name == "stats":
        return "ok " + json.dumps(_stats(sim))
    elif name == "flush":
        if sim.recorder is None:
            raise ValueError("flush: this simulator keeps no record (--record)")
        sim.recorder.flush(now, force=True)
    elif name in ("busy", "corrupt", "drop-ok"):
        _set(sim, name, _one_number(name, args), now)
    else:
        raise ValueError(f"unknown command {name!r}; known: {', '.join(COMMANDS)}")
    return "ok"


def _click(sim: Simulator, now: float) -> str:
    """The LCD's button: continues a parked M600 (Marlin only)."""
    click = getattr(sim.firmware, "click", None)
    if click is None:
        raise ValueError("click: only a Marlin firmware has a display to click")
    if not click(now):
        raise ValueError("click: the printer is not waiting for the user")
    return "ok"


def _card(sim: Simulator, *, stop: bool, args: list[str]) -> str:
    """`sd`: the card as JSON; `sd-stop`: the printer's menu stops the card's print."""
    sd = getattr(sim.firmware, "sd", None)
    if args:
        raise ValueError("sd and sd-stop take no argument")
    if sd is None:
        raise ValueError("this printer has no SD card (--sd-card or --sd-dir)")
    if stop:
        if not sd.stop_from_display():
            raise ValueError("sd-stop: the card is not printing")
        return "ok"
    state = {
        "files": {name: sd.files.size(name) for name in sd.files},
        "selected": sd.selected,
        "position": sd.position,
        "printing": sd.printing,
        "writing": sd.writing,
    }
    return "ok " + json.dumps(state)


def _action(sim: Simulator, rest: list[str], now: float) -> str:
    """`action pause`: the firmware prints `//action:pause` (host action commands)."""
    text = _one_line("action takes the text after //action:, e.g. `action pause`", rest)
    refusal = "action: only a Marlin firmware sends host action commands"
    return _firmware_says(sim, f"//action:{text}", refusal)


def _say(sim: Simulator, rest: list[str]) -> str:
    """`say <text>`: the firmware prints a line of its own, as another firmware words
    it (`say Error: Heater 1 fault: ... 1.5°C/sec`, RepRapFirmware's)."""
    text = _one_line(
        "say takes the line to print, e.g. `say Error: heater fault`", rest
    )
    refusal = "say: only a Marlin firmware prints lines of its own here"
    return _firmware_says(sim, text, refusal)


def _firmware_says(sim: Simulator, line: str, refusal: str) -> str:
    """The firmware prints *line*; ValueError(*refusal*) for one that cannot."""
    say = getattr(sim.firmware, "say", None)
    if say is None:
        raise ValueError(refusal)
    say(line)
    return "ok"


def _one_line(usage: str, rest: list[str]) -> str:
    """The command's argument: one line of text (ValueError with *usage* if not)."""
    text = rest[0].strip() if rest else ""
    if not text or "\n" in text or "\r" in text:
        raise ValueError(usage)
    return text


def _one_number(name: str, args: list[str]) -> float:
    if len(args) != 1:
        raise ValueError(f"{name} takes one number")
    try:
        return float(args[0])
    except ValueError:
        raise ValueError(f"{name}: not a number: {args[0]!r}") from None


def _set(sim: Simulator, name: str, value: float, now: float) -> None:
    config = sim.faults.config
    if name == "busy":
        if value < 0:
            raise ValueError("busy: seconds must not be negative")
        sim.firmware.stall(now, value)
    elif name == "corrupt":
        if not 0 <= value <= 1:
            raise ValueError("corrupt: share must be between 0 and 1")
        config.corrupt = value
    else:
        if value < 0 or value != int(value):
            raise ValueError("drop-ok: every_n must be a whole number >= 0")
        config.drop_ok_every = int(value)


def _stats(sim: Simulator) -> dict[str, object]:
    firmware = sim.firmware
    return {
        "executed": firmware.executed_count,
        "dropped_bytes": firmware.dropped_bytes,
        "corrupted_lines": sim.faults.corrupted,
        "garbled_bytes": sim.faults.garbled,
        "dropped_oks": sim.faults.dropped_oks,
        "closed": sim.closed,
        "state": state_text(firmware),
    }
