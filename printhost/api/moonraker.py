"""(being written) router for the moonraker endpoints."""

from __future__ import annotations

from ninja import Router

router = Router()
