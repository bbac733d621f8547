"""The printer worker: the spooler loop that drives one printer (see loop.py)."""

from __future__ import annotations
