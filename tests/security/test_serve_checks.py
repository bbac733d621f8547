"""The web server's start-up checks and its access log, in real processes.

- `printhost.serve` refuses to start when a Twisted/daphne internal it patches is
  gone (the check is fed stand-ins here; the installed versions must pass it);
- the development secret key is refused on a non-loopback bind unless DEBUG is on
  (`python -m printhost.serve` and `manage.py runhost`, as subprocesses);
- API keys in query strings never reach the access log (a running runhost's log).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from typing import TYPE_CHECKING

import httpx
import pytest

from printhost import startup
from printhost.redact import redact_target
from tests.conftest import ROOT, wait_for
from tests.hosts import Host, free_port

if TYPE_CHECKING:
    from pathlib import Path


class Channel:
    """A stand-in for Twisted's HTTPChannel, with one method and no `_path`."""

    def allHeadersReceived(self) -> None:
        self._command = b"GET"


def test_missing_internals_are_named_and_stop_the_server() -> None:
    internals = (
        startup.Internal(Channel, "allHeadersReceived"),
        startup.Internal(Channel, "allContentReceived"),
        startup.Internal(Channel, "_command", set_in="allHeadersReceived"),
        startup.Internal(Channel, "_path", set_in="allHeadersReceived"),
        startup.Internal(Channel, "_version", set_in="lineReceived"),
    )
    missing = startup.missing_internals(internals)
    assert [m.rsplit(".", 1)[-1] for m in missing] == [
        "allContentReceived",
        "_path (set in allHeadersReceived)",
        "_version (set in lineReceived)",
    ]
    from printhost import serve

    with pytest.raises(SystemExit) as stop:
        serve.check_internals(internals)
    assert "printhost.serve cannot protect uploads" in str(stop.value.code)
    assert "Channel.allContentReceived" in str(stop.value.code)
    assert "requirements.txt" in str(stop.value.code)


def test_the_installed_twisted_and_daphne_have_every_internal_serve_uses() -> None:
    from printhost import serve

    assert startup.missing_internals(serve.INTERNALS) == []


def test_twisted_is_pinned_to_the_installed_version() -> None:
    from importlib.metadata import version

    pins = (ROOT / "requirements.txt").read_text()
    assert f"Twisted=={version('twisted')}" in pins


def _env(tmp_path: Path, **extra: str) -> dict[str, str]:
    env = {**os.environ, "PRINTHOST_DATA_DIR": str(tmp_path), **extra}
    for name in ("PRINTHOST_SECRET_KEY", "PRINTHOST_DEBUG"):
        if name not in extra:
            env.pop(name, None)
    return env


def _serve(tmp_path: Path, bind: str, **extra: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "printhost.serve", "-b", bind, "-p", str(free_port()),
         "printhost.asgi:application"],
        cwd=ROOT, env=_env(tmp_path, **extra), stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip


def test_the_development_secret_key_is_refused_beyond_loopback(tmp_path: Path) -> None:
    for bind in ("0.0.0.0", "::"):
        process = _serve(tmp_path, bind)
        output, _ = process.communicate(timeout=120)
        assert process.returncode != 0, output
        assert "refusing to serve on" in output
        assert "development secret key" in output
        assert "PRINTHOST_SECRET_KEY" in output

    runhost = subprocess.run(
        [sys.executable, "manage.py", "runhost", "--bind", "0.0.0.0", "--port",
         str(free_port())],
        cwd=ROOT, env=_env(tmp_path), capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert runhost.returncode != 0
    assert "development secret key" in runhost.stderr


def test_loopback_debug_or_a_real_key_still_serve(tmp_path: Path) -> None:
    subprocess.run(
        [sys.executable, "manage.py", "migrate", "--noinput"], cwd=ROOT,
        env=_env(tmp_path), check=True, capture_output=True, timeout=120,
    )  # fmt: skip
    for bind, extra in (
        ("127.0.0.1", {}),
        ("0.0.0.0", {"PRINTHOST_SECRET_KEY": "x" * 60}),
        ("0.0.0.0", {"PRINTHOST_DEBUG": "1"}),
    ):
        process = _serve(tmp_path, bind, **extra)
        try:
            assert process.stdout is not None
            seen: list[str] = []

            def listening(
                process: subprocess.Popen[str] = process, seen: list[str] = seen
            ) -> bool:
                line = process.stdout.readline()  # type: ignore[union-attr]
                seen.append(line)
                return "Listening on TCP address" in line or not line

            wait_for(listening, 120, f"daphne on {bind} {extra}")
            assert process.poll() is None, "".join(seen)
        finally:
            process.terminate()
            process.wait(timeout=30)


def test_keys_in_query_strings_are_redacted_in_the_access_log(tmp_path: Path) -> None:
    host = Host(tmp_path)
    host.migrate()
    key = host.add_user("op", superuser=True)
    with host.running():
        for name in ("apikey", "token"):
            answer = httpx.get(f"{host.url}/api/version?x=1&{name}={key}", timeout=30)
            assert answer.status_code == 200
        refused = httpx.post(
            f"{host.url}/api/files/local?apikey=ph_notakeyatall00000000000",
            content=b"x" * 10,
            timeout=30,
        )
        assert refused.status_code == 401

        def logged() -> bool:
            log = host.log_tail(400)
            return (
                len(re.findall(r'"GET /api/version\?', log)) >= 2
                and "refused POST /api/files/local" in log
            )

        wait_for(logged, 30, "the access log lines")
    log = (tmp_path / "runhost.log").read_text()
    assert key not in log
    assert key[:12] not in log
    assert "ph_notakeyatall" not in log
    assert '"GET /api/version?x=1&apikey=[redacted]" 200' in log
    assert '"GET /api/version?x=1&token=[redacted]" 200' in log
    assert "refused POST /api/files/local?apikey=[redacted]" in log


@pytest.mark.parametrize(
    ("target", "logged"),
    [
        ("/api/version?apikey=ph_abc", "/api/version?apikey=[redacted]"),
        ("/ws/printers/?token=ph_abc&last=4", "/ws/printers/?token=[redacted]&last=4"),
        (
            "/x?a=1&API_KEY=s3cret&password=hunter2",
            "/x?a=1&API_KEY=[redacted]&password=[redacted]",
        ),
        ("/printer/job/p1?a=list", "/printer/job/p1?a=list"),
        ("/printer/job/p1?monkey=1", "/printer/job/p1?monkey=1"),
    ],
)
def test_credentials_in_a_logged_url_are_redacted(target: str, logged: str) -> None:
    assert redact_target(target) == logged
