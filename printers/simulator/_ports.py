"""The simulator's endpoints: a pty behind a symlink, one TCP client, the control socket.

The TCP port also speaks RFC 2217 (serial over telnet) to a client that opens with a
telnet command (`rfc2217://` in pyserial), so a host can drive the modem lines: a
DTR pulse resets the board, as it does on the usual USB boards (Arduino Mega/RAMPS
and most others). A plain `socket://` client never sends 0xFF first, so it gets raw
bytes as before.
"""

from __future__ import annotations

import contextlib
import os
import socket
import tty
from typing import TYPE_CHECKING

from serial.rfc2217 import IAC, PortManager

if TYPE_CHECKING:
    from pathlib import Path

__all__ = ["ControlServer", "PtyPort", "SetupError", "TcpPort"]

#: Bytes kept for a reader that does not read; past this, output is lost as a
#: serial port's would be.
MAX_PENDING = 1 << 20
READ_SIZE = 65536


class SetupError(Exception):
    """A port could not be set up (bad path, address in use); the message says why."""


class _Stream:
    """Non-blocking writes with a pending buffer, shared by the pty and TCP ports."""

    def __init__(self) -> None:
        self.pending = bytearray()
        self.lost = 0

    def queue(self, data: bytes) -> None:
        room = MAX_PENDING - len(self.pending)
        if len(data) > room:
            self.lost += len(data) - room
            data = data[:room]
        self.pending += data

    def _write_to(self, write: object) -> None:
        while self.pending:
            try:
                sent = write(self.pending)  # type: ignore[operator]
            except (BlockingIOError, InterruptedError):
                return
            del self.pending[:sent]


