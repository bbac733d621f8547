"""The worker's side of the database queue: requests in, replies back to their origin."""

from __future__ import annotations

import contextlib
import logging
from functools import partial
from typing import TYPE_CHECKING

from django.db import connections
from django.db.models import Case, When

from jobs.commands import EMERGENCY_COMMANDS
from jobs.models import Job
from printers.dbclock import shared_now
from printers.models import QueuedCommand
from printers.protocol.errors import CommandRejected
from printers.streaming import Stream, StreamType, lines_from_text
from printers.streaming.objects import ObjectFilter
from printers.worker.emergency import after_m112
from printers.worker.esp_commands import EspCommands
from printers.worker.grbl_rules import refused_mid_job
from printers.worker.lease import UNREACHABLE, DatabaseAway
from printers.worker.prompts import DISPLAY_HINT

if TYPE_CHECKING:
    from django.db.models import Model

    from printers.worker.loop import PrinterWorker

logger = logging.getLogger("printhost.worker")
Kind = QueuedCommand.Kind
RowState = QueuedCommand.State

#: GRBL realtime bytes a client may type as a command.
_GRBL_REALTIME = {"!", "~", "?", "\x18", "\x85", "\x84"}
#: Marlin's emergency commands as GRBL realtime bytes: stop = feed hold + soft reset.
_GRBL_EMERGENCY = {"M112": ["!", "\x18"], "M410": ["!"]}
#: `cancel_object:<job id>`: apply the job's `cancelled_objects` to its stream
#: (written by printhost/api/objects.py).
CANCEL_OBJECT = "cancel_object"


