"""(being written) router for the keys endpoints."""

from __future__ import annotations

from ninja import Router

router = Router()
