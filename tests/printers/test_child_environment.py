"""What runhost's children load: those that serve no pages start without the web
server's apps, and none carries the file analyser (numpy) but Celery's tasks."""

from __future__ import annotations

import subprocess
import sys

import pytest

from printers.supervisor import child_environment
from tests.conftest import ROOT

#: Loaded by daphne's and django-ninja's apps, by nothing a printer worker runs.
WEB_ONLY = ("daphne.server", "twisted.internet", "ninja", "pydantic")
#: Loaded only by the analysis task's body (jobs/analysis_task.py).
ANALYSER = ("numpy", "jobs.analysis.analyser")


def modules_after_setup(env: dict[str, str], imports: str = "") -> set[str]:
    """Which of WEB_ONLY and ANALYSER a `manage.py` process has loaded once Django
    is set up and *imports* ran."""
    names = WEB_ONLY + ANALYSER
    code = f"{imports}\nimport sys; print(' '.join(m for m in {names!r} if m in sys.modules))"
    out = subprocess.run(
        [sys.executable, "manage.py", "shell", "--no-imports", "-c", code],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=120, check=True,
    )  # fmt: skip
    return set(out.stdout.split())


@pytest.mark.parametrize("name", ["worker:mk3", "celery"])
def test_children_that_serve_no_pages_leave_the_web_apps_out(name):
    env = child_environment(name)
    assert env["PRINTHOST_WEB_APPS"] == "0"
    assert modules_after_setup(env) == set()


def test_a_printer_worker_and_the_pages_never_load_the_analyser():
    worker = "import printers.worker.loop, jobs.services, jobs.tasks"
    assert modules_after_setup(child_environment("worker:mk3"), worker) == set()
    pages = "import printhost.urls, printhost.asgi"
    assert modules_after_setup(child_environment("daphne"), pages) == set(WEB_ONLY)


def test_the_web_server_keeps_the_web_apps():
    env = child_environment("daphne")
    assert env["PRINTHOST_WEB_APPS"] == "1"
    assert modules_after_setup(env) == set(WEB_ONLY)
