"""Credentials out of URLs before they are logged."""

from __future__ import annotations

import re

#: Query parameters whose values are secrets (API keys, tokens, passwords).
SECRET_PARAMS = (
    "apikey",
    "api_key",
    "key",
    "token",
    "access_token",
    "auth",
    "password",
    "secret",
    "session",
    "sessionid",
    "csrftoken",
    "signature",
)
_SECRET = re.compile(r"(?i)([?&;](?:" + "|".join(SECRET_PARAMS) + r")=)[^&;#\s\"]*")


def redact_target(target: str) -> str:
    """*target* (a path with its query) with every credential value replaced."""
    return _SECRET.sub(r"\1[redacted]", target) if "=" in target else target
