"""What clients may ask of a printer: validate, write the intent to the database, return.

The printer's worker picks the rows up; nothing here touches a port.
"""

from __future__ import annotations

import re
import shutil
import uuid
from pathlib import Path

from django.conf import settings
from django.db import transaction

from jobs.gcode import BadGcode, FileFacts, inspect_file
from jobs.models import Job
from printers.driver import LinkConfig
from printers.models import Printer, QueuedCommand
from printers.worker.spool import next_position

_SAFE_NAME = re.compile(r"[^A-Za-z0-9._ -]+")
#: Commands that must skip every queue (Marlin's emergency parser set).
EMERGENCY_COMMANDS = frozenset({"M112", "M108", "M410"})


def storage_dir(printer: Printer) -> Path:
    """The printer's job storage (`/sd/` and `/fs/` of [ESP700])."""
    path = Path(settings.JOB_STORAGE_DIR) / printer.slug
    path.mkdir(parents=True, exist_ok=True)
    return path


def safe_name(name: str) -> str:
    """A file name that cannot climb out of the storage folder."""
    cleaned = _SAFE_NAME.sub("_", Path(name).name).strip(" .")
    if not cleaned:
        raise BadGcode(f"{name!r} is not a usable file name")
    return cleaned


def enqueue_job(
    printer: Printer, source: Path, *, name: str = "", origin: str = ""
) -> Job:
    """Check *source*, copy it into the printer's storage and queue a job for it.

    1. Inspect the file (binary, empty, too-long lines -> BadGcode) before storing.
    2. Copy it beside the other jobs under a unique name (never overwrite one).
    3. Create the job at the end of the printer's queue.
    """
    name = safe_name(name or source.name)
    limit = LinkConfig.from_printer(printer).command_limit
    size = source.stat().st_size if source.is_file() else 0
    if size > settings.PRINTHOST_MAX_JOB_BYTES:
        raise BadGcode(
            f"{name}: {size} bytes is over the limit of "
            f"{settings.PRINTHOST_MAX_JOB_BYTES} bytes"
        )
    facts = inspect_file(source, max_command_length=limit)
    target = storage_dir(printer) / f"{uuid.uuid4().hex[:8]}-{name}"
    shutil.copyfile(source, target)
    return _create_job(printer, target, name, facts, origin)


def queue_stored_file(printer: Printer, stored_name: str, *, origin: str = "") -> Job:
    """Queue a file already in the printer's storage ([ESP700]stream=/sd/...)."""
    path = storage_dir(printer) / safe_name(stored_name)
    limit = LinkConfig.from_printer(printer).command_limit
    facts = inspect_file(path, max_command_length=limit)
    return _create_job(printer, path, path.name, facts, origin)


def _create_job(
    printer: Printer, path: Path, name: str, facts: FileFacts, origin: str
) -> Job:
    relative = path.relative_to(Path(settings.JOB_STORAGE_DIR))
    with transaction.atomic():
        return Job.objects.create(
            printer=printer,
            name=name,
            file=str(relative),
            size_bytes=facts.size_bytes,
            line_count=facts.line_count,
            sha256=facts.sha256,
            position=next_position(printer.pk),
            origin=origin,
        )


def send_command(printer: Printer, text: str, *, origin: str = "") -> QueuedCommand:
    """Queue a command (or several lines) for the printer; emergencies skip the queue."""
    text = text.strip()
    if not text:
        raise ValueError("empty command")
    if "\x00" in text:
        raise ValueError("a command cannot hold a NUL byte")
    word = text.split()[0].upper() if text.split() else ""
    kind = (
        QueuedCommand.Kind.EMERGENCY
        if word in EMERGENCY_COMMANDS and "\n" not in text
        else QueuedCommand.Kind.COMMAND
    )
    return QueuedCommand.objects.create(
        printer=printer, kind=kind, text=text, origin=origin
    )


def emergency_stop(printer: Printer, *, origin: str = "") -> QueuedCommand:
    """Stop the machine now: M112 (Marlin) or feed hold + soft reset (GRBL)."""
    return QueuedCommand.objects.create(
        printer=printer, kind=QueuedCommand.Kind.EMERGENCY, text="M112", origin=origin
    )


def request_action(printer: Printer, action: str, *, origin: str = "") -> QueuedCommand:
    """Ask the worker to pause, resume, abort, accept a clear bed or reconnect."""
    if action not in QueuedCommand.Action.values:
        raise ValueError(
            f"unknown action {action!r}; use one of {', '.join(QueuedCommand.Action.values)}"
        )
    return QueuedCommand.objects.create(
        printer=printer, kind=QueuedCommand.Kind.ACTION, text=action, origin=origin
    )
