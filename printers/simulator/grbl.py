"""GRBL 1.1h as a host sees it over serial, sans-IO: realtime bytes, RX ring, one line at a time.

Rules of this module:
1. Same shape as the Marlin model: `receive(data, now)`, `step(now)`,
   `data_to_send()`, `next_deadline()`; time passes only through `now`.
2. Realtime bytes (`?` `!` `~` 0x18 and 0x80-0xFF) are taken as they arrive and
   never enter the ring; every other byte waits in a 128-byte ring (overflow is
   lost). Each line gets exactly one `ok` or `error:N`; all lines end in CRLF.
3. While an EEPROM write runs, arriving bytes are lost (GRBL turns the RX
   interrupt off), so `$x=`, `G10 L2`, `G28.1`... must be sent ping-pong; `$x=`
   is refused with error:8 unless Idle (or Alarm), and G10 L2/G28.1 first wait
   for the planner to empty (FORCE_BUFFER_SYNC_DURING_EEPROM_WRITE).
4. `variant="grblhal"` answers as grblHAL does: its banner, `[FIRMWARE:grblHAL]`
   and a 1024-byte RX buffer in `$I` (the runner picks the buffer size).
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

from printers.simulator import _grbl_realtime as realtime
from printers.simulator import _grbl_system as system
from printers.simulator._grbl_gcode import GcodeState
from printers.simulator._motion import Planner, distance
from printers.simulator._rx import LineReader

if TYPE_CHECKING:
    from collections.abc import Callable, Generator

    from printers.simulator.faults import Faults

    Wait = float | Callable[[], bool]
    Job = Generator[Wait, float, int]

__all__ = ["GrblFirmware"]

BANNER = "\r\nGrbl 1.1h ['$' for help]"
#: What each variant prints when it starts.
BANNERS = {"grbl": BANNER, "grblhal": "\r\nGrblHAL 1.1f ['$' or '$HELP' for help]"}
#: RX buffer bytes each variant has unless told otherwise (grblHAL drivers: 1024).
RX_BUFFERS = {"grbl": 128, "grblhal": 1024}
#: LINE_BUFFER_SIZE 80 holds 79 characters and the terminator.
MAX_LINE = 79
#: Seconds an EEPROM write keeps the RX interrupt off (times time_scale).
EEPROM_SECONDS = 0.02
HOMING_SECONDS = 2.0
_REALTIME = re.compile(rb"[?!~\x18\x80-\xff]")
_CLEAN = re.compile(r"\([^)]*\)?|;.*|[\x00- ]")
_MOVING = ("Run", "Jog", "Home")
_LOCKED_MESSAGE = "[MSG:'$H'|'$X' to unlock]"


class GrblFirmware:
    """A 3-axis GRBL controller: 16-block planner (15 usable), 128-byte RX ring."""

    WAKE_BYTES = b"\n\r?!~\x18" + bytes(range(0x80, 0x100))

    def __init__(
        self,
        *,
        rx_buffer: int | None = None,
        planner: int = 16,
        variant: str = "grbl",
        time_scale: float = 1.0,
        faults: Faults | None = None,
        on_execute: Callable[[str], None] | None = None,
        now: float = 0.0,
    ) -> None:
        if variant not in BANNERS:
            raise ValueError(
                f"unknown GRBL variant {variant!r}; known: {sorted(BANNERS)}"
            )
        self.variant = variant
        self.rx_buffer = rx_buffer = rx_buffer or RX_BUFFERS[variant]
        self.planner_blocks = planner
        self.time_scale = time_scale
        self.faults = faults
        self.on_execute = on_execute
        self.executed_count = 0
        self.lost_bytes = 0
        self._out: list[str] = []
        self._reader = LineReader(rx_buffer, self._on_line, self._can_read)
        self.settings = dict(system.DEFAULTS)
        self.startup_lines = ["", ""]
        rates = tuple(self.settings[k] for k in (110, 111, 112))
        self.gcode = GcodeState(rates)
        self.state = "Idle"
        self._power_on(now)

    # -- the sans-IO surface ---------------------------------------------------------

    def receive(self, data: bytes, now: float) -> None:
        """Bytes that arrived from the host by *now*."""
        if not data:
            return
        now = float(now)
        self.step(now)
        if now < self._rx_off_until:
            self.lost_bytes += len(data)
            return
        pos = 0
        for match in _REALTIME.finditer(data):
            if match.start() > pos:
                self._reader.feed(data[pos : match.start()], now)
            realtime.act(self, data[match.start()], now)
            pos = match.end()
        if pos < len(data):
            self._reader.feed(data[pos:] if pos else data, now)

    def step(self, now: float) -> None:
        """Advance motion and the blocked line (if any) to *now*; read waiting lines."""
        now = max(float(now), self._clock)
        self._clock = now
        self.planner.advance(now)
        if self._job is not None:
            self._resume(now)
        self._update_state()
        self._reader.drain(now)

    def data_to_send(self) -> bytes:
        if not self._out:
            return b""
        data = "".join(self._out).encode("ascii", "replace")
        self._out.clear()
        return data

    def next_deadline(self) -> float | None:
        times = []
        if self._job is not None:
            times.append(self._wait if isinstance(self._wait, float) else None)
            times.append(self.planner.next_deadline())
        if self._stall_until > self._clock:
            times.append(self._stall_until)
        pending = [t for t in times if t is not None]
        return min(pending) if pending else None

    # -- control -----------------------------------------------------------------

    def reset(self, now: float) -> None:
        """Power cycle: the state starts over at Idle and the banner is printed."""
        self.state = "Idle"
        self.gcode.position = [0.0, 0.0, 0.0]
        self._power_on(now)

    def soft_reset(self, now: float) -> None:
        """Ctrl-X: stop everything; ALARM:3 if it interrupted motion."""
        self._update_state()
        self.gcode.position = list(self.planner.clear(now))
        if self.state in _MOVING:
            self.print_lines("ALARM:3")
            self.state = "Alarm"
        elif self.state not in ("Alarm", "Sleep"):
            self.state = "Idle"
        else:
            self.state = "Alarm"
        self._power_on(now)

    def halt(self, now: float) -> None:
        """A hard-limit alarm: ALARM:1, and nothing but `?` and Ctrl-X until reset."""
        self._stop_motion(now)
        self.state = "Alarm"
        self._locked = True
        self.print_lines("ALARM:1", "[MSG:Reset to continue]")

    def stall(self, now: float, seconds: float) -> None:
        """Stay busy for *seconds*: no line is read or answered."""
        self._stall_until = max(self._stall_until, now + seconds)

    @property
    def rx_free(self) -> int:
        """RX ring bytes free (the second number of `Bf:`)."""
        return self._reader.free

    @property
    def dropped_bytes(self) -> int:
        """Bytes lost to a full ring or to an EEPROM write."""
        return self._reader.dropped + self.lost_bytes

    def _power_on(self, now: float) -> None:
        self._clock = now
        self._reader.flush()
        self.planner = Planner(self.planner_blocks, tuple(self.gcode.position))
        self.gcode.reset_modes()
        self._job: Job | None = None
        self._wait: Wait | None = None
        self._stops = 0
        self._locked = False
        self.reset_after_ok = False
        self._rx_off_until = 0.0
        self._stall_until = 0.0
        self._feed_ov, self._rapid_ov, self._spindle_ov = 100, 100, 100
        self._reports = 0
        self._rate = 0.0
        self.print_lines(BANNERS[self.variant])
        if self.state == "Alarm":
            self.print_lines(_LOCKED_MESSAGE)

    # -- realtime bytes ------------------------------------------------------------

    def _stop_motion(self, now: float) -> None:
        """Flush the planner; the parser continues from where the machine stopped."""
        self.gcode.position = list(self.planner.clear(now))
        self.planner.hold(now, held=False)
        self._stops += 1

    def _update_state(self) -> None:
        if self.state in ("Run", "Jog") and self.planner.idle():
            self.state = "Idle"

    def _status(self, now: float) -> None:
        """`?`: the report of the state at *now* (see `_grbl_system.status_fields`)."""
        self._update_state()
        position = self.planner.position(now)
        running = self.state in ("Run", "Jog")
        rate = self._rate * self._feed_ov / 100 if running else 0.0
        overrides = (self._feed_ov, self._rapid_ov, self._spindle_ov)
        fields = system.status_fields(self, position, rate, overrides, self._reports)
        self._reports += 1
        self.print_lines("<" + "|".join(fields) + ">")

    # -- lines ---------------------------------------------------------------------

    def _can_read(self) -> bool:
        return (
            self._job is None
            and not self._locked
            and self._clock >= self._stall_until
            and self.state != "Sleep"
        )

    def _on_line(self, raw: bytes, now: float) -> None:
        if self.faults is not None:
            raw = self.faults.corrupt_line(raw)
        original = raw.decode("latin-1")
        line = _CLEAN.sub("", original).upper()
        if len(line) > MAX_LINE:
            self._reply(11, now)  # line overflow
            return
        if not line:
            self._reply(0, now)  # empty or comment line: ok, for syncing
            return
        stall = self.faults.busy_for(self.executed_count + 1) if self.faults else 0.0
        if stall > 0:
            self._start(self._later(line, original, stall, now), now)
            return
        result = self._process(line, original, now)
        if isinstance(result, int):
            self._reply(result, now)
        else:
            self._start(result, now)

    def _later(self, line: str, original: str, seconds: float, now: float) -> Job:
        until = now + seconds
        while now < until:
            now = yield until
        result = self._process(line, original, now)
        if isinstance(result, int):
            return result
        return (yield from result)

    def _process(self, line: str, original: str, now: float) -> int | Job:
        """Run a line: an error code, 0 for ok now, or a job that ends with the code."""
        if line[0] == "$":
            result = system.run_command(self, line, now)
        elif self.state == "Alarm" or self.state == "Jog":
            return 9  # G-code locked out during alarm or jog state
        else:
            actions = self.gcode.execute(line)
            result = actions if isinstance(actions, int) else self.play(actions, now)
        if result != 0 and isinstance(result, int):
            return result
        self.executed_count += 1
        if self.on_execute is not None:
            self.on_execute(original.strip())
        return result

    def play(self, actions: list[tuple], now: float, *, jog: bool = False) -> int | Job:
        """Play a line's actions: 0 if done at once, else the job that ends with its ok."""
        if self.state == "Check" or not actions:
            return 0
        if len(actions) == 1 and actions[0][0] == "move" and self.planner.has_room():
            self._add_move(actions[0], now, jog=jog)
            return 0
        return self._run(actions, now, jog=jog)

    def _run(self, actions: list[tuple], now: float, *, jog: bool = False) -> Job:
        """Play the actions of one line; the line's ok waits until the last is done."""
        for action in actions:
            kind = action[0]
            if kind == "move":
                stops = self._stops
                while not self.planner.has_room() and stops == self._stops:
                    now = yield self.planner.has_room
                if stops == self._stops:
                    self._add_move(action, now, jog=jog)
            elif kind == "sync":
                while not self.planner.idle():
                    now = yield self.planner.idle
            elif kind in ("dwell", "eeprom"):
                seconds = action[1] if kind == "dwell" else EEPROM_SECONDS
                until = now + seconds * self.time_scale
                if kind == "eeprom":
                    self._rx_off_until = until
                while now < until:
                    now = yield until
            else:
                self._play_message(kind, now)
        return 0

    def _play_message(self, kind: str, now: float) -> None:
        if kind == "pause":
            realtime.feed_hold(self, now)
        elif kind == "end":
            self.print_lines("[MSG:Pgm End]")
        elif kind == "probe":
            self.print_lines(f"[PRB:{_xyz(self.gcode.position)}:1]")

    def _add_move(self, action: tuple, now: float, *, jog: bool = False) -> None:
        _, target, seconds, rapid = action
        length = distance(self.planner.end, target)
        self._rate = length / seconds * 60.0 if seconds > 0 else 0.0
        self.planner.add(seconds * self.time_scale, target, now, rapid=rapid)
        if self.state == "Idle" and not self.planner.idle():
            self.state = "Jog" if jog else "Run"

    def _start(self, job: Job, now: float) -> None:
        try:
            self._wait = next(job)
        except StopIteration as stop:
            self._reply(stop.value or 0, now)
            return
        self._job = job
        self._resume(now)

    def _resume(self, now: float) -> None:
        job = self._job
        while job is not None:
            wait = self._wait
            if not (now >= wait if isinstance(wait, float) else wait()):
                return
            try:
                self._wait = job.send(now)
            except StopIteration as stop:
                self._job = self._wait = None
                self._reply(stop.value or 0, now)
                return

    def _reply(self, status: int, now: float) -> None:
        if status:
            self.print_lines(f"error:{status}")
        elif self.faults is None or not self.faults.drop_ok():
            self.print_lines("ok")
        if self.reset_after_ok:
            self.reset_after_ok = False
            self.soft_reset(now)
        elif self.faults is not None and self.faults.reset_due(self.executed_count):
            self.reset(now)

    def home(self, now: float) -> Job:
        """`$H`: the Home state for a while, then Idle at machine zero."""
        self.state = "Home"
        until = now + HOMING_SECONDS * self.time_scale
        while now < until:
            now = yield until
        self.gcode.position = [0.0, 0.0, 0.0]
        self.planner.set_origin((0.0, 0.0, 0.0))
        self.state = "Idle"
        return 0

    def print_lines(self, *lines: str) -> None:
        """Queue reply lines (CRLF-terminated, as GRBL writes them)."""
        self._out.extend(line + "\r\n" for line in lines)


def _xyz(values: list[float] | tuple[float, ...]) -> str:
    return ",".join(f"{v:.3f}" for v in values)
