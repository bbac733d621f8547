"""The printer's own SD card, as clients ask for it: print a file from it, copy one to it.

Both become jobs in the printer's queue, spooled in order with the others: an
`sd_print` job has the printer run a file from its card (printhost watches its
progress), an `sd_upload` job writes a stored job's file onto the card (M28/M29).
Reading the listing again (M20) and deleting a file (M30) are requests for the worker.
Nothing here touches a port.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING, Any

from jobs.models import Job
from printers.models import Printer, QueuedCommand
from printers.protocol.marlin_sd import short_name
from printers.worker.spool import next_position

if TYPE_CHECKING:
    from django.contrib.auth.models import AbstractBaseUser

__all__ = [
    "BadCardName",
    "SdRefused",
    "card_files",
    "card_name",
    "card_present",
    "delete_sd_file",
    "list_sd_card",
    "queue_sd_print",
    "queue_sd_upload",
    "require_card",
]

#: What a name on the card may hold: it goes on a command line (`M23 <name>`), so no
#: blanks, no `;` (a comment), no `*` (a checksum) and no brackets (a comment to the
#: host's line cleaning and to Marlin's PAREN_COMMENTS: `M30 KEEP(1).GCO` would
#: delete KEEP.GCO).
_CARD_NAME = re.compile(r"^[A-Z0-9_~!#$%&'@^`{}.\-/]{1,100}$")


class SdRefused(ValueError):
    """The request cannot be done on this printer's card; the message says why."""


class BadCardName(SdRefused):
    """A name the card cannot hold or a command line cannot carry."""


def card_name(name: str) -> str:
    """*name* as the card knows it (upper case), or SdRefused."""
    upper = name.strip().upper()
    if not _CARD_NAME.match(upper) or ".." in upper.split("/"):
        raise BadCardName(
            f"{name!r} is not a name on the printer's SD card (letters, digits and "
            "_~!#$%&'@^`{}.-/ only, no blanks, no brackets, no '..')"
        )
    return upper


def card_files(printer: Printer) -> dict[str, dict[str, Any]]:
    """The card's files by name, as the printer last listed them (M20)."""
    files = (printer.sd_card or {}).get("files") or []
    return {str(f.get("name", "")).upper(): f for f in files if f.get("name")}


def card_present(printer: Printer) -> bool:
    """The printer's last listing found a card in it (OctoPrint's `sdReady`)."""
    return bool((printer.sd_card or {}).get("present"))


def require_card(printer: Printer) -> None:
    """SdRefused unless the printer's firmware can have an SD card (not GRBL)."""
    if printer.is_grbl:
        raise SdRefused(f"{printer.slug} runs GRBL, which has no SD card")


def queue_sd_print(
    printer: Printer,
    name: str,
    *,
    origin: str = "",
    user: AbstractBaseUser | None = None,
) -> Job:
    """Queue a job that prints *name* from the printer's card (M23, M24).

    The name need not be in the last listing (files come and go from the printer's
    display); if the printer cannot open it, the job fails with the printer's words.
    """
    require_card(printer)
    sd_name = card_name(name)
    listed = card_files(printer).get(sd_name, {})
    return Job.objects.create(
        printer=printer,
        kind=Job.Kind.SD_PRINT,
        name=str(listed.get("long_name") or sd_name),
        sd_name=sd_name,
        size_bytes=int(listed.get("size") or 0),
        position=next_position(printer.pk),
        origin=origin,
        uploaded_by=user,
    )


def queue_sd_upload(
    printer: Printer,
    source: Job,
    *,
    sd_name: str = "",
    print_after: bool = False,
    origin: str = "",
    user: AbstractBaseUser | None = None,
) -> Job:
    """Queue a job that copies *source*'s stored file onto the card (M28 ... M29).

    Without *sd_name*, an 8.3 name is made from the job's name that no listed file
    and no waiting upload has (a `.bgcode` job's copy is plain G-code: `.GCO`). With *print_after*, a print of it from the card is
    queued when the copy is complete (never after a failed or aborted copy).
    """
    require_card(printer)
    if source.printer_id != printer.pk:
        raise SdRefused(f"job {source.pk} belongs to another printer")
    if source.kind != Job.Kind.PRINT or not source.file:
        raise SdRefused(f"job {source.pk} has no stored file to copy")
    if not source.path.is_file():
        raise SdRefused(f"job {source.pk}: the stored file is gone")
    taken = set(card_files(printer)) | set(
        Job.objects.filter(
            printer=printer, kind=Job.Kind.SD_UPLOAD, state=Job.State.QUEUED
        ).values_list("sd_name", flat=True)
    )
    if sd_name:
        wanted = card_name(sd_name)
        if short_name(wanted) != wanted:
            raise BadCardName(
                f"{sd_name!r} is not an 8.3 name (up to 8 characters, a dot and up "
                "to 3): the printer's card takes only those"
            )
    else:
        # The card gets plain G-code, whatever the stored file's form.
        stem, dot, extension = source.name.rpartition(".")
        plain = (
            f"{stem}.gcode" if dot and extension.lower() == "bgcode" else source.name
        )
        wanted = short_name(plain, taken)
    return Job.objects.create(
        printer=printer,
        kind=Job.Kind.SD_UPLOAD,
        name=source.name,
        file=source.file,
        sd_name=wanted,
        print_after=print_after,
        size_bytes=source.size_bytes,
        line_count=source.line_count,
        sha256=source.sha256,
        position=next_position(printer.pk),
        origin=origin,
        uploaded_by=user,
    )


def list_sd_card(printer: Printer, *, origin: str = "") -> QueuedCommand:
    """Ask the worker to read the card's listing again (M20)."""
    require_card(printer)
    return QueuedCommand.objects.create(
        printer=printer,
        kind=QueuedCommand.Kind.ACTION,
        text=QueuedCommand.Action.SD_LIST,
        origin=origin,
    )


def delete_sd_file(printer: Printer, name: str, *, origin: str = "") -> QueuedCommand:
    """Ask the worker to delete *name* from the card (M30); it lists the card again."""
    require_card(printer)
    return QueuedCommand.objects.create(
        printer=printer,
        kind=QueuedCommand.Kind.ACTION,
        text=f"{QueuedCommand.Action.SD_DELETE}:{card_name(name)}",
        origin=origin,
    )
