"""printhost: a print server for 3D printers, CNC routers and lasers."""

from printhost.celery import app as celery_app

#: The release, as pyproject.toml names it; the API dialects report it.
__version__ = "0.1.0"

__all__ = ["__version__", "celery_app"]
