"""`manage.py check --deploy` with production settings: no warnings at all."""

from __future__ import annotations

import os
import secrets
import subprocess
import sys
from pathlib import Path

from tests.conftest import ROOT


def deploy_check(tmp_path: Path, **env: str) -> subprocess.CompletedProcess[str]:
    environment = {**os.environ, "PRINTHOST_DATA_DIR": str(tmp_path), **env}
    environment.pop("PRINTHOST_DEBUG", None)
    return subprocess.run(
        [sys.executable, "manage.py", "check", "--deploy", "--fail-level", "WARNING"],
        cwd=ROOT, env=environment, capture_output=True, text=True, timeout=120,
    )  # fmt: skip


def test_deploy_check_is_clean_with_production_settings(tmp_path: Path):
    done = deploy_check(
        tmp_path,
        PRINTHOST_SECRET_KEY=secrets.token_urlsafe(50),
        PRINTHOST_HTTPS="1",
        PRINTHOST_ALLOWED_HOSTS="printhost.example.org",
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert "no issues" in done.stdout


def test_deploy_check_flags_the_development_secret_key(tmp_path: Path):
    done = deploy_check(tmp_path, PRINTHOST_HTTPS="1")
    assert done.returncode != 0
    assert "SECRET_KEY" in done.stdout + done.stderr
