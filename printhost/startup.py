"""Checks the web server makes before it listens; each failure says what to fix.

- `printhost.serve` patches daphne and Twisted internals (see that module); a Twisted
  or daphne that no longer has one of them must stop the server at start-up, not
  leave an upload path quietly unprotected (`missing_internals`).
- The development secret key signs sessions anyone can forge with the public source;
  it is refused unless DEBUG is on or every bind is loopback (`secret_key_refusal`).
"""

from __future__ import annotations

import inspect
import ipaddress
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Iterable

#: The secret key `printhost/settings.py` falls back to without PRINTHOST_SECRET_KEY.
DEVELOPMENT_SECRET_KEY = "printhost-insecure-development-key-change-me"
_LOOPBACK_NAMES = {"localhost", "localhost.localdomain", "ip6-localhost"}


@dataclass(frozen=True)
class Internal:
    """One attribute of another project's code that printhost relies on.

    An attribute set on instances (not visible on the class) is named with the
    method that assigns it (`set_in`): its source must still assign it.
    """

    owner: object
    name: str
    set_in: str = ""

    @property
    def label(self) -> str:
        owner = getattr(self.owner, "__qualname__", None) or getattr(
            self.owner, "__name__", repr(self.owner)
        )
        module = getattr(self.owner, "__module__", None)
        where = f"{module}.{owner}" if module and module != owner else owner
        return f"{where}.{self.name}" + (
            f" (set in {self.set_in})" if self.set_in else ""
        )

    def present(self) -> bool:
        if not self.set_in:
            return hasattr(self.owner, self.name)
        try:
            source = inspect.getsource(getattr(self.owner, self.set_in))
        except (AttributeError, OSError, TypeError):
            return False
        pattern = rf"self\.{re.escape(self.name)}\s*(:[^=\n]+)?=[^=]"
        return re.search(pattern, source) is not None


def missing_internals(internals: Iterable[Internal]) -> list[str]:
    """The labels of the internals that are gone."""
    return [internal.label for internal in internals if not internal.present()]


def internals_refusal(internals: Iterable[Internal], versions: str) -> str:
    """Why the server must not start with these internals ("" when all are there)."""
    missing = missing_internals(internals)
    if not missing:
        return ""
    return (
        "printhost.serve cannot protect uploads with the installed "
        f"{versions}: missing {', '.join(missing)}. Install the versions pinned in "
        "requirements.txt."
    )


def is_loopback(host: str) -> bool:
    """Whether *host* (an address or a name) is only reachable from this machine."""
    host = host.strip().strip("[]").lower()
    if host in _LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def endpoint_is_local(endpoint: str) -> bool:
    """Whether a Twisted endpoint string (daphne `-e`) listens only locally."""
    kind, _, rest = endpoint.partition(":")
    if kind == "unix":
        return True
    if kind in ("tcp", "tcp6", "ssl"):
        options = dict(part.split("=", 1) for part in rest.split(":") if "=" in part)
        interface = options.get("interface", "").replace("\\:", ":")
        return bool(interface) and is_loopback(interface)
    return False


def secret_key_refusal(
    *, secret_key: str, debug: bool, hosts: Iterable[str], endpoints: Iterable[str] = ()
) -> str:
    """Why serving with *secret_key* is refused ("" when it is fine).

    The development key is public: sessions and CSRF tokens signed with it can be
    forged by anyone, so it may only serve loopback binds (the demo, the tests) or
    DEBUG.
    """
    if debug or secret_key != DEVELOPMENT_SECRET_KEY:
        return ""
    exposed = [h for h in hosts if not is_loopback(h)]
    exposed += [e for e in endpoints if not endpoint_is_local(e)]
    if not exposed:
        return ""
    return (
        "refusing to serve on "
        f"{', '.join(exposed)} with the development secret key: set "
        'PRINTHOST_SECRET_KEY to a long random value (e.g. `python -c "import '
        'secrets; print(secrets.token_urlsafe(50))"`), or bind to 127.0.0.1'
    )
