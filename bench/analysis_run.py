"""One analyser on one file, in its own process (`bench/analysis.py` runs this).

    python -m bench.analysis_run printhost|reference FILE [REPEAT]

Prints one JSON line: seconds (all repeats), peak RSS in bytes, the figures, and
for printhost its start-up: the seconds its first analysis of a few lines took
before the timed ones (numba loading its compiled loops, once per process, as a
Celery worker does once for every file it reads after).
"""

from __future__ import annotations

import json
import resource
import sys
import tempfile
import time
from pathlib import Path

from bench import reference_analyser
from jobs.analysis.analyser import Analyser

#: A few lines that take every compiled loop of the analyser.
_SAMPLE = b"G1 X1 Y1 E1 F1800\nG1 X2 Y1.5 E2\nG1 X3 Y1 E3\nG1 X4 Y1.5 E4\n"


def start_up() -> float:
    """Seconds the first analysis of a few lines takes (numba's loops loaded)."""
    started = time.perf_counter()
    with tempfile.TemporaryFile() as sink:
        analyser = Analyser(toolpath=sink)
        analyser.feed(_SAMPLE)
        analyser.finish()
    return time.perf_counter() - started


def printhost(path: str) -> dict[str, object]:
    # As the Celery task does: the preview's toolpath written to a file as it reads.
    with tempfile.TemporaryFile() as sink:
        analyser = Analyser(toolpath=sink)
        with Path(path).open("rb") as handle:
            while chunk := handle.read(1 << 20):
                analyser.feed(chunk)
        found = analyser.finish()
    return {
        "toolpath_bytes": found.toolpath.get("bytes", 0),
        "motion_seconds": round(found.motion_seconds, 1),
        "heating_seconds": round(found.heating_seconds, 1),
        "filament_mm": round(found.filament_total, 1),
        "layers": len(found.layers),
        "thumbnails": len(analyser.pictures),
    }


def main() -> int:
    which, path = sys.argv[1], sys.argv[2]
    repeat = int(sys.argv[3]) if len(sys.argv) > 3 else 1
    analyse = printhost if which == "printhost" else reference_analyser.analyse
    warm = start_up() if which == "printhost" else 0.0
    started = time.perf_counter()
    for _ in range(repeat):
        figures = analyse(path)
    seconds = time.perf_counter() - started
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(
        json.dumps(
            {"seconds": seconds, "start_up": warm, "rss": rss, "figures": figures}
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