class RequestPoller(EspCommands):
    """Reads pending QueuedCommand rows and turns them into stream-host requests."""

    def __init__(self, worker: PrinterWorker) -> None:
        self.worker = worker

    def poll(self, now: float) -> int:
        """Handle every pending request, emergencies first; returns how many.

        Each row is acted on at most once, whatever the database does meanwhile:
        an emergency goes to the port before anything is written (sent twice, it
        stops the machine twice, harmlessly), every other row is marked taken
        before it is acted on (a move or a heater must not run twice because the
        mark was lost), and what is written after an act waits while the
        database is away (`hold_or_run`).
        """
        if not self._any_pending():
            return 0
        # Emergencies first in the read itself: one behind 200 other rows waits
        # for no other turn.
        emergencies_first = Case(When(kind=Kind.EMERGENCY, then=0), default=1)
        rows = list(
            QueuedCommand.objects.filter(
                printer_id=self.worker.printer.pk, state=RowState.PENDING
            ).order_by(emergencies_first, "id")[:200]
        )
        taken = False
        for row in rows:
            if row.kind != Kind.EMERGENCY and not taken:
                self._take([r.pk for r in rows if r.kind != Kind.EMERGENCY])
                taken = True
            self._handle_once(row, now)
        return len(rows)

    def _take(self, ids: list[int]) -> None:
        """Mark the rows taken (DatabaseAway: none is; they are read again later)."""
        with self.worker.lease.held():
            QueuedCommand.objects.filter(pk__in=ids, state=RowState.PENDING).update(
                state=RowState.SENT
            )

    def _handle_once(self, row: QueuedCommand, now: float) -> None:
        """Act on a taken row; the database gone in the middle fails it, clearly.

        A row the protocol refuses is answered with why. Any other error is a
        bug: the row is answered before the worker stops, so the next worker does
        not meet it again (an emergency row is acted on before it is marked taken,
        and would stop every worker after this one too).
        """
        try:
            self._handle(row, now)
        except (DatabaseAway, *UNREACHABLE) as error:
            if not isinstance(error, DatabaseAway):
                self.worker.lease.unreachable(error)
            self._finish(
                row, "error: the database went away while this was handled; ask again"
            )
        except CommandRejected as error:
            self._finish(row, f"error: {error}")
        except Exception as error:
            with contextlib.suppress(Exception):
                self._finish(row, f"error: the worker failed on this: {error!r}")
            raise

    def fail_orphans(self, why: str) -> int:
        """Fail the printer's taken rows no stream of this worker holds; how many.

        A row is marked taken before it is acted on, so one can be left taken and
        never answered: its worker stopped first, or the database committed the
        mark and the answer was lost, so this worker never acted on it. Its client
        is told why and asks again (never sent twice: it may have run).
        """
        host = self.worker.host
        mine = {_row_id(s) for s in (*host.stream_queue, *host.script_queue)}
        orphans = QueuedCommand.objects.filter(
            printer_id=self.worker.printer.pk, state=RowState.SENT
        ).exclude(pk__in=mine - {None})
        with self.worker.lease.held():
            return orphans.update(
                state=RowState.FAILED,
                reply=f"error: {why}; ask again",
                done_at=shared_now(),
            )

    def _any_pending(self) -> bool:
        """One cheap indexed read (the pending index) before the ORM's query.

        It runs ten times a second on every printer and almost always finds
        nothing; building the ORM's query cost more than the query itself.
        """
        return any_row(QueuedCommand, self.worker.printer.pk, RowState.PENDING.value)

    def jobs_waiting(self) -> bool:
        """Whether a job of the printer is queued (one cheap indexed read).

        The idle worker asks every poll before it claims one (`claim_next`, in a
        transaction that holds the lease); almost always there is none.
        """
        return any_row(Job, self.worker.printer.pk, Job.State.QUEUED.value)

    def _handle(self, row: QueuedCommand, now: float) -> None:
        if row.kind == Kind.EMERGENCY:
            self._emergency(row, now)
        elif row.kind == Kind.ACTION:
            self._finish(row, self._action(row.text, row.origin))
        elif row.text.startswith("[ESP") and self.worker.transport is None:
            self._finish(row, self.esp(row.text, row.origin))
        elif self.worker.transport is None:
            self._finish(row, "error: printer offline")
        elif self.worker.printer.is_grbl and row.text in _GRBL_REALTIME:
            self.worker.protocol.send_emergency(row.text, now)
            self._finish(row, "ok")
        else:
            self._queue_command(row)

    def _queue_command(self, row: QueuedCommand) -> None:
        lines = lines_from_text(row.text)
        if not lines:
            self._finish(row, "error: nothing to send (only comments?)")
            return
        refused = refused_mid_job(self.worker, lines)
        if refused:
            self._finish(row, f"error: {refused}")
            return
        kind = (
            StreamType.SINGLE_COMMAND
            if len(lines) == 1
            else StreamType.MULTIPLE_COMMANDS
        )
        stream = Stream(
            kind, lines, name=row.text[:40], ref=("cmd", row.pk), origin=row.origin
        )
        self.worker.host.submit(stream)

    def _emergency(self, row: QueuedCommand, now: float) -> None:
        """Out ahead of everything: written to the port before this returns."""
        worker = self.worker
        if worker.transport is None:
            self._finish(row, "error: printer offline")
            return
        # The command word alone goes out: nothing after it rides ahead of the
        # queue, unnumbered (`M108 M29` would close a file being written).
        word = row.text.split()[0].upper() if row.text.split() else ""
        if word not in EMERGENCY_COMMANDS:
            self._finish(row, f"error: {row.text[:20]!r} is not an emergency command")
            return
        full_stop = word == "M112"
        texts = _GRBL_EMERGENCY.get(word, []) if worker.printer.is_grbl else [word]
        if not texts:
            self._finish(row, f"error: {word} has no meaning on GRBL; use M112 or M410")
            return
        for text in texts:
            worker.protocol.send_emergency(text, now)
        worker.pump(now)
        if worker.transport is None:  # the write failed: port_lost stopped the job
            self._finish(
                row, f"error: {word} was not written: the port went away; the "
                "machine may still be moving: cut its power",
            )  # fmt: skip
            return
        path = ""
        if full_stop:
            who = f" by {row.origin}" if row.origin else ""
            path = after_m112(worker, who)
            worker.stop_streams(f"emergency stop{who}", outcome="aborted", note=True)
        alone = "" if row.text.strip().upper() == word else f"{word} sent alone"
        said = "; ".join(part for part in (alone, path) if part)
        self._finish(row, f"ok: {said}" if said else "ok")

    def _action(self, action: str, origin: str) -> str:
        worker = self.worker
        host = worker.host
        who = f" by {origin}" if origin else ""
        if action.startswith(f"{QueuedCommand.Action.PROMPT}:"):
            return self._answer_prompt(action.partition(":")[2], who)
        if action.startswith(f"{QueuedCommand.Action.SD_DELETE}:"):
            error = worker.sd.delete(action.partition(":")[2])
            return f"error: {error}" if error else "ok"
        if action.startswith(f"{CANCEL_OBJECT}:"):
            return self._cancel_objects(action.partition(":")[2], who)
        match action:
            case QueuedCommand.Action.PAUSE:
                error = host.request_pause()
            case QueuedCommand.Action.RESUME:
                error = host.request_resume()
            case QueuedCommand.Action.ABORT:
                error = host.request_abort(f"aborted{who}")
            case QueuedCommand.Action.BED_CLEAR:
                worker.waitstart, error = False, ""
            case QueuedCommand.Action.RECONNECT:
                worker.stay_offline, worker.next_connect = False, 0.0
                worker.halted = ""  # an emergency stop's halt ends only here
                worker.disconnect(f"reconnect asked{who}")
                error = ""
            case QueuedCommand.Action.SD_LIST:
                error = worker.sd.list_card()
            case QueuedCommand.Action.DISCONNECT:
                worker.stay_offline = True
                worker.disconnect(f"disconnected{who}")
                error = ""
            case _:
                error = f"unknown action {action!r}"
        worker.update_state()
        return f"error: {error}" if error else "ok"

    def _cancel_objects(self, job_id: str, who: str) -> str:
        """Cancel the objects the job's row names, in its running stream.

        1. Find the job's stream and its object filter (none: the job is not
           streaming; the row keeps the intent, nothing else happens).
        2. For each newly cancelled object: if the firmware cancels objects itself
           (`firmware_cancels`) and the file numbered it with `M486 S`, send
           `M486 P<n>` ahead of the stream (the script queue); else the filter
           skips its extrusion from the next line it reads.
        """
        worker = self.worker
        stream = worker.host.current_stream
        objects = stream.lines if stream is not None else None
        if stream is None or str(stream.ref) != job_id:
            return "error: the job is not streaming"
        if not isinstance(objects, ObjectFilter):
            return "error: the job's stream reads no objects"
        wanted = Job.objects.filter(pk=stream.ref).values_list(
            "cancelled_objects", flat=True
        )
        firmware = firmware_cancels(worker.status.fields)
        done = []
        for name in wanted.first() or []:
            if name in objects.cancelled or name in objects.firmware_cancelled:
                continue
            number = objects.m486_ids.get(name)
            if firmware and number is not None:
                objects.firmware_cancelled.add(name)
                worker.submit_internal(f"M486 P{number}")
                done.append(f"{name} (M486 P{number})")
            else:
                objects.cancel(name)
                done.append(f"{name} (skipped by the host)")
        if done:
            worker.note(f"job {job_id}: cancelled {', '.join(done)}{who}")
        return "ok"

    def _answer_prompt(self, choice: str, who: str) -> str:
        """M876 S<n> for the shown host prompt, out of band like M112.

        Marlin's EMERGENCY_PARSER catches M876 even while the firmware is blocked
        in M600's wait loop; a line queued behind the job would never get there.
        """
        worker = self.worker
        if worker.transport is None:
            return "error: printer offline"
        try:
            command = worker.prompts.answer(int(choice))
        except ValueError as error:  # PromptError is a ValueError
            return f"error: {error}"
        now = worker.clock()
        worker.protocol.send_emergency(command, now)
        worker.pump(now)
        worker.note(f"answered the printer's prompt with {command}{who}")
        worker.update_state()
        if worker.emergency_parser is not True:
            return f"ok: {command} sent; {DISPLAY_HINT}"
        return f"ok: {command} sent"

    # -- replies ------------------------------------------------------------------

    def answered(self, stream: Stream, *, ok: bool, message: str) -> None:
        """A single command got its ok, or was refused."""
        if _row_id(stream) is not None and stream.type is StreamType.SINGLE_COMMAND:
            self._finish_id(_row_id(stream), "ok" if ok else f"error: {message}")

    def ended(self, stream: Stream) -> None:
        """A script stream left the queue: close its request row."""
        row_id = _row_id(stream)
        if row_id is None:
            if stream.outcome == "failed":
                self.worker.note(f"{stream.name}: {stream.message}")
            return
        reply = "ok" if stream.outcome == "completed" else f"error: {stream.message}"
        QueuedCommand.objects.filter(pk=row_id, state=RowState.SENT).update(
            state=RowState.DONE if reply == "ok" else RowState.FAILED,
            reply=reply,
            done_at=shared_now(),
        )

    def answer_esp(self, stream: Stream, text: str) -> None:
        """An [ESPxxx] line was read from a stream: answer it to its origin."""
        reply = self.esp(text, stream.origin, within=stream)
        row_id = _row_id(stream)
        if row_id is not None:
            self._finish_id(row_id, reply)

    def _finish(self, row: QueuedCommand, reply: str) -> None:
        """Reply to a request just handled (held while the database is away)."""
        self.worker.hold_or_run(partial(self._finish_id, row.pk, reply))

    def _finish_id(self, row_id: int, reply: str) -> None:
        failed = reply.startswith("error")
        QueuedCommand.objects.filter(pk=row_id).update(
            state=RowState.FAILED if failed else RowState.DONE,
            reply=reply,
            done_at=shared_now(),
        )


