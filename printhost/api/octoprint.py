"""(being written) router for the octoprint endpoints."""

from __future__ import annotations

from ninja import Router

router = Router()
