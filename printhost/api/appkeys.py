"""(being written) router for the appkeys endpoints."""

from __future__ import annotations

from ninja import Router

router = Router()