def any_row(model: type[Model], printer_id: int, state: str) -> bool:
    """Whether *model* has a row of the printer in *state*: one read, no ORM query.

    The state is written into the statement (a constant of ours, never input): a
    planner matches a partial index's condition (`state = 'pending'`, `state =
    'queued'`) against literals, not bound parameters.
    """
    connection = connections[model.objects.db]
    table = connection.ops.quote_name(model._meta.db_table)
    if not state.isidentifier():
        raise ValueError(f"not a state: {state!r}")
    with connection.cursor() as cursor:
        cursor.execute(
            f"SELECT 1 FROM {table} WHERE printer_id = %s AND state = '{state}' LIMIT 1",
            [printer_id],
        )
        return cursor.fetchone() is not None


def firmware_cancels(fields: dict[str, object]) -> bool:
    """Whether the connected firmware cancels objects itself (M486 P).

    Marlin's M115 reports no capability for CANCEL_OBJECTS (a build option, off by
    default), so a Marlin build is trusted only if it says `Cap:CANCEL_OBJECTS:1`
    (the simulator's `--cancel-objects`, a fork that adds the line);
    RepRapFirmware always has M486. Anything else: the host skips the lines.
    """
    caps = fields.get("capabilities")
    if isinstance(caps, dict) and caps.get("CANCEL_OBJECTS") is True:
        return True
    return "reprapfirmware" in str(fields.get("firmware_name", "")).lower()


def _row_id(stream: Stream) -> int | None:
    ref = stream.ref
    if isinstance(ref, tuple) and len(ref) == 2 and ref[0] == "cmd":
        return int(ref[1])
    return None
