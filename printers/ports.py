"""Which ports a printer may name, checked before any is stored or opened.

pyserial's `serial_for_url` opens far more than serial ports: `spy://...?file=`
writes a file, `loop://` and `hwgrep://` are no machine, `socket://` reaches any TCP
service (Redis, PostgreSQL). A printer's port may only be

- a device path: `/dev/tty*`, `/dev/cu.*`, `/dev/serial/by-id/*`,
  `/dev/serial/by-path/*`;
- a pty or link under the data directory (`PRINTHOST_DATA_DIR`), where the
  simulators put theirs;
- `socket://host:port` or `rfc2217://host:port` for a pair listed in
  `PRINTHOST_PORT_HOSTS` (empty by default; runhost's simulators use pty links in
  the data directory, a simulator on `--tcp` needs its address listed).

A path that exists must lead (symlinks followed) to a serial character device: a
link in the data directory to a regular file is refused too.
"""

from __future__ import annotations

import os
import re
import shlex
import stat
from pathlib import Path
from typing import TYPE_CHECKING
from urllib.parse import urlsplit

if TYPE_CHECKING:
    from collections.abc import Iterable

#: Device paths a port may name directly (after normalisation).
_DEVICE = re.compile(r"^/dev/(tty[^/]+|cu\.[^/]+|serial/by-(id|path)/[^/]+)$")
#: Where a port path may lead once symlinks are followed (ptys are /dev/pts/N).
_SERIAL_TARGET = re.compile(r"^/dev/(tty[^/]*|cu\.[^/]+|pts/\d+|rfcomm\d+)$")
_NETWORK = ("socket", "rfc2217")


class PortRefused(ValueError):
    """The port is not one a printer may use; the message says why and what is."""


def check_port(
    port: str,
    *,
    data_dir: Path,
    hosts: Iterable[str] = (),
) -> None:
    """Raise PortRefused unless *port* is a device path or an allowed TCP address.

    *hosts* are the `host:port` pairs `PRINTHOST_PORT_HOSTS` lists.
    """
    if not port or port != port.strip() or any(ord(c) < 32 for c in port):
        raise PortRefused(f"{port!r}: give a device path such as /dev/ttyUSB0")
    if "://" in port:
        _check_url(port, hosts=hosts)
    else:
        _check_path(port, data_dir=data_dir)


def _check_url(port: str, *, hosts: Iterable[str]) -> None:
    scheme = port.split("://", 1)[0].lower()
    if scheme not in _NETWORK:
        raise PortRefused(
            f"{port!r}: {scheme}:// ports are not allowed; use a device path, "
            "socket://host:port or rfc2217://host:port"
        )
    parts = urlsplit(port)
    if parts.query or parts.fragment or parts.path not in ("", "/") or "@" in port:
        raise PortRefused(f"{port!r}: only {scheme}://host:port, with no options")
    try:
        host, number = parts.hostname, parts.port
    except ValueError:
        host, number = None, None
    if not host or number is None:
        raise PortRefused(f"{port!r}: expected {scheme}://host:port")
    address = _address(host, number)
    allowed = {_normal(entry) for entry in hosts}
    if address in allowed:
        return
    raise PortRefused(
        f"{port!r}: {address} is not in PRINTHOST_PORT_HOSTS "
        f"(allowed: {', '.join(sorted(allowed)) or 'none'})"
    )


def _check_path(port: str, *, data_dir: Path) -> None:
    if not port.startswith("/"):
        raise PortRefused(f"{port!r}: give an absolute device path (/dev/ttyUSB0)")
    normal = os.path.normpath(port)
    in_data = any(
        Path(normal).is_relative_to(root) and Path(normal) != root
        for root in (data_dir.absolute(), data_dir.resolve())
    )
    if not (_DEVICE.match(normal) or in_data):
        raise PortRefused(
            f"{port!r}: not a serial device path; use /dev/tty*, "
            "/dev/serial/by-id/* or /dev/serial/by-path/* (or a simulator's link "
            "in the data directory)"
        )
    target = Path(normal)
    if not (target.exists() or target.is_symlink()):
        return  # unplugged, or the simulator has not started yet
    resolved = target.resolve()
    try:
        mode = resolved.stat().st_mode
    except OSError:
        return  # a dangling link: opening it fails with its own message
    if not (stat.S_ISCHR(mode) and _SERIAL_TARGET.match(str(resolved))):
        raise PortRefused(f"{port!r}: not a serial device (it leads elsewhere)")


def _address(host: str, number: int) -> str:
    host = host.lower()
    return f"[{host}]:{number}" if ":" in host else f"{host}:{number}"


def _normal(entry: str) -> str:
    host, _, number = entry.strip().lower().rpartition(":")
    return _address(host.strip("[]"), int(number)) if number.isdigit() else entry


def simulator_paths_outside(simulator: str, *, data_dir: Path) -> list[str]:
    """The file options of simulator arguments (--record, --link, --control,
    --sd-dir) that would write outside *data_dir*; [] when all stay inside."""
    try:
        words = shlex.split(simulator)
    except ValueError as error:
        return [f"unreadable arguments: {error}"]
    data = data_dir.resolve()
    outside = []
    for index, word in enumerate(words):
        name, _, value = word.partition("=")
        if name not in ("--record", "--link", "--control", "--sd-dir"):
            continue
        if not value and index + 1 < len(words):
            value = words[index + 1]
        path = Path(value)
        if not path.is_absolute():
            outside.append(f"{name} {value} (give an absolute path)")
            continue
        # The simulator replaces its --link, so only where the link sits matters;
        # --record, --control and --sd-dir are opened, so follow their symlinks.
        lexical = Path(os.path.normpath(path))
        resolved = lexical if name == "--link" else path.resolve()
        if not resolved.is_relative_to(data) or resolved == data:
            outside.append(f"{name} {value}")
    return outside


def check_configured_port(port: str) -> None:
    """`check_port` with this installation's data directory and host list."""
    from django.conf import settings

    check_port(
        port,
        data_dir=Path(settings.DATA_DIR),
        hosts=getattr(settings, "PRINTHOST_PORT_HOSTS", ()),
    )
