"""Marlin 2.1 as a host sees it over serial, sans-IO: RX ring, line checks, queue, planner.

Rules of this module:
1. Bytes come in through `receive(data, now)` (already paced by a Wire); time
   passes only through `now` arguments; output leaves through `data_to_send()`.
2. Every reply uses Marlin's own wording (queue.cpp, language.h, M115.cpp), so a
   host that works here works against the firmware.
3. Command handlers either finish at once (return None) or are generators that
   yield what they wait for: a time (float) or a condition (callable -> bool).
   The executor resumes them with the current time.
"""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING

from printers.simulator import _marlin_text as text
from printers.simulator._marlin_dialect import DIALECTS
from printers.simulator._marlin_lines import CODE, Command, LineInput
from printers.simulator._marlin_machine import MarlinMachine, words
from printers.simulator._marlin_objects import CancelObjects
from printers.simulator._marlin_pause import FilamentChange
from printers.simulator._marlin_sd import SdCard
from printers.simulator._rx import LineReader

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    from printers.simulator._marlin_machine import Handler, Job, Wait
    from printers.simulator._motion import Planner
    from printers.simulator.faults import Faults

__all__ = ["MarlinFirmware"]


class MarlinFirmware(LineInput):
    """A Marlin printer: 4-slot command queue, 16-block planner, hotend and bed.

    `executed_count` counts commands taken from the queue; *on_execute* gets each
    one's text (without line number and checksum) in execution order.
    """

    WAKE_BYTES = b"\n\r"

    def __init__(
        self,
        *,
        rx_buffer: int = 128,
        bufsize: int = 4,
        planner: int = 16,
        time_scale: float = 1.0,
        advanced_ok: bool = True,
        emergency_parser: bool = True,
        keepalive: float = 2.0,
        host_prompts: bool = True,
        dialect: str = "marlin",
        ok_before_resend: bool = False,
        echo_lines: str = "",
        sd_card: bool = False,
        sd_dir: Path | None = None,
        faults: Faults | None = None,
        on_execute: Callable[[str], None] | None = None,
        now: float = 0.0,
        cancel_objects: bool = False,
        instant_waits: bool = False,
    ) -> None:
        self.rx_buffer = rx_buffer
        self.bufsize = bufsize
        self.planner_blocks = planner
        self.time_scale = time_scale
        #: Heat-ups and homing take no time, whatever the time scale.
        self.instant_waits = instant_waits
        self.advanced_ok = advanced_ok
        self.emergency_parser = emergency_parser
        self.default_keepalive = keepalive
        #: HOST_PROMPT_SUPPORT: M600 sends //action:paused and a prompt.
        self.host_prompts = host_prompts
        #: Wording and order of line errors (see _marlin_dialect).
        self.dialect = DIALECTS[dialect]
        self._ok_order = self.dialect.ok_order
        if ok_before_resend and self._ok_order != "none":
            self._ok_order = "before"
        #: "echo": print `echo:<line>` for each line received; "raw": the line.
        self.echo_lines = echo_lines
        self.faults = faults
        self.on_execute = on_execute
        #: CANCEL_OBJECTS: M486 (_marlin_objects), reported in M115.
        self.cancel_objects = cancel_objects
        self.objects: CancelObjects | None = None
        self.executed_count = 0
        self._out: list[str] = []
        self._reader = LineReader(rx_buffer, self._on_line, self._has_slot)
        #: SDSUPPORT: a card (in memory, or the files of *sd_dir*); it outlives resets.
        self.sd = SdCard(self._print, sd_dir) if sd_card or sd_dir else None
        self.reset(now)

    @property
    def planner(self) -> Planner:
        return self.machine.planner

    # -- the sans-IO surface ---------------------------------------------------------

    def receive(self, data: bytes, now: float) -> None:
        """Bytes that arrived from the host by *now*."""
        if self.killed or not data:
            return
        now = float(now)
        self.step(now)
        if self.emergency_parser:
            self._scan_emergency(data, now)
            if self.killed:
                return
            if self._poked:
                self._execute(now)
        self._reader.feed(data, now)

    def step(self, now: float) -> None:
        """Advance reports, moves, heaters and blocked commands to *now*."""
        if self.killed:
            return
        now = max(float(now), self._clock)
        self._clock = now
        self.planner.advance(now)
        self._tick_reports(now)
        self._execute(now)
        self._reader.drain(now)

    def data_to_send(self) -> bytes:
        """Everything printed since the last call."""
        if not self._out:
            return b""
        data = "".join(self._out).encode("latin-1", "replace")
        self._out.clear()
        return data

    def next_deadline(self) -> float | None:
        """The next time `step` has something to do, or None."""
        if self.killed:
            return None
        times = [self._keepalive_at, self._report_at]
        if self._job is not None:
            times.append(self._wait if isinstance(self._wait, float) else None)
            times.append(self.planner.next_deadline())
        if self._queue and self._stall_until > self._clock:
            times.append(self._stall_until)
        if self.sd is not None:
            times.append(self.sd.next_report())
            if self.sd.printing and len(self._queue) < self.bufsize:
                times.append(self._clock)  # the card can feed a free slot
        pending = [t for t in times if t is not None]
        return min(pending) if pending else None

    # -- control (the runner's control socket and faults) ---------------------------

    def reset(self, now: float, banner: str = "start") -> None:
        """Power-on or reset: forget everything, print the boot banner.

        *banner* "noise" puts bootloader garbage before `start`; "none" prints
        nothing (a reset the host can only notice by the line numbers).
        """
        self._clock = now
        self.killed = False
        self._reader.flush()
        self._queue: deque[Command] = deque()
        self._job: Job | None = None
        self._wait: Wait | None = None
        self._poked = False
        self._last_n = 0
        self._ep_tail = b""
        self._stall_until = 0.0
        self._keepalive_at: float | None = None
        self._report_at: float | None = None
        self._report_interval = 0.0
        self.keepalive = self.default_keepalive
        self.pause = FilamentChange(self._print, host_prompts=self.host_prompts)
        self.machine = MarlinMachine(
            self._print,
            planner=self.planner_blocks,
            time_scale=self.time_scale,
            now=now,
            instant_waits=self.instant_waits,
        )
        if self.sd is not None:
            self.sd.reset()
        if self.cancel_objects:
            self.objects = CancelObjects(self._print)
        self._handlers = self._handler_table()
        if banner == "noise":
            self._out.append(text.BOOT_NOISE)
        if banner != "none":
            self._print(*text.BOOT)

    def halt(self, now: float) -> None:
        """kill(): what M112 does. Nothing works until `reset`."""
        self._print("Error:Printer halted. kill() called!", "//action:kill")
        self.killed = True
        self._reader.flush()
        self._queue.clear()
        self._job = None
        self.machine.switch_off(now)

    def stall(self, now: float, seconds: float) -> None:
        """Stay busy for *seconds*: nothing starts or finishes, keepalives go out."""
        self._stall_until = max(self._stall_until, now + seconds)
        self._update_busy(now)

    @property
    def dropped_bytes(self) -> int:
        """Bytes lost because they arrived while the RX ring was full."""
        return self._reader.dropped

    # -- reading lines ---------------------------------------------------------------

    def _has_slot(self) -> bool:
        return len(self._queue) < self.bufsize and not self.killed

    def click(self, now: float) -> bool:
        """The LCD's button: continue a parked M600; False if nothing waits."""
        if not self.pause.continue_("click"):
            return False
        self._poked = True
        self._execute(now)
        return True

    def say(self, text: str) -> None:
        """Print *text* as a line of the firmware's own (an error, a notice, a
        `//action:` as an LCD menu or a macro makes it)."""
        self._print(text)

    # -- executing commands ----------------------------------------------------------

    def _execute(self, now: float) -> None:
        """Run queued commands in order until one blocks or the queue is empty."""
        self._feed_from_card()
        while self._queue and not self.killed:
            if self._job is not None:
                if not self._resume(now):
                    break
            else:
                if now < self._stall_until:
                    break
                if self.faults is not None:
                    stall = self.faults.busy_for(self.executed_count + 1)
                    if stall > 0:
                        self._stall_until = now + stall
                        break
                job = self._dispatch(self._queue[0], now)
                if job is not None and not self._start(job, now):
                    break
            self._finish(now)
            self._feed_from_card()
        self._update_busy(now)

    def _feed_from_card(self) -> None:
        """get_sdcard_commands: while printing, the card's lines fill free slots."""
        sd = self.sd
        if sd is None or self._reader.waiting:
            return  # serial lines first: step() drains them into the free slot
        while sd.printing and len(self._queue) < self.bufsize:
            line = sd.next_command()
            if line is None:
                return
            self._queue.append(Command(line, None, from_card=True))

    def _start(self, job: Job, now: float) -> bool:
        """Run a blocking handler up to its first wait; True if it finished at once."""
        try:
            self._wait = next(job)
        except StopIteration:
            return True
        self._job = job
        return self._resume(now)

    def _resume(self, now: float) -> bool:
        """Drive the blocked head command; True once it has finished."""
        job = self._job
        while job is not None:
            wait = self._wait
            if not self._poked and not (
                now >= wait if isinstance(wait, float) else wait()
            ):
                return False
            self._poked = False
            try:
                self._wait = job.send(now)
            except StopIteration:
                self._job = self._wait = None
                return True
        return True

    def _dispatch(self, command: Command, now: float) -> Job | None:
        sd = self.sd
        if sd is not None and not command.from_card and sd.capture(command.text):
            return None  # M28 is writing: the line went into the file, never run
        self.executed_count += 1
        if self.on_execute is not None:
            self.on_execute(command.text)
        code = CODE.match(command.text)
        handler = None
        if code is not None:
            handler = self._handlers.get(code[1].upper() + str(int(code[2])))
        if handler is None:
            self._print(f'echo:Unknown command: "{command.text}"')
            return None
        return handler(command.text[code.end() :], now)

    def _finish(self, now: float) -> None:
        """ok_to_send(), while the command still counts in the queue; then free its slot."""
        command = self._queue[0]
        reply, self.machine.custom_ok = self.machine.custom_ok, None
        if command.from_card:
            reply = ""  # a command from the card came from no port: no ok
        elif self.faults is not None and self.faults.drop_ok():
            reply = None
        elif reply is None:
            reply = "ok"
            if self.advanced_ok:
                n = "" if command.number is None else f" N{command.number}"
                free = self.bufsize - len(self._queue)
                reply = f"ok{n} P{self.planner.free} B{free}"
            elif self.dialect.numbered_ok and command.number is not None:
                reply = f"ok {command.number}"
        if reply:
            self._out.append(reply + "\n")
        self._queue.popleft()
        self._keepalive_at = None  # idle() between commands restarts its timer
        if self.faults is not None and self.faults.reset_due(self.executed_count):
            self.reset(now, self.faults.config.reset_banner)

    def _update_busy(self, now: float) -> None:
        """host_keepalive: `busy: processing` every interval while a command blocks."""
        blocked = self._job is not None or (self._queue and now < self._stall_until)
        if not blocked or self.keepalive <= 0:
            self._keepalive_at = None
        elif self._keepalive_at is None:
            self._keepalive_at = now + self.keepalive

    def _tick_reports(self, now: float) -> None:
        at = self._keepalive_at
        if at is not None and now >= at:
            why = "paused for user" if self.pause.waiting else "processing"
            self._print(f"echo:busy: {why}")
            self._keepalive_at = max(at + self.keepalive, now)
        at = self._report_at
        if at is not None and now >= at:
            self._print(" " + self.machine.temperatures(now))
            self._report_at = max(at + self._report_interval, now)
        if self.sd is not None:
            self.sd.tick(now)

    def _print(self, *lines: str) -> None:
        self._out.extend(line + "\n" for line in lines)

    # -- the commands that touch the serial side -------------------------------------

    def _handler_table(self) -> dict[str, Handler]:
        table = self.machine.handlers()
        table.update(
            M110=self._m110,
            M113=self._m113,
            M115=self._m115,
            M155=self._m155,
            M600=self.pause.m600,
            M876=self.pause.m876,
        )
        if self.sd is not None:
            table.update(self.sd.handlers())
        if self.objects is not None:
            self.objects.wrap(table)
        return self.dialect.supported(table)

    def _m110(self, args: str, now: float) -> None:
        given = words(args)
        if "N" in given:
            self._last_n = int(given["N"])

    def _m113(self, args: str, now: float) -> None:
        given = words(args)
        if "S" in given:
            self.keepalive = min(max(given["S"], 0.0), 60.0)

    def _m115(self, args: str, now: float) -> None:
        if self.dialect.name == "reprapfirmware":
            self._print(text.RRF_INFO)
            return
        self._print(
            text.firmware_info(
                emergency_parser=self.emergency_parser, sd_card=self.sd is not None
            )
        )
        if self.objects is not None:
            self._print("Cap:CANCEL_OBJECTS:1")

    def _m155(self, args: str, now: float) -> None:
        interval = words(args).get("S", 0.0)
        self._report_interval = interval
        self._report_at = now + interval if interval > 0 else None
