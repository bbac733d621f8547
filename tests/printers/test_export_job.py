"""export_job: the file driver writes exactly the bytes a print would send."""

from __future__ import annotations

import pytest
from django.core.management import CommandError, call_command

from printers.protocol.checksum import format_line

pytestmark = pytest.mark.django_db


def test_export_writes_numbered_checksummed_lines_after_m110(
    make_printer, make_job, tmp_path
):
    printer = make_printer()
    job = make_job(printer, "G28 ; home\n\nG1 X1 Y2\nM84\n")
    out = tmp_path / "out.gcode"

    call_command("export_job", str(job.pk), str(out), "--driver", "marlin")

    expected = [format_line(0, "M110 N0")]
    expected += [format_line(n, c) for n, c in enumerate(["G28", "G1 X1 Y2", "M84"], 1)]
    assert out.read_text().splitlines() == expected


def test_export_for_grbl_writes_compact_unnumbered_lines(
    make_printer, make_job, tmp_path
):
    printer = make_printer(firmware="grbl")
    job = make_job(printer, "G21\nG1 X1 Y2 F100\n")
    out = tmp_path / "out.nc"

    call_command("export_job", str(job.pk), str(out))

    assert out.read_text().splitlines() == ["G21", "G1X1Y2F100"]


def test_export_of_an_unknown_job_is_a_clear_error(db, tmp_path):
    with pytest.raises(CommandError, match="no job 999"):
        call_command("export_job", "999", str(tmp_path / "x"))
