"""The serial link: pyserial's serial_for_url behind read(timeout) / write(bytes) / close().

Any URL pyserial knows works as a printer port: `/dev/ttyUSB0`, a pty path,
`socket://host:port`, `rfc2217://host:port`. The transport knows nothing of G-code.
"""

from __future__ import annotations

import contextlib
import select

import serial

#: A write that cannot finish in this time (flow control stalled, a wedged USB
#: adapter) is a lost port. Bounded well under the printer lease, which the worker
#: loop renews between writes; a healthy port takes milliseconds for a window.
WRITE_TIMEOUT = 2.0


class TransportError(Exception):
    """The port could not be opened or used; the message says which and why."""


class TransportClosed(TransportError):
    """The port went away (unplugged, simulator gone, socket closed)."""


class SerialTransport:
    """One open port. `read(timeout)` returns b"" on timeout, raises TransportClosed at EOF."""

    def __init__(self, port: serial.SerialBase) -> None:
        self._port = port
        try:
            self._fd: int | None = port.fileno()
        except (AttributeError, NotImplementedError, serial.SerialException):
            self._fd = None

    @classmethod
    def open(cls, url: str, baud: int) -> SerialTransport:
        """Open *url* at *baud*; TransportError with a clear message if it fails."""
        try:
            port = serial.serial_for_url(
                url,
                baudrate=baud,
                timeout=0,
                write_timeout=WRITE_TIMEOUT,
                exclusive=True,
            )
        except ValueError as error:
            raise TransportError(f"{url}: bad port settings: {error}") from None
        except (serial.SerialException, OSError) as error:
            raise TransportError(f"{url}: cannot open port: {error}") from None
        return cls(port)

    def read(self, timeout: float) -> bytes:
        """Bytes that arrived within *timeout* seconds; b"" if none did."""
        try:
            if self._fd is not None:
                ready, _, _ = select.select([self._fd], [], [], max(0.0, timeout))
                if not ready:
                    return b""
                data = self._port.read(65536)
                if not data:
                    raise TransportClosed(f"{self._port.port}: port closed")
                return data
            self._port.timeout = max(0.001, min(timeout, 0.05))
            return self._port.read(65536)
        except (serial.SerialException, OSError) as error:
            raise TransportClosed(f"{self._port.port}: {error}") from None

    def write(self, data: bytes) -> None:
        """Write *data* in one call (whole lines: pyserial is slow byte by byte)."""
        if not data:
            return
        try:
            self._port.write(data)
        except (serial.SerialException, OSError) as error:
            raise TransportClosed(f"{self._port.port}: write failed: {error}") from None

    def close(self) -> None:
        with contextlib.suppress(serial.SerialException, OSError):
            self._port.close()
