"""Who the raw TCP terminal lets in, and who makes way (sans-IO).

Rules, per printer port:

A1  At most *most* clients logged in. A connection that finds them all taken is
    refused at once; one whose login finds them taken meanwhile is refused then.
A2  At most *per_address* connections from one client address, logged in or not:
    the one past it is refused at once.
A3  Connections that have not logged in yet are held apart from A1: at most
    *most* of them. One more arriving lets the oldest go (`arrive` returns it),
    so clients that connect and never send a key (from several addresses, each
    under A2) cannot keep a user with a key out: a login takes milliseconds, a
    connection that sends nothing waits PRINTHOST_TERMINAL_LOGIN_SECONDS.
"""

from __future__ import annotations

from collections import Counter
from typing import Generic, TypeVar

__all__ = ["Admission"]

C = TypeVar("C")


class Admission(Generic[C]):
    """The terminal's counts: clients logged in, waiting to, and per address."""

    def __init__(self, most: int, per_address: int) -> None:
        self.most = most
        self.per_address = per_address
        self.logged_in: Counter[str] = Counter()
        self.addresses: Counter[str] = Counter()
        #: Per printer, connections waiting for their key line, oldest first.
        self.waiting: dict[str, dict[C, None]] = {}
        #: Connections let go for newer ones (A3) that have not left yet.
        self.let_go: set[C] = set()

    def refusal(self, slug: str, address: str) -> str:
        """Why a new connection from *address* to *slug* is refused ("" if not)."""
        if self.logged_in[slug] >= self.most:
            return self._full(slug)
        if self.addresses[address] >= self.per_address:
            return (
                f"too many terminal connections from {address} "
                f"(at most {self.per_address})"
            )
        return ""

    def arrive(self, slug: str, address: str, client: C) -> C | None:
        """Count *client* (let in by `refusal`) as waiting to log in; the oldest
        waiting client to let go for it (A3), or None."""
        self.addresses[address] += 1
        waiting = self.waiting.setdefault(slug, {})
        waiting[client] = None
        if len(waiting) <= self.most:
            return None
        oldest = next(iter(waiting))
        del waiting[oldest]
        self.let_go.add(oldest)
        return oldest

    def log_in(self, slug: str, client: C) -> str:
        """*client* gave a good key: why it may not stay (A1, A3), "" when it may."""
        if client in self.let_go:
            return "too many connections waiting to log in"
        if self.logged_in[slug] >= self.most:
            return self._full(slug)
        self.waiting.get(slug, {}).pop(client, None)
        self.logged_in[slug] += 1
        return ""

    def leave(self, slug: str, address: str, client: C) -> None:
        """*client* is gone, logged in or not."""
        waiting = self.waiting.get(slug, {})
        if client in self.let_go:
            self.let_go.discard(client)
        elif client in waiting:
            del waiting[client]
            if not waiting:
                del self.waiting[slug]
        else:
            self.logged_in[slug] -= 1
            if self.logged_in[slug] <= 0:
                del self.logged_in[slug]
        self.addresses[address] -= 1
        if self.addresses[address] <= 0:
            del self.addresses[address]

    def _full(self, slug: str) -> str:
        return f"too many terminal clients on printer {slug!r} (at most {self.most})"
