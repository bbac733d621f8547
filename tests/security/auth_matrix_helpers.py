"""The auth matrix: every endpoint with the role it needs, every kind of caller, and
what each caller should get."""

from __future__ import annotations

from dataclasses import dataclass

from printhost.models import Role

PUBLIC, VIEWER, OPERATOR, ADMIN = 0, Role.VIEWER, Role.OPERATOR, Role.ADMIN
SAFE = ("GET", "HEAD", "OPTIONS")


@dataclass(frozen=True)
class Endpoint:
    method: str
    path: str  # {stored} {done} {file} {upload} {own_key} {app_token} {user_token}
    # {entry} {running} {farm}
    role: int
    #: "p": acts on printer p (a key bound to q is refused); "any": a role anywhere
    #: will do; "unbound": a role anywhere, but a key bound to a printer is refused;
    #: "every": a role on every printer, and a key bound to a printer is refused.
    scope: str = "p"
    #: "json:{...}", "jsonf:{{...{stored}}}" (formatted like the path), "file"
    #: (multipart G-code), "raw".
    body: str = ""
    #: The printer's state the call needs: "", "printing", "paused", "waitstart",
    #: "prompt" (paused in M600, the firmware's prompt shown).
    state: str = ""
    #: A GET that changes something: only API keys may (sessions must POST).
    acts: bool = False
    #: Checked by CallerAuth (a session's unsafe call needs the CSRF token).
    csrf: bool = True
    #: Only people decide (a browser session), never a key.
    people_only: bool = False

    def __str__(self) -> str:
        return f"{self.method} {self.path}"


def ep(method: str, path: str, role: int, **options: object) -> Endpoint:
    return Endpoint(method, path, role, **options)  # type: ignore[arg-type]


