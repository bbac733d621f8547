"""ASGI entry point: HTTP through Django, websockets through Channels."""

from __future__ import annotations

import os

from django.core.asgi import get_asgi_application

os.environ.setdefault("DJANGO_SETTINGS_MODULE", "printhost.settings")
# Django must be set up before the consumers (and their models) are imported.
http_application = get_asgi_application()

from channels.auth import AuthMiddlewareStack  # noqa: E402
from channels.routing import ProtocolTypeRouter, URLRouter  # noqa: E402
from channels.security.websocket import OriginValidator  # noqa: E402
from django.conf import settings  # noqa: E402
from django.urls import path  # noqa: E402

from printers.consumers import PrinterConsumer, PrintersConsumer  # noqa: E402


class OriginCheck(OriginValidator):
    """Refuse browsers from foreign sites; let programs that send no Origin through.

    Browsers always send Origin on a websocket handshake, so a missing one means a
    program (a slicer, a script, another host): those authenticate with an API key,
    and a cookie they might hold was not sent by a page of someone else's site.
    Browsers' origins must match ALLOWED_HOSTS (Channels' AllowedHostsOriginValidator).
    """

    def valid_origin(self, parsed_origin: object) -> bool:
        if parsed_origin is None:
            return True
        return super().valid_origin(parsed_origin)


websocket_urls = [
    path("ws/printers/", PrintersConsumer.as_asgi()),
    path("ws/printers/<slug:slug>/", PrinterConsumer.as_asgi()),
]

application = ProtocolTypeRouter(
    {
        "http": http_application,
        "websocket": OriginCheck(
            AuthMiddlewareStack(URLRouter(websocket_urls)), settings.ALLOWED_HOSTS
        ),
    }
)
