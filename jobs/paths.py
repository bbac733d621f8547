"""Paths a client, a job file or a stored row names: resolved and kept in their storage.

Every file printhost reads or writes for a client ([ESP700] streams and scripts,
stored-file jobs, reprints, upload targets, a job's file read back from the
database) goes through `inside`: a name that climbs out of its folder, an absolute
name, or a symlink whose target lies elsewhere is refused before anything is opened.
"""

from __future__ import annotations

from pathlib import Path, PurePosixPath

from jobs.gcode import BadGcode


class PathRefused(BadGcode):
    """The name points outside the storage it must stay in; the message says which."""


def inside(root: Path, name: str, *, hidden: bool = False) -> Path:
    """*name* under *root*, resolved; PathRefused unless it stays inside *root*.

    1. Refuse an empty name, a NUL byte, an absolute name and `..` parts; refuse
       hidden parts (`.uploads`, staging files) unless *hidden*.
    2. Resolve *root* and *root*/*name*, following every symlink (a missing file
       is fine: only where it would be matters).
    3. The result must lie strictly below the resolved *root*.

    The message names the given *name* only, never where a symlink leads.
    """
    text = str(name)
    if not text.strip() or "\x00" in text:
        raise PathRefused(f"{text!r} is not a file name")
    parts = PurePosixPath(text).parts
    if text.startswith(("/", "\\")) or (parts and parts[0] == "/"):
        raise PathRefused(
            f"{text!r}: an absolute path; name a file inside the printer's storage"
        )
    if ".." in parts:
        raise PathRefused(f"{text!r}: '..' may not climb out of the printer's storage")
    if not hidden and any(part.startswith(".") for part in parts):
        raise PathRefused(f"{text!r}: hidden files are not job files")
    base = root.resolve()
    target = (base / text).resolve()
    if target == base or not target.is_relative_to(base):
        raise PathRefused(f"{text!r} lies outside the printer's storage")
    return target
