"""The Celery app: slow work (file analysis, upkeep) away from requests and workers.

The broker is Redis when REDIS_URL is set (a farm, CI) and otherwise kombu's
filesystem transport in the data directory (`make run`): messages are files, so
it needs no server and no extra package, and it survives a restart like the
SQLite database beside it. PRINTHOST_CELERY_BROKER names another broker.
"""

from __future__ import annotations

import os
from typing import Any

from celery import Celery
from celery.signals import setup_logging

os.environ.setdefault("DJANGO_SETTINGS_MODULE", "printhost.settings")

app = Celery("printhost")
app.config_from_object("django.conf:settings", namespace="CELERY")
app.autodiscover_tasks()


@setup_logging.connect
def use_printhost_logging(**_: Any) -> None:
    """Celery's worker and beat log as every other printhost process does
    (settings.LOGGING: PRINTHOST_LOG_FORMAT, PRINTHOST_LOG_LEVEL); a receiver
    here keeps Celery from installing handlers and formats of its own."""
    from logging.config import dictConfig

    from django.conf import settings

    dictConfig(settings.LOGGING)