class PtyPort(_Stream):
    """A pty whose slave side is reachable at *link*; we keep the slave open too,
    so a host may close and reopen the port without the master seeing a hangup."""

    def __init__(self, link: Path) -> None:
        super().__init__()
        self.link = link
        self.master: int | None = None
        self._slave: int | None = None
        self.name = ""

    def open(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        self.master, self._slave, self.name = master, slave, os.ttyname(slave)
        try:
            _replace_link(self.link, self.name)
        except SetupError:
            self.close()
            raise

    def close(self) -> None:
        with contextlib.suppress(OSError):
            if self.link.is_symlink() and str(self.link.readlink()) == self.name:
                self.link.unlink()
        for fd in (self.master, self._slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self.master = self._slave = None
        self.pending.clear()

    def read(self) -> bytes:
        try:
            return os.read(self.master, READ_SIZE)  # type: ignore[arg-type]
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError:  # EIO while no one holds the slave: nothing to read
            return b""

    def flush(self) -> None:
        self._write_to(lambda data: os.write(self.master, data))  # type: ignore[arg-type]


def _replace_link(link: Path, target: str) -> None:
    if link.is_symlink():
        link.unlink()
    elif link.exists():
        raise SetupError(f"{link}: exists and is not a symlink; not replacing it")
    try:
        link.symlink_to(target)
    except OSError as error:
        raise SetupError(f"{link}: cannot create the link: {error.strerror}") from None


class _ModemLines:
    """The serial port PortManager drives: settings are kept, DTR pulses counted."""

    def __init__(self) -> None:
        self.baudrate, self.bytesize, self.parity, self.stopbits = 115200, 8, "N", 1
        self.xonxoff = self.rtscts = self.break_condition = False
        self.rts = True
        self.cts = self.dsr = self.ri = self.cd = False
        self._dtr = True
        self.resets = 0

    @property
    def dtr(self) -> bool:
        return self._dtr

    @dtr.setter
    def dtr(self, value: bool) -> None:
        """DTR asserted after it was dropped: the auto-reset capacitor resets the MCU."""
        if value and not self._dtr:
            self.resets += 1
        self._dtr = value

    def reset_input_buffer(self) -> None:
        pass

    def reset_output_buffer(self) -> None:
        pass


class _Raw:
    """PortManager's telnet answers go out unescaped, in order with the data."""

    def __init__(self, port: TcpPort) -> None:
        self.port = port

    def write(self, data: bytes) -> None:
        _Stream.queue(self.port, data)


class TcpPort(_Stream):
    """A TCP listener serving one client at a time; a new client replaces the old.

    A client whose first byte is telnet's IAC gets RFC 2217 (see the module doc).
    """

    def __init__(self, host: str, port: int) -> None:
        super().__init__()
        try:
            self.listener = socket.create_server((host, port), reuse_port=False)
        except OSError as error:
            raise SetupError(f"tcp {host}:{port}: {error.strerror}") from None
        self.listener.settimeout(0.0)
        self.client: socket.socket | None = None
        self.accepting = True
        self._first = True
        self._lines: _ModemLines | None = None
        self._rfc2217: PortManager | None = None

    @property
    def address(self) -> str:
        host, port = self.listener.getsockname()[:2]
        return f"{host}:{port}"

    def accept(self) -> socket.socket | None:
        """Take a waiting connection; returns the client it replaced (to unregister)."""
        try:
            client, _ = self.listener.accept()
        except (BlockingIOError, InterruptedError):
            return None
        if not self.accepting:
            client.close()
            return None
        old = self.client
        self.drop_client()
        client.settimeout(0.0)
        client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.client = client
        return old

    def drop_client(self) -> None:
        if self.client is not None:
            self.client.close()
        self.client = None
        self.pending.clear()
        self._first, self._lines, self._rfc2217 = True, None, None

    def queue(self, data: bytes) -> None:
        if self._rfc2217 is not None:
            data = b"".join(self._rfc2217.escape(data))
        super().queue(data)

    def take_dtr_reset(self) -> bool:
        """True once for each DTR pulse the RFC 2217 client made (the board resets)."""
        if self._lines is None or not self._lines.resets:
            return False
        self._lines.resets -= 1
        return True

    def _filter(self, data: bytes) -> bytes:
        if self._first:
            self._first = False
            if data[:1] == IAC:
                self._lines = _ModemLines()
                self._rfc2217 = PortManager(self._lines, _Raw(self))
        if self._rfc2217 is None:
            return data
        return b"".join(self._rfc2217.filter(data))

    def read(self) -> bytes | None:
        """Bytes from the client; None when it hung up."""
        try:
            data = self.client.recv(READ_SIZE)  # type: ignore[union-attr]
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError:
            return None
        return self._filter(data) if data else None

    def flush(self) -> None:
        try:
            self._write_to(self.client.send)  # type: ignore[union-attr]
        except OSError:
            self.drop_client()

    def close(self) -> None:
        self.drop_client()
        self.listener.close()


class ControlServer:
    """A Unix socket taking text commands, one per line, each answered with one line."""

    def __init__(self, path: Path) -> None:
        self.path = path
        if path.is_socket():
            path.unlink()
        self.listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            self.listener.bind(str(path))
        except OSError as error:
            self.listener.close()
            raise SetupError(
                f"{path}: cannot create the control socket: {error}"
            ) from None
        self.listener.listen(8)
        self.listener.settimeout(0.0)
        self.buffers: dict[socket.socket, bytes] = {}

    def accept(self) -> socket.socket | None:
        try:
            client, _ = self.listener.accept()
        except (BlockingIOError, InterruptedError):
            return None
        client.settimeout(0.0)
        self.buffers[client] = b""
        return client

    def read_lines(self, client: socket.socket) -> list[str] | None:
        """Complete lines from *client*; None when it hung up."""
        try:
            data = client.recv(4096)
        except (BlockingIOError, InterruptedError):
            return []
        except OSError:
            data = b""
        if not data:
            return None
        *lines, rest = (self.buffers[client] + data).split(b"\n")
        self.buffers[client] = rest[-4096:]
        return [line.decode("utf-8", "replace").strip() for line in lines]

    @staticmethod
    def answer(client: socket.socket, text: str) -> None:
        with contextlib.suppress(OSError):
            client.settimeout(1.0)
            client.sendall(text.encode() + b"\n")
            client.settimeout(0.0)

    def drop(self, client: socket.socket) -> None:
        self.buffers.pop(client, None)
        client.close()

    def close(self) -> None:
        for client in list(self.buffers):
            self.drop(client)
        self.listener.close()
        with contextlib.suppress(OSError):
            self.path.unlink()
