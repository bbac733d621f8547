"""The simulator's ports in its selectors loop: reading what hosts write, asking
for write events only while output waits, a TCP client coming and going, the
device pulled and plugged back, and the control socket. A mixin of Simulator
(runner.py).
"""

from __future__ import annotations

import selectors
import time
from typing import TYPE_CHECKING

from printers.simulator._ports import PtyPort, TcpPort

if TYPE_CHECKING:
    import socket

    from printers.simulator.runner import Simulator

__all__ = ["PortEvents"]


class PortEvents:
    """Port and control-socket events of the simulator's loop."""

    def _open_ports(self: Simulator) -> list[tuple[object, PtyPort | TcpPort]]:
        """(file object, port) of every port a host can talk through right now."""
        ports: list[tuple[object, PtyPort | TcpPort]] = []
        if self.pty is not None and self.pty.master is not None:
            ports.append((self.pty.master, self.pty))
        if self.tcp is not None and self.tcp.client is not None:
            ports.append((self.tcp.client, self.tcp))
        return ports

    def _read_ports(self: Simulator, since: float) -> None:
        """Read what the hosts wrote while we were not listening (see `run`).

        We stop listening while the inbound wire is busy: bytes written then
        queue behind it anyway, so reading them a little later changes nothing,
        and a streaming host costs one wake-up per line instead of three.
        """
        for _, port in self._open_ports():
            self._read_port(port, since)

    def _read_port(self: Simulator, port: PtyPort | TcpPort, now: float) -> None:
        data = port.read()
        if data is None:  # the TCP client hung up
            self._drop_tcp_client()
        elif data:
            share = self.faults.config.noise_to_firmware
            data = self.faults.garble(data, share, one_per_line=True)
            self.to_firmware.put(data, now)
        if isinstance(port, TcpPort) and port.take_dtr_reset():  # RFC 2217 DTR pulse
            self.to_firmware.clear()
            self.firmware.reset(now)

    def _update_interest(self: Simulator) -> None:
        """Read only while listening; ask for EVENT_WRITE only while output waits."""
        for fileobj, port in self._open_ports():
            mask = selectors.EVENT_READ if self._listening else 0
            if port.pending:
                mask |= selectors.EVENT_WRITE
            self._set_interest(fileobj, mask, port)

    def _set_interest(
        self: Simulator, fileobj: object, mask: int, port: PtyPort | TcpPort
    ) -> None:
        current = self._masks.get(fileobj, 0)
        if mask == current:
            return
        if not mask:
            self.selector.unregister(fileobj)
            del self._masks[fileobj]
            return
        if current:
            self.selector.modify(fileobj, mask, self._port_callback(port))
        else:
            self.selector.register(fileobj, mask, self._port_callback(port))
        self._masks[fileobj] = mask

    def _forget(self: Simulator, fileobj: object) -> None:
        if self._masks.pop(fileobj, 0):
            self.selector.unregister(fileobj)

    def _port_callback(self: Simulator, port: PtyPort | TcpPort) -> object:
        def on_event(mask: int) -> None:
            if mask & selectors.EVENT_WRITE:
                port.flush()
            if mask & selectors.EVENT_READ:
                self._read_port(port, time.monotonic())

        return on_event

    def _on_accept(self: Simulator, mask: int) -> None:
        tcp = self.tcp
        assert tcp is not None
        old = tcp.client
        if old is not None:
            self._forget(old)
        tcp.accept()

    def _drop_tcp_client(self: Simulator) -> None:
        tcp = self.tcp
        if tcp is not None and tcp.client is not None:
            self._forget(tcp.client)
            tcp.drop_client()

    def close_ports(self: Simulator) -> None:
        """The device went away: the link disappears and the TCP client is dropped."""
        if self.pty is not None and self.pty.master is not None:
            self._forget(self.pty.master)
            self.pty.close()
        if self.tcp is not None:
            self._drop_tcp_client()
            self.tcp.accepting = False
        self.closed = True
        self.to_firmware.clear()
        self.to_host.clear()

    def reopen_ports(self: Simulator, now: float) -> None:
        """The device is back (powered up again): fresh pty, firmware reset."""
        self._reopen_at = None
        if not self.closed:
            return
        if self.pty is not None:
            self.pty.open()
        if self.tcp is not None:
            self.tcp.accepting = True
        self.closed = False
        self.firmware.reset(now)
        self._boot_output()

    # -- the control socket ----------------------------------------------------------

    def _on_control_accept(self: Simulator, mask: int) -> None:
        client = self.control.accept()  # type: ignore[union-attr]
        if client is not None:
            self.selector.register(
                client, selectors.EVENT_READ, self._control_reader(client)
            )

    def _control_reader(self: Simulator, client: socket.socket) -> object:
        def on_readable(mask: int) -> None:
            control = self.control
            assert control is not None
            lines = control.read_lines(client)
            if lines is None:
                self.selector.unregister(client)
                control.drop(client)
                return
            for line in lines:
                if line:
                    control.answer(client, self.handle_control(line))

        return on_readable
