"""What a request body may be before the application sees it: the one list of upload
routes, their size caps, who may send one, and how many at once.

`printhost.serve` asks these questions while a request's headers are in and its body
is not (or only its first bytes are): a body over its cap is refused with 413 as soon
as the cap is crossed (at once when Content-Length says so), an upload without a
valid API key or session gets 401 before its body is read (`Expect: 100-continue` is
answered only after the check), one from a user who may upload nowhere (no operator
role) gets 403 once it is larger than a body that is not an upload, one that would
not fit in the job storage gets 507, and a user with `PRINTHOST_UPLOADS_PER_CALLER`
uploads in flight gets 429.

No Twisted here: the server feeds plain values (method, target, headers) in.
"""

from __future__ import annotations

import re
import shutil
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING
from urllib.parse import parse_qs, urlsplit

from django.conf import settings

if TYPE_CHECKING:
    from django.contrib.sessions.backends.base import SessionBase

#: Every route that takes a job file in its body: (method, path pattern). The
#: dialects' `/p/<slug>` aliases are matched after that prefix is taken off.
UPLOAD_ROUTES: tuple[tuple[str, re.Pattern[str]], ...] = (
    # The seed's jobs call: `a=upload` (multipart) and `a=append` (raw chunk);
    # `a` may sit in the multipart body, so every POST counts.
    ("POST", re.compile(r"/printer/job/[^/]+/?")),
    # Repetier host type (PrusaSlicer, Cura): a model stored, not queued.
    ("POST", re.compile(r"/printer/model/[^/]+/?")),
    # Resumable uploads: each PATCH appends its body.
    ("PATCH", re.compile(r"/printer/upload/[^/]+/[^/]+/?")),
    # OctoPrint (PrusaSlicer, OrcaSlicer, Cura's plugin).
    ("POST", re.compile(r"/api/files/(?:local|sdcard)/?")),
    # Moonraker (PrusaSlicer, OrcaSlicer).
    ("POST", re.compile(r"/server/files/upload/?")),
)
_DIALECT_ALIAS = re.compile(r"/p/[^/]+(?=/)")
#: Query parameters and cookies whose values are credentials.
CREDENTIAL_PARAMS = ("apikey", "token")


def is_upload(method: str, target: str) -> bool:
    """Whether *method* on *target* (path and query) is one of UPLOAD_ROUTES."""
    path = urlsplit(target).path
    path = _DIALECT_ALIAS.sub("", path, count=1) if path.startswith("/p/") else path
    method = method.upper()
    return any(m == method and p.fullmatch(path) for m, p in UPLOAD_ROUTES)


def body_cap(*, upload: bool) -> int:
    """The largest body a request may send: a job file, or a small form/JSON body."""
    if upload:
        return int(settings.PRINTHOST_MAX_JOB_BYTES)
    return int(settings.PRINTHOST_MAX_BODY_BYTES)


def too_large(*, upload: bool) -> str:
    """The 413 message: the cap, and the setting that sets it."""
    setting = "PRINTHOST_MAX_JOB_BYTES" if upload else "PRINTHOST_MAX_BODY_BYTES"
    what = "job file" if upload else "request body (not an upload)"
    return f"{what} larger than {body_cap(upload=upload)} bytes ({setting})"


def free_bytes(folder: Path) -> int:
    """Free space on the file system that holds *folder* (or its nearest parent)."""
    while not folder.exists() and folder.parent != folder:
        folder = folder.parent
    return shutil.disk_usage(folder).free


def storage_refusal(size: int) -> str:
    """Why an upload of *size* bytes would not fit in the job storage ("" if it fits)."""
    spare = int(settings.PRINTHOST_UPLOAD_SPARE_BYTES)
    free = free_bytes(Path(settings.JOB_STORAGE_DIR))
    if size + spare > free and not size:
        return (
            f"not enough space for uploads: {spare} bytes spare wanted, {free} free "
            "in the job storage"
        )
    if size + spare > free:
        return (
            f"not enough space for this upload: {size} bytes plus {spare} spare "
            f"wanted, {free} free in the job storage"
        )
    return ""


