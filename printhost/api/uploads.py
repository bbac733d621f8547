"""(being written) router for the uploads endpoints."""

from __future__ import annotations

from ninja import Router

router = Router()
