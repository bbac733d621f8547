"""The Celery app: slow work (file analysis, upkeep) away from requests and workers.

The broker is Redis when REDIS_URL is set (a farm, CI) and otherwise kombu's
filesystem transport in the data directory (`make run`): messages are files, so
it needs no server and no extra package, and it survives a restart like the
SQLite database beside it. PRINTHOST_CELERY_BROKER names another broker.
"""

from __future__ import annotations

import os

from celery import Celery

os.environ.setdefault("DJANGO_SETTINGS_MODULE", "printhost.settings")

app = Celery("printhost")
app.config_from_object("django.conf:settings", namespace="CELERY")
app.autodiscover_tasks()