@dataclass(frozen=True)
class Credentials:
    """What a request's headers offer as proof of who sends it."""

    key: str | None
    session: str | None

    @property
    def given(self) -> bool:
        return bool(self.key or self.session)


def credentials(
    target: str, headers: dict[str, str], cookies: dict[str, str]
) -> Credentials:
    """The API key (X-Api-Key, Bearer, ?apikey=/?token=) or session cookie, like
    `printhost.access.key_from_request` reads them; *headers* have lower-case names."""
    key = (headers.get("x-api-key") or "").strip() or None
    if key is None:
        scheme, _, value = headers.get("authorization", "").partition(" ")
        if scheme.lower() == "bearer" and value.strip():
            key = value.strip()
    if key is None:
        query = parse_qs(urlsplit(target).query)
        for name in CREDENTIAL_PARAMS:
            values = [v.strip() for v in query.get(name, []) if v.strip()]
            if values:
                key = values[0]
                break
    session = cookies.get(settings.SESSION_COOKIE_NAME) or None
    return Credentials(key=key, session=session)


@dataclass(frozen=True)
class Uploader:
    """Who sends an upload, as far as the gate can tell before its body."""

    #: "user:<id>" (the upload slots' name for them), or None: nobody active.
    who: str | None
    #: They hold the operator role on some printer (within their key's).
    #: Which printer, or the farm, the view decides once the body is in; one
    #: who may upload nowhere may send no more than a body that is not an upload.
    operator: bool = False


def uploader(given: Credentials) -> Uploader:
    """Who *given* names, and whether they may upload anywhere.

    A key that matches nobody is refused even with a session, as the API does.
    Reads the database: call it from a thread (`database_sync_to_async`).
    """
    from importlib import import_module

    from django.contrib.auth import SESSION_KEY, get_user_model

    from printhost.access import Caller, find_key
    from printhost.models import Role

    if given.key is not None:
        key = find_key(given.key)
        if key is None:
            return Uploader(None)
        caller = Caller(client="upload", user=key.user, key=key)
    elif given.session:
        engine = import_module(settings.SESSION_ENGINE)
        store: SessionBase = engine.SessionStore(session_key=given.session)
        user_id = store.load().get(SESSION_KEY)
        user = get_user_model().objects.filter(pk=user_id, is_active=True).first()
        if user is None:
            return Uploader(None)
        caller = Caller(client="upload", user=user)
    else:
        return Uploader(None)
    # The views' own reckoning (the key's printer and role, the user's roles).
    operator = bool(caller.printers(Role.OPERATOR, fields=("id",)))
    return Uploader(f"user:{caller.user.pk}", operator)


class UploadSlots:
    """Uploads in flight per uploader, at most `PRINTHOST_UPLOADS_PER_CALLER` each."""

    def __init__(self) -> None:
        self._held: dict[str, int] = {}
        self._lock = threading.Lock()

    def take(self, who: str) -> bool:
        """Hold one slot for *who*; False when all theirs are taken."""
        limit = int(settings.PRINTHOST_UPLOADS_PER_CALLER)
        with self._lock:
            if self._held.get(who, 0) >= limit:
                return False
            self._held[who] = self._held.get(who, 0) + 1
            return True

    def give_back(self, who: str) -> None:
        with self._lock:
            left = self._held.get(who, 0) - 1
            if left > 0:
                self._held[who] = left
            else:
                self._held.pop(who, None)

    def busy(self) -> str:
        limit = int(settings.PRINTHOST_UPLOADS_PER_CALLER)
        return (
            f"too many uploads at once: at most {limit} per user; wait for one to end"
        )


#: The serving process's slots (one daphne process serves every upload).
SLOTS = UploadSlots()
