"""(being written) router for the printer endpoints."""

from __future__ import annotations

from ninja import Router

router = Router()
