"""Typed protocol errors: who broke the protocol, us or the firmware."""

from __future__ import annotations


class ProtocolError(Exception):
    """Base class of every error raised by the sans-IO protocols."""


class LocalProtocolError(ProtocolError):
    """We asked the protocol for something its state does not allow (a bug or bad input)."""


class RemoteProtocolError(ProtocolError):
    """The firmware said something the protocol cannot make sense of."""


class CommandRejected(LocalProtocolError):
    """A command cannot be sent at all (too long, binary, empty); the stream stops."""
