"""A TCP proxy a test can cut: a database or broker that goes away and comes back.

Real sockets, real server behind: `cut()` closes every connection through it and
turns new ones away (accepted, then closed at once, as a restarting server does),
`restore()` lets them through again. `cut_at()` is a blip at one chosen moment:
the connections drop as the client sends a given message, before the server sees it
or after the server answered it (the client never hears the answer), and new
connections go through at once.
"""

from __future__ import annotations

import contextlib
import socket
import threading


class TcpProxy:
    """Forwards 127.0.0.1:<port> to *target* until cut."""

    def __init__(self, target: tuple[str, int]) -> None:
        self.target = target
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.cuts = 0
        self._cut = threading.Event()
        self._closed = threading.Event()
        self._lock = threading.Lock()
        self._sockets: set[socket.socket] = set()
        #: cut_at(): the marker awaited, and whether the server answers it first.
        self._marker = b""
        self._after_reply = False
        self._then = b""
        #: With *then*: the client connection the marker came on (then's too).
        self._armed_on: socket.socket | None = None
        #: The upstream socket whose next answer is dropped with the cut.
        self._drop_reply_of: socket.socket | None = None
        self.blipped = threading.Event()
        threading.Thread(target=self._accept, daemon=True).start()

    def url(self, scheme: str, path: str = "", user: str = "") -> str:
        who = f"{user}@" if user else ""
        return f"{scheme}://{who}127.0.0.1:{self.port}{path}"

    def cut(self) -> None:
        self._cut.set()
        self._drop_all()

    def _drop_all(self) -> None:
        self.cuts += 1
        with self._lock:
            for sock in self._sockets:
                with contextlib.suppress(OSError):
                    sock.shutdown(socket.SHUT_RDWR)
                sock.close()
            self._sockets.clear()

    def cut_at(self, marker: bytes, *, after_reply: bool, then: bytes = b"") -> None:
        """Once: drop every connection as a client sends a message holding *marker*,
        before the server gets it, or (*after_reply*) once the server has answered
        it, with the answer lost. With *then*, the message that counts is the next
        one holding *then* after *marker* on the same connection (the COMMIT of
        marker's transaction).
        `blipped` is set when it happened."""
        self._marker, self._after_reply, self._then = marker, after_reply, then
        self._armed_on = None
        self.blipped.clear()

    def _blip(self) -> None:
        self._marker = b""
        self._drop_reply_of = None
        self._drop_all()
        self.blipped.set()

    def restore(self) -> None:
        self._cut.clear()

    def close(self) -> None:
        self._closed.set()
        self.cut()
        self.listener.close()

    def _accept(self) -> None:
        while not self._closed.is_set():
            try:
                client, _ = self.listener.accept()
            except OSError:
                return
            if self._cut.is_set():
                client.close()
                continue
            try:
                upstream = socket.create_connection(self.target, timeout=5)
            except OSError:
                client.close()
                continue
            upstream.settimeout(None)
            with self._lock:
                self._sockets.update((client, upstream))
            for source, sink, asks in ((client, upstream, True),
                                       (upstream, client, False)):  # fmt: skip
                threading.Thread(
                    target=self._pump, args=(source, sink, asks), daemon=True
                ).start()

    def _pump(self, source: socket.socket, sink: socket.socket, asks: bool) -> None:
        """Pass on what *source* sends; *asks*: it is the client."""
        try:
            while data := source.recv(65536):
                if source is self._drop_reply_of:
                    self._blip()  # the server did it; the client never hears
                    return
                armed = self._armed_on
                if (
                    asks
                    and self._marker
                    and self._marker in data
                    and (armed is None or armed is source)
                ):
                    if self._then:  # this one only arms the cut
                        self._armed_on = source  # first: others' COMMITs skip
                        self._marker, self._then = self._then, b""
                    elif not self._after_reply:
                        self._blip()  # the server never sees it
                        return
                    else:
                        self._drop_reply_of = sink
                sink.sendall(data)
        except OSError:
            pass
        finally:
            for sock in (source, sink):
                with contextlib.suppress(OSError):
                    sock.shutdown(socket.SHUT_RDWR)
