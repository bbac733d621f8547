"""An app that speaks OctoPrint drives printhost: pyoctoprintapi (the client library
of Home Assistant's OctoPrint integration) against a running server over real HTTP,
on a simulated Marlin: server, printer and job info, temperatures, pause, resume
and cancel of a print, disconnect and connect."""

from __future__ import annotations

import asyncio
from typing import TYPE_CHECKING

import pytest

from tests.conftest import wait_for
from tests.hosts import Host, import_or_skip

if TYPE_CHECKING:
    from pathlib import Path

pytestmark = pytest.mark.slow

SLUG = "mk3"
#: A print of a minute or so at the simulator's speed: long enough to pause.
LONG = "G28\nG1 Z0.3 F600\n" + "".join(
    f"G1 X{10 + i % 50} Y{10 + (i * 7) % 50} F3000\n" for i in range(400)
)


def job_state(host: Host) -> list[tuple]:
    return host.query("SELECT state FROM jobs_job ORDER BY id")


def test_pyoctoprintapi_reads_and_controls_the_printer(tmp_path: Path) -> None:
    import_or_skip("pyoctoprintapi")
    aiohttp = import_or_skip("aiohttp")
    from pyoctoprintapi import OctoprintClient

    host = Host(tmp_path)
    host.migrate()
    record = host.add_simulated_printer(SLUG, sim_args="--time-scale 0.05")
    key = host.add_user("homeassistant", "operator")
    job = tmp_path / "long.gcode"
    job.write_text(LONG)

    async def drive(port: int) -> dict:
        seen: dict = {}
        async with aiohttp.ClientSession() as session:
            client = OctoprintClient("127.0.0.1", session, port, False, f"/p/{SLUG}/")
            client.set_api_key(key)
            seen["server"] = await client.get_server_info()
            seen["printer"] = await client.get_printer_info()
            await client.set_tool_temperature("tool0", 200)
            await client.set_bed_temperature(60)
            host.manage("add_job", SLUG, str(job))
            await asyncio.to_thread(
                wait_for, lambda: job_state(host) == [("printing",)], 60, "the print"
            )
            seen["job"] = await client.get_job_info()
            await client.pause_job()
            await asyncio.to_thread(
                wait_for, lambda: job_state(host) == [("paused",)], 30, "the pause"
            )
            await client.resume_job()
            await asyncio.to_thread(
                wait_for, lambda: job_state(host) == [("printing",)], 30, "the resume"
            )
            await client.cancel_job()
            await asyncio.to_thread(
                wait_for, lambda: job_state(host) == [("aborted",)], 30, "the cancel"
            )
            await client.disconnect()
            await asyncio.to_thread(
                wait_for,
                lambda: host.query("SELECT state FROM printers_printer") == [("offline",)],
                30, "the disconnect",
            )  # fmt: skip
            await client.connect()
            # Connected again, and waiting for the bed to be cleared after the cancel.
            await asyncio.to_thread(
                wait_for,
                lambda: host.query("SELECT state FROM printers_printer")
                in ([("idle",)], [("waitstart",)]),
                60, "the connect",
            )  # fmt: skip
        return seen

    with host.running():
        wait_for(
            lambda: host.query("SELECT state FROM printers_printer") == [("idle",)],
            60, f"the printer to connect:\n{host.log_tail()}",
        )  # fmt: skip
        seen = asyncio.run(drive(host.port))
    assert seen["server"].version
    assert seen["printer"].state.flags.operational
    assert seen["job"].job.file.name == "long.gcode"
    text = record.read_text()
    assert "M104 T0 S200" in text
    assert "M140 S60" in text
