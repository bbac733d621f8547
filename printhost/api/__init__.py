"""The host API: one django-ninja API, one OpenAPI schema at /api/schema/.

Modules add their routers here: the seed's Repetier-style `/printer/` API and the
slicer dialects (OctoPrint `/api/`, Moonraker `/server/` and `/printer/print/`).
"""

from __future__ import annotations

from ninja import NinjaAPI

from printhost.api.common import CallerAuth, docs_access, install_error_handlers

api = NinjaAPI(
    title="printhost",
    version="1",
    description=(
        "Print server API: Repetier-Server's `/printer/` API with the "
        '`{"error", "data"}` envelope, plus OctoPrint, Moonraker and Repetier '
        "dialects so slicers can upload and print without a plugin. Authenticate "
        "with `X-Api-Key`, `Authorization: Bearer`, `?apikey=` or a session."
    ),
    auth=CallerAuth(),
    openapi_url="/api/schema/",
    docs_url="/api/docs/",
    docs_decorator=docs_access,
    urls_namespace="api",
)
install_error_handlers(api)


def _register() -> None:
    """Import the modules that hold routers (each calls `api.add_router`)."""
    import importlib

    for name in ROUTER_MODULES:
        module = importlib.import_module(f"printhost.api.{name}")
        api.add_router("", module.router)


#: Modules with a `router`; add a module here to publish its endpoints.
#: Order matters where paths overlap: Moonraker's `/printer/print/...` comes before
#: the seed's `/printer/<call>/<slug>`.
ROUTER_MODULES: list[str] = [
    "moonraker",
    "moonraker_history",
    "octoprint",
    "octoprint_control",
    "octoprint_jobs",
    "octoprint_sd",
    "appkeys",
    "keys",
    "config",
    "sdcard",
    "analysis",
    "printer",
    "host",
    "repetier",
    "uploads",
    "resume",
    "history",
    "print_history",
    "objects",
    "farm",
]
_register()
