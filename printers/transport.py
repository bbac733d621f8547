"""The serial link: pyserial's serial_for_url behind read(timeout) / write(bytes) / close().

The ports `printers.ports` allows work: `/dev/ttyUSB0`, a pty link in the data
directory, `socket://host:port` and `rfc2217://host:port` to listed hosts. The transport knows nothing of G-code.
"""

from __future__ import annotations

import contextlib
import errno
import os
import select
import time

import serial
from serial.serialposix import Serial as PosixSerial

from printers.ports import PortRefused, check_configured_port

#: A write that cannot finish in this time (flow control stalled, a wedged USB
#: adapter) is a lost port. Bounded well under the printer lease, which the worker
#: loop renews between writes; a healthy port takes milliseconds for a window.
WRITE_TIMEOUT = 2.0
#: How long DTR is dropped for a reset pulse (boards reset on the edge; bootloader
#: tools hold it about this long).
DTR_PULSE_SECONDS = 0.1
#: The most one read takes from the port.
READ_BYTES = 65536
#: errno values that mean "not now" on a non-blocking descriptor.
_AGAIN = (errno.EAGAIN, errno.EWOULDBLOCK, errno.EINTR)


class TransportError(Exception):
    """The port could not be opened or used; the message says which and why."""


class TransportClosed(TransportError):
    """The port went away (unplugged, simulator gone, socket closed)."""


class PortNotAllowed(TransportError):
    """The port is not one printhost may open (`printers.ports`); retrying won't help."""


class SerialTransport:
    """One open port. `read(timeout)` returns b"" on timeout, raises TransportClosed at EOF."""

    def __init__(self, port: serial.SerialBase) -> None:
        self._port = port
        try:
            self._fd: int | None = port.fileno()
        except (AttributeError, NotImplementedError, OSError, serial.SerialException):
            self._fd = None
        #: A POSIX serial device or pty, opened non-blocking by pyserial: read and
        #: written with one system call each. pyserial's own read and write wait
        #: in select() around every call (three calls a read, two a write), which
        #: was a third of the worker's CPU per line.
        self._raw = self._fd if isinstance(port, PosixSerial) else None
        #: The last read's *wake* descriptor was readable.
        self.woken = False

    @classmethod
    def open(cls, url: str, baud: int) -> SerialTransport:
        """Open *url* at *baud*; TransportError with a clear message if it fails.

        Only ports `printers.ports` allows are opened (a row stored before that
        check, or written around it, must not reach `spy://` or another service).
        """
        try:
            check_configured_port(url)
        except PortRefused as error:
            raise PortNotAllowed(f"cannot open port: {error}") from None
        try:
            # pyserial's RFC 2217 client has no write timeout (it writes to a socket).
            bound = None if url.startswith("rfc2217://") else WRITE_TIMEOUT
            port = serial.serial_for_url(
                url, baudrate=baud, timeout=0, write_timeout=bound, exclusive=True
            )
        except ValueError as error:
            raise TransportError(f"{url}: bad port settings: {error}") from None
        except (serial.SerialException, OSError) as error:
            raise TransportError(f"{url}: cannot open port: {error}") from None
        return cls(port)

    def read(self, timeout: float, *, wake: int | None = None) -> bytes:
        """Bytes that arrived within *timeout* seconds; b"" if none did.

        *wake*: another file descriptor that ends the wait as well (the worker's
        database notifications); `woken` says whether it was readable.
        """
        self.woken = False
        if self._raw is not None:
            return self._read_raw(self._raw, timeout, wake)
        try:
            if self._fd is not None:
                if not self._ready(self._fd, timeout, wake):
                    return b""
                data = self._port.read(65536)
                if not data:
                    raise TransportClosed(f"{self._port.port}: port closed")
                return data
            # No file descriptor (rfc2217://): wait for one byte, then take the rest;
            # *wake* is looked at after that short wait (an emergency stop written
            # for the printer is not left to the next poll).
            self._port.timeout = max(0.001, min(timeout, 0.05))
            first = self._port.read(1)
            waiting = self._port.in_waiting if first else 0
            if wake is not None:
                self.woken = bool(select.select([wake], [], [], 0)[0])
            return first + (self._port.read(waiting) if waiting else b"")
        except (serial.SerialException, OSError) as error:
            raise TransportClosed(f"{self._port.port}: {error}") from None

    def read_waiting(self) -> bytes:
        """What has arrived already, without waiting (b"" if nothing has).

        On a raw descriptor one read, no select(): b"" there means nothing came
        or the device is gone, which the next `read` tells apart.
        """
        if self._raw is None:
            return self.read(0.0)
        try:
            return os.read(self._raw, READ_BYTES)
        except OSError as error:
            if error.errno in _AGAIN:
                return b""
            raise TransportClosed(f"{self._port.port}: {error}") from None

    def _ready(self, fd: int, timeout: float, wake: int | None) -> bool:
        """Wait up to *timeout* for *fd* or *wake*; `woken` says whether *wake* was
        readable; True when *fd* is."""
        fds = [fd] if wake is None else [fd, wake]
        ready, _, _ = select.select(fds, [], [], max(0.0, timeout))
        self.woken = wake is not None and wake in ready
        return fd in ready

    def _read_raw(self, fd: int, timeout: float, wake: int | None) -> bytes:
        # select() first even without a timeout: a tty set up as pyserial does
        # (VMIN = VTIME = 0) reads b"" both when nothing came and when the device
        # is gone; only after select() said "ready" does b"" mean gone.
        try:
            if not self._ready(fd, timeout, wake):
                return b""
            data = os.read(fd, READ_BYTES)
        except OSError as error:
            if error.errno in _AGAIN:
                return b""
            raise TransportClosed(f"{self._port.port}: {error}") from None
        if not data:
            raise TransportClosed(f"{self._port.port}: port closed")
        return data

    def write(self, data: bytes) -> None:
        """Write *data* in one call (whole lines: pyserial is slow byte by byte)."""
        if not data:
            return
        if self._raw is not None:
            self._write_raw(self._raw, data)
            return
        try:
            self._port.write(data)
        except (serial.SerialException, OSError) as error:
            raise TransportClosed(f"{self._port.port}: write failed: {error}") from None

    def _write_raw(self, fd: int, data: bytes) -> None:
        """os.write until all is written; waits for room at most WRITE_TIMEOUT."""
        deadline = None
        view = memoryview(data)
        while view:
            try:
                view = view[os.write(fd, view) :]
                continue
            except OSError as error:
                if error.errno not in _AGAIN:
                    raise TransportClosed(
                        f"{self._port.port}: write failed: {error}"
                    ) from None
            now = time.monotonic()
            deadline = deadline or now + WRITE_TIMEOUT
            try:
                _, ready, _ = select.select([], [fd], [], max(0.0, deadline - now))
            except OSError as error:
                raise TransportClosed(
                    f"{self._port.port}: write failed: {error}"
                ) from None
            if not ready:
                raise TransportClosed(f"{self._port.port}: write failed: Write timeout")

    def pulse_dtr(self) -> str:
        """Drop and raise DTR (resets the usual USB boards); returns "" or why not."""
        url = str(self._port.port or "")
        if url.startswith(("socket://", "loop://")):
            return f"{url.split(':', 1)[0]}:// has no DTR line"
        try:
            self._port.dtr = False
            time.sleep(DTR_PULSE_SECONDS)
            self._port.dtr = True
        except (serial.SerialException, OSError, ValueError) as error:
            return f"this port has no DTR line to pulse ({error})"
        return ""

    def close(self) -> None:
        with contextlib.suppress(serial.SerialException, OSError):
            self._port.close()