PASSIVE = 'json:{"passive": true}'
ENDPOINTS = [
    # OctoPrint dialect (slicers); /p/p/ names the printer.
    ep("GET", "/api/version", PUBLIC, scope="any"),
    # A passive login reports the caller's session or key, so it needs one.
    ep("POST", "/api/login", VIEWER, scope="any", body=PASSIVE, csrf=False),
    ep("GET", "/api/server", VIEWER, scope="any"),
    ep("GET", "/api/currentuser", VIEWER, scope="any"),
    ep("GET", "/api/settings", VIEWER, scope="any"),
    ep("GET", "/p/p/api/printerprofiles", VIEWER),
    ep("GET", "/p/p/api/connection", VIEWER),
    ep("POST", "/p/p/api/connection", OPERATOR, body='json:{"command": "connect"}'),
    ep("GET", "/p/p/api/printer", VIEWER),
    ep("POST", "/p/p/api/printer/command", OPERATOR, body='json:{"commands": ["M105"]}'),
    ep("GET", "/p/p/api/printer/tool", VIEWER),
    ep("POST", "/p/p/api/printer/tool", OPERATOR, body='json:{"command": "target", "targets": {"tool0": 200}}'),
    ep("GET", "/p/p/api/printer/bed", VIEWER),
    ep("POST", "/p/p/api/printer/bed", OPERATOR, body='json:{"command": "target", "target": 60}'),
    ep("POST", "/p/p/api/printer/printhead", OPERATOR, body='json:{"command": "feedrate", "factor": 100}'),
    ep("POST", "/p/p/api/files/local", OPERATOR, body="file"),
    ep("GET", "/p/p/api/files/local/{file}", VIEWER),
    ep("GET", "/p/p/api/files", VIEWER),
    ep("GET", "/p/p/api/files/local", VIEWER),
    ep("GET", "/p/p/api/files/thumbnail/{stored}/16x16.png", VIEWER),
    ep("POST", "/p/p/api/files/local/{file}", OPERATOR, body='json:{"command": "select"}'),
    ep("GET", "/p/p/api/job", VIEWER),
    ep("POST", "/p/p/api/job", OPERATOR, body='json:{"command": "cancel"}', state="printing"),
    ep("GET", "/p/p/api/files/sdcard", VIEWER),
    ep("POST", "/p/p/api/files/sdcard", OPERATOR, body="file"),
    ep("POST", "/p/p/api/files/sdcard/CUBE.GCO", OPERATOR,
       body='json:{"command": "select", "print": true}'),
    ep("GET", "/p/p/api/printer/sd", VIEWER),
    ep("POST", "/p/p/api/printer/sd", OPERATOR, body='json:{"command": "refresh"}'),
    # Moonraker dialect.
    ep("GET", "/p/p/server/info", VIEWER),
    ep("GET", "/p/p/server/files/metadata?filename={file}", VIEWER),
    ep("GET", "/p/p/server/files/gcodes/.thumbs/{stored}/16x16.png", VIEWER),
    ep("POST", "/p/p/server/files/upload", OPERATOR, body="file"),
    ep("POST", "/p/p/printer/print/start?filename={file}", OPERATOR),
    ep("POST", "/p/p/printer/print/pause", OPERATOR, state="printing"),
    ep("POST", "/p/p/printer/print/resume", OPERATOR, state="paused"),
    ep("POST", "/p/p/printer/print/cancel", OPERATOR, state="printing"),
    ep("POST", "/p/p/printer/emergency_stop", OPERATOR),
    ep("GET", "/p/p/server/history/list", VIEWER),
    ep("GET", "/p/p/server/history/job?uid={entry}", VIEWER),
    ep("GET", "/p/p/server/history/totals", VIEWER),
    # App-key pairing (Cura) and the user's keys.
    ep("GET", "/plugin/appkeys/probe", PUBLIC, scope="any"),
    ep("POST", "/plugin/appkeys/request", PUBLIC, scope="any", body='json:{"app": "Cura"}'),
    ep("GET", "/plugin/appkeys/request/{app_token}", PUBLIC, scope="any"),
    # Everyone sees the requests that name them; operators see all.
    ep("GET", "/api/appkeys/pending", VIEWER, scope="any"),
    ep(
        "POST", "/plugin/appkeys/decision/{user_token}", OPERATOR, scope="any",
        body='json:{"decision": true}', people_only=True,
    ),
    ep("GET", "/api/keys", VIEWER, scope="any"),
    # A key bound to one printer cannot mint a key for every printer.
    ep("POST", "/api/keys", VIEWER, scope="unbound", body='json:{"name": "more"}'),
    ep("DELETE", "/api/keys/{own_key}", VIEWER, scope="any"),
    # The seed's /printer/ API and the host extras.
    ep("GET", "/printer/list", VIEWER, scope="any"),
    ep("GET", "/printer/info", VIEWER, scope="any"),
    ep("GET", "/printer/send/p?cmd=M105", OPERATOR, acts=True),
    ep("POST", "/printer/send/p?cmd=M105", OPERATOR),
    ep("GET", "/printer/response/p?start=0", VIEWER),
    ep("GET", "/printer/job/p?a=list", VIEWER),
    ep("GET", "/printer/job/p?a=pause", OPERATOR, state="printing", acts=True),
    ep("POST", "/printer/job/p?a=pause", OPERATOR, state="printing"),
    ep("GET", "/printer/job/p?a=start&id={stored}", OPERATOR, acts=True),
    ep("POST", "/printer/job/p?a=start&id={stored}", OPERATOR),
    ep("POST", "/printer/job/p?a=reprint&id={done}", OPERATOR),
    ep("GET", "/printer/job/p?a=delete&id={done}", OPERATOR, acts=True),
    ep("POST", "/printer/job/p?a=delete&id={done}", OPERATOR),
    ep("POST", "/printer/job/p?a=upload", OPERATOR, body="file"),
    ep("GET", "/printer/state/p", VIEWER),
    ep("GET", "/printer/temperatures/p", VIEWER),
    # Print history: each caller reads the printers it may view.
    ep("GET", "/printer/history", VIEWER, scope="any"),
    ep("GET", "/printer/history?format=csv", VIEWER, scope="any"),
    ep("GET", "/printer/history/totals?group=printer", VIEWER, scope="any"),
    ep("POST", "/printer/connect/p", OPERATOR),
    ep("POST", "/printer/disconnect/p", OPERATOR),
    ep("POST", "/printer/bedclear/p", OPERATOR, state="waitstart"),
    ep("POST", "/printer/emergency/p", OPERATOR),
    ep("POST", "/printer/prompt/p", OPERATOR, body='json:{"choice": 0}', state="prompt"),
    ep("POST", "/printer/queue/p", OPERATOR, body='json:{"order": []}'),
    ep("GET", "/printer/sd/p", VIEWER),
    ep("POST", "/printer/sd/p/refresh", OPERATOR),
    ep("POST", "/printer/sd/p/print", OPERATOR, body='json:{"name": "CUBE.GCO"}'),
    ep("POST", "/printer/sd/p/upload", OPERATOR, body='jsonf:{{"job": {stored}}}'),
    ep("POST", "/printer/sd/p/delete", OPERATOR, body='json:{"name": "CUBE.GCO"}'),
    ep("GET", "/printer/analysis/p/{stored}", VIEWER),
    ep("POST", "/printer/analysis/p/{stored}/again", OPERATOR),
    ep("GET", "/printer/thumbnail/p/{stored}/16x16.png", VIEWER),
    ep("GET", "/printer/toolpath/p/{stored}/0", VIEWER),
    ep("GET", "/printer/resume/p?id={stopped}", VIEWER),
    ep("GET", "/printer/resume/p?plan={plan}", VIEWER),
    ep("POST", "/printer/resume/p", OPERATOR, body='jsonf:{{"id": {stopped}}}'),
    ep("POST", "/printer/resume/p/start", OPERATOR, body='jsonf:{{"plan": {plan}}}'),
    ep("GET", "/printer/objects/p?id={stored}", VIEWER),
    ep("POST", "/printer/objects/p", OPERATOR, body='jsonf:{{"id": {running}, "object": "a"}}', state="printing"),
    ep("POST", "/printer/model/p", OPERATOR, body="file"),
    ep("GET", "/printer/api/p?a=listModelGroups", VIEWER),
    ep("POST", "/printer/api/p?a=listModelGroups", VIEWER),
    ep("GET", '/printer/api/p?a=send&data={{"cmd": "M105"}}', OPERATOR, acts=True),
    ep("POST", '/printer/api/p?a=send&data={{"cmd": "M105"}}', OPERATOR),
    ep("GET", "/printer/api/p?a=stopJob", OPERATOR, state="printing", acts=True),
    ep("POST", "/printer/api/p?a=continueJob", OPERATOR, state="paused"),
    ep("POST", "/printer/upload/p?name=a.gcode&size=5", OPERATOR),
    ep("GET", "/printer/upload/p/{upload}", OPERATOR),
    ep("HEAD", "/printer/upload/p/{upload}", OPERATOR),
    ep("PATCH", "/printer/upload/p/{upload}", OPERATOR, body="raw"),
    ep("DELETE", "/printer/upload/p/{upload}", OPERATOR),
    # The admin role.
    ep("GET", "/printer/config/p", ADMIN),
    ep("PATCH", "/printer/config/p", ADMIN, body='json:{"auto_start": true}'),
    ep("GET", "/api/users", ADMIN, scope="any"),
    ep("POST", "/api/users/viewer/role", ADMIN, scope="any", body='json:{"role": "viewer"}'),
    # The farm: a job may go to any printer, so a role on every printer, and no
    # key bound to one; what a printer has loaded is its operator's.
    ep("GET", "/printer/farm", VIEWER, scope="every"),
    ep("GET", "/printer/farm/{farm}", VIEWER, scope="every"),
    ep("PATCH", "/printer/farm/{farm}", OPERATOR, scope="every", body='json:{"priority": 3}'),
    ep("POST", "/printer/farm/{farm}/cancel", OPERATOR, scope="every"),
    ep("GET", "/printer/job/farm?a=list", VIEWER, scope="every"),
    ep("POST", "/printer/job/farm?a=upload&material=PLA", OPERATOR, scope="every", body="file"),
    ep("POST", "/p/farm/api/files/local", OPERATOR, scope="every", body="file"),
    ep("POST", "/p/farm/server/files/upload", OPERATOR, scope="every", body="file"),
    ep("POST", "/printer/loaded/p", OPERATOR, body='json:{"material": "PETG"}'),
    # Prometheus' scrape (no PRINTHOST_METRICS_TOKEN here): admins of every printer.
    ep("GET", "/metrics", ADMIN, scope="any"),
]  # fmt: skip

