"""Upkeep settings: defaults, beat's schedule (every task it names is registered), and
nonsense values stopping the start with the variable's name."""

from __future__ import annotations

import runpy
from pathlib import Path
from typing import Any

import pytest
from django.conf import settings
from django.core.exceptions import ImproperlyConfigured

from printhost.celery import app
from tests.conftest import ROOT

SETTINGS = ROOT / "printhost" / "settings.py"
#: Each upkeep variable, its default, and the beat entry it times (if any).
VARIABLES = {
    "PRINTHOST_UPKEEP_RESPONSE_LOG_SECONDS": (60.0, "upkeep-response-log"),
    "PRINTHOST_UPKEEP_TEMPERATURE_SECONDS": (600.0, "upkeep-temperature-samples"),
    "PRINTHOST_UPKEEP_UPLOADS_SECONDS": (3600.0, "upkeep-partial-uploads"),
    "PRINTHOST_UPKEEP_JOB_FILES_SECONDS": (3600.0, "upkeep-job-files"),
    "PRINTHOST_UPKEEP_ANALYSES_SECONDS": (3600.0, "upkeep-orphaned-analyses"),
    "PRINTHOST_TEMPERATURE_KEEP_HOURS": (24.0, None),
    "PRINTHOST_UPLOAD_EXPIRE_HOURS": (24.0, None),
}
TASKS = {
    "upkeep-response-log": "printers.tasks.trim_response_logs",
    "upkeep-temperature-samples": "printers.tasks.prune_temperature_samples",
    "upkeep-partial-uploads": "jobs.tasks.expire_uploads",
    "upkeep-job-files": "jobs.tasks.remove_expired_job_files",
    "upkeep-orphaned-analyses": "jobs.tasks.remove_orphaned_analyses",
}


def load(monkeypatch: pytest.MonkeyPatch, tmp_path: Path, **env: str) -> dict[str, Any]:
    """printhost/settings.py run afresh with *env* (its data dir in *tmp_path*)."""
    monkeypatch.setenv("PRINTHOST_DATA_DIR", str(tmp_path))
    for name in VARIABLES:
        monkeypatch.delenv(name, raising=False)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    return runpy.run_path(str(SETTINGS))


def test_defaults_and_the_schedule_they_make(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    loaded = load(monkeypatch, tmp_path)
    schedule = loaded["CELERY_BEAT_SCHEDULE"]
    for name, (default, entry) in VARIABLES.items():
        assert loaded[name] == default, name
        if entry is not None:
            assert schedule[entry]["schedule"] == default
            # A run the worker could not start within its interval is dropped.
            assert schedule[entry]["options"] == {"expires": max(default, 60)}
    assert {k: schedule[k]["task"] for k in TASKS} == TASKS


def test_values_from_the_environment_are_used(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    loaded = load(
        monkeypatch, tmp_path,
        PRINTHOST_UPKEEP_JOB_FILES_SECONDS="90.5", PRINTHOST_UPLOAD_EXPIRE_HOURS="6",
    )  # fmt: skip
    schedule = loaded["CELERY_BEAT_SCHEDULE"]
    assert schedule["upkeep-job-files"]["schedule"] == 90.5
    assert schedule["upkeep-job-files"]["options"] == {"expires": 90.5}
    assert loaded["PRINTHOST_UPLOAD_EXPIRE_HOURS"] == 6.0


@pytest.mark.parametrize("value", ["-5", "0", "abc", "nan", "inf", "1e999", "-0.1"])
@pytest.mark.parametrize("name", sorted(VARIABLES))
def test_nonsense_stops_the_start_naming_the_variable(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, name: str, value: str
) -> None:
    with pytest.raises(ImproperlyConfigured, match=f"^{name}="):
        load(monkeypatch, tmp_path, **{name: value})


def test_every_scheduled_task_is_a_registered_task() -> None:
    app.loader.import_default_modules()  # what a worker does at start
    scheduled = {entry["task"] for entry in settings.CELERY_BEAT_SCHEDULE.values()}
    assert set(TASKS.values()) <= scheduled
    missing = sorted(name for name in scheduled if name not in app.tasks)
    assert missing == []
