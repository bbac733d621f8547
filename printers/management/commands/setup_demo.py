"""`manage.py setup_demo`: a demo admin and two simulated printers, if none exist.

The Marlin one has an SD card (a folder in the data directory) holding a demo file.
"""

from __future__ import annotations

import secrets
from pathlib import Path
from typing import Any

from django.conf import settings
from django.contrib.auth import get_user_model
from django.core.management.base import BaseCommand

from jobs.services import storage_dir
from printers.models import Printer
from printhost.access import issue_key
from printhost.models import UserProfile


def demo_gcode(size: float = 40.0, loops: int = 10) -> str:
    """A small square spiral, enough to watch a job stream on a simulator."""
    lines = ["; printhost demo: a square spiral", "G21", "G90", "G28", "G1 Z0.3 F1200"]
    for loop in range(loops):
        inset = loop * 1.5
        low, high = 10 + inset, 10 + size - inset
        for x, y in ((low, low), (high, low), (high, high), (low, high)):
            lines.append(f"G1 X{x:.2f} Y{y:.2f} F3000")
    lines.append("M84")
    return "\n".join(lines) + "\n"


class Command(BaseCommand):
    help = "Create a demo admin and two simulated printers (Marlin and GRBL) if none exist."

    def handle(self, *args: Any, **options: Any) -> None:
        if Printer.objects.exists():
            self.stdout.write("printers already exist; no demo printers added")
            self._admin(None)
            return
        links = Path(settings.DATA_DIR) / "sim"
        links.mkdir(parents=True, exist_ok=True)
        for slug, name, firmware, baud in (
            ("marlin-sim", "Marlin (simulated)", "marlin", 250000),
            ("grbl-sim", "GRBL (simulated)", "grbl", 115200),
        ):
            link = links / slug
            simulator = f"{firmware} --link {link} --baud {baud} --latency-ms 1"
            if firmware == "marlin":  # an SD card with a file on it
                card = links / f"{slug}-sd"
                card.mkdir(exist_ok=True)
                (card / "SQUARE.GCO").write_text(demo_gcode())
                simulator += f" --sd-dir {card}"
            printer = Printer.objects.create(
                name=name,
                slug=slug,
                firmware=firmware,
                port=str(link),
                baud=baud,
                simulator=simulator,
                pause_script="G91\nG1 Z5\nG90" if firmware == "marlin" else "",
            )
            (storage_dir(printer) / "demo-square.gcode").write_text(demo_gcode())
            self.stdout.write(f"added {printer}, simulated on {link}")
        self._admin(Printer.objects.get(slug="marlin-sim"))

    def _admin(self, default: Printer | None) -> None:
        """The demo admin; uploads without a printer in the URL go to *default*."""
        users = get_user_model()
        if users.objects.filter(username="admin").exists():
            self.stdout.write("demo admin exists (user: admin)")
            return
        password = secrets.token_urlsafe(9)
        admin = users.objects.create_superuser("admin", "admin@localhost", password)
        self.stdout.write(f"demo admin created: user admin, password {password}")
        if default is not None:
            UserProfile.objects.update_or_create(
                user=admin, defaults={"default_printer": default}
            )
        _, key = issue_key(admin, "demo (setup_demo)")
        self.stdout.write(f"demo API key (for curl and slicers; shown once): {key}")
        if default is not None:
            self.stdout.write(slicer_help(key, default.slug))


def slicer_help(key: str, slug: str, url: str = "http://127.0.0.1:8000") -> str:
    """What to type in the slicers to send jobs to the demo (the admin's default)."""
    return "\n".join(
        [
            f"send jobs from a slicer to {slug} (uploads on the bare address go there):",
            f"  PrusaSlicer / OrcaSlicer: Physical Printer > Host Type OctoPrint (or "
            f"Moonraker), Hostname {url}, API Key {key}",
            f"  Cura: OctoPrint Connection plugin, Add instance {url}, API key {key}",
            f"  another printer: {url}/p/<slug> as the address, for example "
            f"{url}/p/grbl-sim",
        ]
    )
