"""The production samples in docs/deploy/ hold up: `check --deploy` is clean with the
example settings, every setting printhost reads is in the example, and the systemd
units name only commands and options that exist."""

from __future__ import annotations

import ast
import configparser
import os
import re
import secrets
import shlex
import subprocess
import sys
from pathlib import Path

from tests.conftest import ROOT

DEPLOY = ROOT / "docs" / "deploy"
ENV_EXAMPLE = DEPLOY / "printhost.env.example"
UNITS = sorted((DEPLOY / "systemd").glob("*.service"))
#: Set by runhost for its own children, not by a deployment.
NOT_DEPLOYMENT_SETTINGS = {"PRINTHOST_WORKER_HOST", "PRINTHOST_WEB_APPS"}
#: What the units' specifiers stand for in these tests.
SPECIFIERS = {"%i": "8001", "%H": "farmhost"}
OPTION = re.compile(r"^--?[A-Za-z][\w-]*$")


def example_values() -> dict[str, str]:
    """The example env file's uncommented NAME=value lines."""
    values = {}
    for line in ENV_EXAMPLE.read_text().splitlines():
        if line.strip() and not line.lstrip().startswith("#"):
            name, _, value = line.partition("=")
            values[name.strip()] = value
    return values


def manage(env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "manage.py", *args], cwd=ROOT, env=env,
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip


def deployment_env(tmp_path: Path, **overrides: str) -> dict[str, str]:
    """The example's values over a clean environment, with a real secret key and a
    data directory in the test's folder (the example's is the server's)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("PRINTHOST_")}
    env.pop("DATABASE_URL", None)
    env.pop("REDIS_URL", None)
    env |= example_values()
    env |= {
        "PRINTHOST_SECRET_KEY": secrets.token_urlsafe(50),
        "PRINTHOST_DATA_DIR": str(tmp_path),
        **overrides,
    }
    return env


def test_check_deploy_is_clean_with_the_example_settings(tmp_path):
    result = manage(
        deployment_env(tmp_path), "check", "--deploy", "--fail-level", "WARNING"
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert "no issues" in result.stdout


def test_check_deploy_fails_without_https_or_with_a_weak_key(tmp_path):
    plain = deployment_env(tmp_path, PRINTHOST_HTTPS="0", PRINTHOST_SECRET_KEY="short")
    result = manage(plain, "check", "--deploy", "--fail-level", "WARNING")
    assert result.returncode != 0
    for warning in ("security.W004", "security.W008", "security.W009", "security.W012"):
        assert warning in result.stderr + result.stdout


def test_an_empty_secret_key_stops_the_start_with_how_to_make_one(tmp_path):
    result = manage(deployment_env(tmp_path, PRINTHOST_SECRET_KEY=""), "check")
    assert result.returncode != 0
    assert "PRINTHOST_SECRET_KEY is empty" in result.stderr
    assert "token_urlsafe(50)" in result.stderr


def settings_read() -> set[str]:
    """Every variable printhost/settings.py reads through printhost.env."""
    tree = ast.parse((ROOT / "printhost" / "settings.py").read_text())
    return {
        node.args[0].value
        for node in ast.walk(tree)
        if isinstance(node, ast.Call)
        and getattr(node.func, "id", "").startswith("env_")
        and node.args
        and isinstance(node.args[0], ast.Constant)
    }


def test_every_setting_a_deployment_may_need_is_in_the_example():
    documented = set(
        re.findall(r"^#?\s*([A-Z][A-Z0-9_]+)=", ENV_EXAMPLE.read_text(), re.M)
    )
    names = settings_read()
    assert len(names) > 40
    missing = names - NOT_DEPLOYMENT_SETTINGS - documented
    assert not missing, (
        f"add these to {ENV_EXAMPLE.name} with a comment: {sorted(missing)}"
    )
    unknown = documented - names
    assert not unknown, (
        f"the example sets what printhost never reads: {sorted(unknown)}"
    )


def exec_start(unit: Path) -> list[str]:
    parser = configparser.ConfigParser(interpolation=None, strict=False)
    parser.optionxform = str  # type: ignore[assignment]
    parser.read_string(unit.read_text())
    service = parser["Service"]
    assert service["EnvironmentFile"] == "/etc/printhost/printhost.env"
    assert service["WorkingDirectory"] == "/opt/printhost"
    assert "WantedBy" in parser["Install"]
    line = service["ExecStart"]
    for specifier, value in SPECIFIERS.items():
        line = line.replace(specifier, value)
    argv = shlex.split(line)
    assert argv[0] == "/opt/printhost/.venv/bin/python", argv
    return argv[1:]


def help_commands(argv: list[str]) -> list[tuple[tuple[str, ...], list[str]]]:
    """(the help command, the options it must list) for one unit's command line.

    `manage.py <command> ...`, `-m celery [global options] <command> ...` and
    `-m printhost.serve ...` are the three kinds the units use.
    """
    if argv[0] == "manage.py":
        return [(("manage.py", argv[1], "--help"), argv[2:])]
    if argv[:2] == ["-m", "celery"]:
        rest, at = argv[2:], 0
        while rest[at].startswith("-"):  # global options; --app takes a value
            at += 2 if rest[at] in ("--app", "-A") else 1
        return [
            (("-m", "celery", "--help"), rest[:at]),
            (("-m", "celery", rest[at], "--help"), rest[at + 1 :]),
        ]
    if argv[:2] == ["-m", "printhost.serve"]:
        return [(("-m", "printhost.serve", "--help"), argv[2:])]
    raise AssertionError(f"a unit runs something the test does not know: {argv}")


def helps(env: dict[str, str], commands: set[tuple[str, ...]]) -> dict[tuple, str]:
    """Each command's --help text, the commands run at once (each starts Django)."""
    runs = {
        command: subprocess.Popen(
            [sys.executable, *command], cwd=ROOT, env=env, text=True,
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
        )
        for command in commands
    }  # fmt: skip
    texts = {}
    for command, run in runs.items():
        texts[command] = run.communicate(timeout=120)[0]
        assert run.returncode == 0, f"{command}: {texts[command]}"
    return texts


def lists(text: str, option: str) -> bool:
    return re.search(rf"(^|[\s,]){re.escape(option)}\b", text) is not None


def test_the_units_name_only_commands_and_options_that_exist(tmp_path):
    checks = {unit.name: help_commands(exec_start(unit)) for unit in UNITS}
    texts = helps(
        deployment_env(tmp_path), {c for found in checks.values() for c, _ in found}
    )
    missing = []
    for name, found in checks.items():
        for command, arguments in found:
            options = [a.split("=", 1)[0] for a in arguments]
            missing += [
                f"{name}: {' '.join(command[:-1])} has no {option}"
                for option in options
                if OPTION.match(option) and not lists(texts[command], option)
            ]
    assert not missing
    # The check itself: an option that does not exist is caught.
    runhost = texts[("manage.py", "runhost", "--help")]
    assert lists(runhost, "--no-workers")
    assert not lists(runhost, "--no-such-option")


def test_the_units_cover_the_control_plane_celery_and_a_worker_host():
    commands = {unit.name: " ".join(exec_start(unit)) for unit in UNITS}
    assert "runhost --no-workers" in commands["printhost-control.service"]
    assert "--worker-host 8001" in commands["printhost-host@.service"]
    assert (
        "celery --quiet --app printhost worker" in commands["printhost-celery.service"]
    )
    assert "beat" in commands["printhost-celery-beat.service"]
