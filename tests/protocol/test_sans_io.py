"""The protocol and stream-host packages stay sans-IO: no Django, no serial, no clock."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PURE = [ROOT / "printers" / "protocol", ROOT / "printers" / "streaming"]
FORBIDDEN_MODULES = {"django", "serial", "time", "threading", "socket", "logging", "os"}


def test_importing_the_protocols_loads_neither_django_nor_pyserial():
    code = (
        "import sys, printers.protocol, printers.streaming, printers.streaming.esp; "
        "bad = [m for m in ('django', 'serial') if m in sys.modules]; "
        "print(bad); sys.exit(1 if bad else 0)"
    )
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                          text=True, check=False)  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr


def test_pure_modules_import_no_io_module():
    offenders = []
    for folder in PURE:
        for path in folder.glob("*.py"):
            for node in ast.walk(ast.parse(path.read_text())):
                names = []
                if isinstance(node, ast.Import):
                    names = [alias.name for alias in node.names]
                elif isinstance(node, ast.ImportFrom) and node.module:
                    names = [node.module]
                offenders += [
                    f"{path.name}: {n}"
                    for n in names
                    if n.split(".")[0] in FORBIDDEN_MODULES
                ]
    assert offenders == []
