"""Helpers of the `/printer/` API tests: a small G-code file and a call through
Django's test client."""

from __future__ import annotations

import json

from django.test import Client

GCODE = "G28\nG1 X10 Y10\nM104 S0\n"


def call(
    method: str, path: str, key: str | None = None, **kwargs: object
) -> tuple[int, dict]:
    headers = {"HTTP_X_API_KEY": key} if key else {}
    response = getattr(Client(), method)(path, **kwargs, **headers)
    body = response.content
    return response.status_code, json.loads(body) if body else {}