KEY_CALLERS = [
    "anonymous", "wrong key", "viewer", "operator", "admin", "superuser",
    "bound to q", "operator of q",
]  # fmt: skip
SESSIONS = ["session with CSRF", "session without CSRF"]
CALLERS = KEY_CALLERS + SESSIONS

#: The role each caller holds on p, and the best it holds anywhere (None: none).
HELD = {
    "viewer": (VIEWER, VIEWER),
    "operator": (OPERATOR, OPERATOR),
    "admin": (ADMIN, ADMIN),
    "superuser": (ADMIN, ADMIN),
    "bound to q": (None, OPERATOR),
    "operator of q": (None, OPERATOR),
    "session with CSRF": (OPERATOR, OPERATOR),
    "session without CSRF": (OPERATOR, OPERATOR),
}


def expected(caller: str, endpoint: Endpoint) -> str:
    if endpoint.role == PUBLIC:
        return "allowed"
    if caller in ("anonymous", "wrong key"):
        return "401"
    session = caller in SESSIONS
    if session and endpoint.acts and endpoint.method in SAFE:
        return "403"
    unsafe = endpoint.method not in SAFE
    if caller == "session without CSRF" and unsafe and endpoint.csrf:
        return "403"
    if endpoint.people_only and not session:
        return "403"
    if caller == "bound to q" and endpoint.scope in ("p", "unbound", "every"):
        return "403"
    on_p, anywhere = HELD[caller]
    held = on_p if endpoint.scope == "p" else anywhere
    every = (endpoint.role == ADMIN and endpoint.scope == "any") or (
        endpoint.scope == "every"
    )
    if every:
        held = ADMIN if caller in ("admin", "superuser") else None  # every printer
    return "allowed" if held is not None and held >= endpoint.role else "403"
