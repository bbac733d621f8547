"""How the worker reacts to protocol and stream-host events (a mixin of PrinterWorker)."""

from __future__ import annotations

import logging
from functools import partial
from typing import TYPE_CHECKING

from jobs.models import Job
from printers.protocol import events as ev
from printers.protocol.events import LineKind
from printers.protocol.grbl_events import BuildOptions, CheckMode, Locked, Unlocked
from printers.streaming import Stream
from printers.streaming import host_events as hv
from printers.worker import spool
from printers.worker.emergency import EMERGENCY, hold_then_reset, reset_when_held
from printers.worker.lease import UNREACHABLE, DatabaseAway

if TYPE_CHECKING:
    from collections.abc import Callable

    from printers.worker.loop import PrinterWorker

logger = logging.getLogger("printhost.worker")

#: What the firmware's //action: lines mean to the stream here: pause/resume run
#: the printer's scripts (the host is asked to act); paused/resumed do not (the
#: printer already parked or continued by itself: from its display, M600, M125).
_STREAM_ACTIONS = {
    "pause": ("pause", True),
    "paused": ("pause", False),
    "resume": ("resume", True),
    "resumed": ("resume", False),
}


class Reactions:
    """Event handlers: each protocol or host event becomes a DB write and/or a request."""

    #: The GRBL alarm the printer shows (ERROR state) until `$X`, homing or a reset.
    grbl_alarm: str = ""
    #: The alarm shown when GRBL last reset: it boots locked in it (`'$X' to unlock`).
    _alarm_before_reset: str = ""

    # -- protocol events ---------------------------------------------------------

    def handle_protocol_events(self: PrinterWorker, now: float) -> None:
        # Every line brings three of these (Sent, Received, Ack): told apart by
        # their exact type, the cheapest test, before the rarer kinds.
        # The protocol's event queue itself (`next_event` pops it): two of these a
        # turn, most finding it empty.
        events = self.protocol.events
        if not events:
            return
        log = self.log
        while events:
            event = events.popleft()
            kind = type(event)
            if kind is ev.Received:
                log.add(event.text, event.kind)
                if self.sd_replies:
                    self.sd.receive(event.text)
            elif kind is ev.Ack:
                self.host.handle_ack(event.tag)
            elif kind is ev.Sent:
                log.add(event.text, LineKind.COMMAND)
            else:
                self._on_protocol_event(event, now)

    def _on_protocol_event(self: PrinterWorker, event: ev.Event, now: float) -> None:
        match event:
            case ev.CommandFailed(tag=tag, message=message):
                self.host.handle_failed(tag, message)
            case ev.ResendServed():
                self.host.handle_resend()
            case ev.TemperatureReport(readings=readings):
                temps = {
                    k: {"current": c, "target": t} for k, (c, t) in readings.items()
                }
                self.status.update(temperatures=temps)
            case ev.StatusReport(state=state, fields=fields):
                self._on_grbl_status(state, fields)
            case ev.FirmwareInfo(name=name, fields=fields):
                self.status.update(firmware_name=name)
                if self.printer.is_grbl:
                    self._merge_capabilities({k.lower(): v for k, v in fields.items()})
            case BuildOptions() | CheckMode() | Locked() | Unlocked():
                self._on_grbl_event(event)
            case ev.Capability(name=name, enabled=enabled):
                self._on_capability(name, enabled=enabled)
            case ev.ActionCommand(action=action, argument=argument):
                self._on_action(action.lower(), argument)
            case ev.FirmwareReset(banner=banner):
                self._on_reset(banner, now)
            case ev.FirmwareHalted(message=message):
                self.stop_streams(f"the firmware halted: {message}", note=True)
                if not self.halted.startswith(EMERGENCY):  # the stop says more
                    self.halted = f"{message} (reset the printer, then reconnect)"
            case ev.Alarm(message=message):
                self._on_alarm(message)
            case ev.FirmwareError(message=message):
                stream = self.host.current_stream
                if stream is not None and self.host.fail_stream(
                    f"the firmware reported an error: {message}"
                ):
                    # Nothing more of the job goes, the lines waiting to be sent
                    # again included.
                    self.protocol.abandon()
                    self.stop_motion_after_error(stream)
            case ev.FirmwareMessage(text=text) if (
                self.quickstopped is not None
                and text.startswith("Unknown command")
                and "M410" in text
            ):
                self.note(
                    "the firmware does not know M410 (Prusa-Firmware on a MK3 has "
                    "none): the quickstop did nothing, the planned moves ran out "
                    "before the abort script; turn quickstop_on_abort off here"
                )
            case ev.LinkFailed(message=message):
                self.stop_streams(message, note=True)
                self._close()
                self._retry_later(now, message)
        self.update_state()

    def _on_capability(self: PrinterWorker, name: str, *, enabled: bool) -> None:
        self._merge_capabilities({name: enabled})
        self.sd.on_capability(name, enabled=enabled)
        if name == "EMERGENCY_PARSER":
            self.emergency_parser = enabled
        interval = self.printer.temperature_interval
        if name == "AUTOREPORT_TEMP" and enabled and interval > 0:
            self.autoreport = True
            self.submit_internal(f"M155 S{max(1, round(interval))}")

    def _merge_capabilities(self: PrinterWorker, values: dict[str, object]) -> None:
        caps = dict(self.status.fields.get("capabilities", {}))
        caps.update(values)
        self.status.update(capabilities=caps)

    # -- GRBL --------------------------------------------------------------------

    def _on_grbl_status(
        self: PrinterWorker, state: str, fields: dict[str, str]
    ) -> None:
        check_mode = bool(getattr(self.protocol, "check_mode", False))
        self.status.update(
            machine_status={"state": state, **fields, "check_mode": check_mode}
        )
        reset_when_held(self, self.clock(), state)
        if state.startswith("Alarm"):
            if not self.grbl_alarm:
                self._show_alarm("GRBL is in alarm")
        elif self.grbl_alarm:
            self._clear_alarm()

    def _on_grbl_event(self: PrinterWorker, event: ev.Event) -> None:
        match event:
            case BuildOptions(letters=letters, planner_blocks=blocks, rx_buffer=rx):
                self._merge_capabilities(
                    {"options": letters, "planner_blocks": blocks, "rx_buffer": rx}
                )
            case CheckMode(enabled=enabled):
                status = dict(self.status.fields.get("machine_status", {}))
                self.status.update(machine_status={**status, "check_mode": enabled})
                if enabled:
                    self.note("GRBL check mode is on: lines are checked, nothing moves")
                else:
                    self.note("GRBL check mode is off")
            case Unlocked():
                self._clear_alarm()
            case Locked():
                self._show_alarm(self._alarm_before_reset or "GRBL started in alarm")

    def _on_alarm(self: PrinterWorker, message: str) -> None:
        """An alarm stops the job (never carried on) and shows until `$X` or reset."""
        if self.host.current_stream is not None:
            # Its end holds the feed; lines in flight are forgotten (GRBL refuses
            # them with error:9 while in alarm, or drops them on a hard limit).
            self.stop_streams(f"GRBL alarm: {message}; the job was stopped", note=True)
        else:
            self.stop_streams(f"GRBL alarm: {message}")
        self._show_alarm(message)

    def _show_alarm(self: PrinterWorker, message: str) -> None:
        if self.halted and not self.grbl_alarm:
            return  # a harder stop (a halt) is already shown
        self.grbl_alarm = message
        self.halted = f"{message} (send $X to unlock, $H to home, or reset)"

    def _clear_alarm(self: PrinterWorker) -> None:
        if self.grbl_alarm and self.halted.startswith(self.grbl_alarm):
            self.halted = ""
        self.grbl_alarm = ""

    def _on_action(self: PrinterWorker, action: str, argument: str) -> None:
        line = f"//action:{action} {argument}".rstrip()
        if action.startswith("prompt_"):
            self.prompts.on_action(
                action, argument, answerable=self.emergency_parser is True
            )
        elif action in _STREAM_ACTIONS:
            wanted, script = _STREAM_ACTIONS[action]
            host = self.host
            error = (
                host.request_pause(script=script)
                if wanted == "pause"
                else host.request_resume(script=script)
            )
            scripted = " (running the printer's script)" if script else ""
            self.note(
                f"the printer asked: {line}{scripted}" + (f": {error}" if error else "")
            )
        elif action == "cancel":
            self.note(f"the printer asked: {line}")
            self.host.request_abort("cancelled by the printer (//action:cancel)")
        elif action == "disconnect":
            self.stay_offline = True
            self.disconnect(
                "the printer asked the host to close the port (//action:disconnect); "
                "it stays offline until a reconnect request"
            )
            self.note("disconnected by the printer (//action:disconnect)")
        elif action == "notification":
            self.note(f"printer says: {argument}")
        else:  # start, probe_failed and whatever a newer firmware adds
            self.note(f"the printer sent {line}")

    def _on_reset(self: PrinterWorker, banner: str, now: float) -> None:
        if self.host.current_stream is not None:
            self.stop_streams(
                f"the firmware reset ({banner!r}) mid-job: the printer lost its state, "
                "so the job was stopped, not continued",
                note=True,
            )
        else:
            self.stop_streams(f"the firmware reset ({banner!r})")
        self._alarm_before_reset = self.grbl_alarm
        self.grbl_alarm = ""
        self.prompts.clear()
        self.sd.reset()
        if self.expect_reset:  # our emergency DTR pulse: the stop's message stays
            self.expect_reset = False
        elif not self.halted.startswith(EMERGENCY):  # the operator's reconnect ends it
            self.halted = ""
        status = self.status.fields.get("machine_status", {})
        if status.get("check_mode"):  # a reset ends GRBL's check mode
            self.status.update(machine_status={**status, "check_mode": False})
        self.hello(now)
        if not self.halted and self.reset_due is None:
            self.host.run_held_scripts()  # GRBL's abort script, after its reset

    def stop_motion_after_error(self: PrinterWorker, stream: Stream) -> None:
        """The machine runs the moves it buffered even after an error or an abort.
        GRBL: hold the feed, then reset it once held (printers/worker/emergency.py).
        Marlin with `quickstop_on_abort`: M410 ahead of everything queued, so the
        moves its planner holds (up to 16: seconds of motion) are dropped where the
        tool is; the few commands it received and has not planned yet still run,
        then the abort script. Off by default: stopping mid-move may cost steps.

        Asked twice for a firmware error (at once, and when the stream ends), it
        stops once: a second M410 could cut the abort script's homing short. A copy
        to the SD card moved nothing, and a line now would go into its file."""
        side = stream.printer_side
        if side is not None and side.exclusive:
            return
        if self.printer.is_grbl:
            hold_then_reset(self, self.clock())  # held once by its own reset_due
        elif (
            self.printer.quickstop_on_abort
            and self.transport is not None
            and self.quickstopped is not stream
        ):
            self.quickstopped = stream
            self.protocol.send_emergency("M410", self.clock())

    # -- stream host events -----------------------------------------------------

    def handle_host_events(self: PrinterWorker, now: float) -> None:
        # The queues change state only with an event (a stream started, paused,
        # resumed or ended): without one, nothing here can change the printer's.
        handled = False
        while (event := self.host.next_event()) is not None:
            self._on_host_event(event)
            handled = True
        if handled:
            self.update_state()

    def hold_or_run(self: PrinterWorker, action: Callable[[], object]) -> None:
        """Run a database write now, or hold it (in order) while the database is away.

        What the printer must do (scripts, waitstart) never waits for it: callers
        do that first and hand only the write here.
        """
        if not self.held and not self.lease.away:
            try:
                action()
                return
            except DatabaseAway:
                if not self.lease.keep_while_away:
                    raise
            except UNREACHABLE as error:
                away = self.lease.unreachable(error)
                if not self.lease.keep_while_away:
                    raise away from None
        elif not self.lease.keep_while_away:
            raise DatabaseAway(f"printer {self.printer.pk}: the database is away")
        self.held.append(action)

    def write_held_actions(self: PrinterWorker) -> None:
        """The writes held while the database was away, in order (DatabaseAway if
        it went away again: the rest stay held)."""
        while self.held:
            try:
                self.held[0]()
            except UNREACHABLE as error:
                raise self.lease.unreachable(error) from None
            self.held.pop(0)

    def _on_host_event(self: PrinterWorker, event: hv.HostEvent) -> None:
        match event:
            case hv.StreamStarted(stream=stream) if spool.is_job(stream):
                dry = " as a dry run (GRBL check mode)" if self._dry_run() else ""
                self.note(f"job {stream.ref} ({stream.name}) started{dry}")
            case hv.StreamPaused(stream=stream) if spool.is_job(stream):
                self.hold_or_run(partial(self._save_state, stream, Job.State.PAUSED))
                self.note(f"job {stream.ref} paused")
            case hv.StreamResumed(stream=stream) if spool.is_job(stream):
                self.hold_or_run(partial(self._save_state, stream, Job.State.PRINTING))
                self.note(f"job {stream.ref} resumed")
            case hv.StreamEnded(stream=stream):
                self._on_stream_end(stream)
            case hv.EspCommand(stream=stream, text=text):
                self.hold_or_run(partial(self.requests.answer_esp, stream, text))
            case hv.CommandAnswered(stream=stream, line=line, ok=ok, message=m):
                self.hold_or_run(
                    partial(self.requests.answered, stream, ok=ok, message=m)
                )
                if ok and self.grbl_alarm and _homes(line.text):
                    self._clear_alarm()  # homing found the machine's position

    def _save_state(self: PrinterWorker, stream: Stream, state: str) -> None:
        with self.lease.held():
            spool.save_progress(stream, state=state)

    def _on_stream_end(self: PrinterWorker, stream: Stream) -> None:
        if not spool.is_job(stream):
            if stream is self.start_script and stream.outcome == "failed":
                self._start_script_failed(stream)
            self.hold_or_run(partial(self.requests.ended, stream))
            return
        if stream.outcome == "completed" and self._dry_run() and not stream.message:
            stream.message = (
                "dry run in GRBL check mode: every line checked, nothing moved"
            )
        # The printer's side first (the bed, the end script), the row after: a
        # database away must not keep the heaters on or let the next job start.
        state = spool.final_state(stream)
        upload = stream.printer_side is not None and stream.printer_side.exclusive
        if not upload:  # a copy to the SD card printed nothing: no bed to clear
            self.waitstart = not self.printer.auto_start
        text = f"job {stream.ref} ({stream.name}) {state.label}"
        self.note(f"{text}: {stream.message}" if stream.message else text)
        if state == Job.State.FAILED:
            self.last_stream_error = stream.message
        if state in (Job.State.FAILED, Job.State.ABORTED):
            self.stop_motion_after_error(stream)
        if state == Job.State.COMPLETED and not upload:
            self.host.run_script("end")
        self.hold_or_run(partial(self._finish, stream, state))

    def _start_script_failed(self: PrinterWorker, script: Stream) -> None:
        """The job the script opens does not start on a machine the script did not
        set up (GRBL's error:N leaves it where it was): its first lines, offered
        in the same turn, are not written either."""
        if self.host.fail_stream(
            f"the printer's start script failed ({script.message}); the job was "
            "not started"
        ):
            self.protocol.abandon()

    def _finish(self: PrinterWorker, stream: Stream, state: Job.State) -> None:
        with self.lease.held():
            spool.finish(stream)
        self.sd.job_ended(stream, state)


def _homes(text: str) -> bool:
    """`$H` (or `$HX`...): GRBL's homing cycle, which also clears an alarm lock."""
    return text.strip().upper().startswith("$H")
