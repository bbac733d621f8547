"""numba and LLVM cost about 100 MB of memory: only a process that analyses a file
loads them, never the web server or a printer's worker."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent.parent

_PROBE = """
import sys
import django
django.setup()
import jobs.services, jobs.analysing, jobs.models, printhost.api.analysis
import printhost.urls, printers.consumers
from printers.worker import loop
print("numba" in sys.modules)
from jobs.analysis.analyser import Analyser
analyser = Analyser()
analyser.feed(b"G1 X1 Y1 E1\\nG1 X2 Y2 E2\\n")
analyser.finish()
print("numba" in sys.modules)
"""


def test_the_web_and_worker_modules_leave_numba_unloaded_until_an_analysis() -> None:
    done = subprocess.run(
        [sys.executable, "-c", _PROBE],
        cwd=ROOT,
        env={**os.environ, "DJANGO_SETTINGS_MODULE": "printhost.settings"},
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["False", "True"]
