"""The farm page's first render: the queue, and the printers by worker host and by
material.

It shows what `GET /printer/farm` answers (`printhost.api.farm.overview`), grouped
for people. Its script (`static/printhost/farm.js`) acts through the same API
(cancel, priority, what a printer has loaded) and refreshes the page's live parts
every few seconds.
"""

from __future__ import annotations

from collections import defaultdict
from datetime import datetime
from typing import TYPE_CHECKING, Any

from printers.hosts import load_figures
from printers.models import Printer
from printhost.api.farm import overview
from printhost.models import Role

if TYPE_CHECKING:
    from printhost.access import Caller

#: The group of printers that name no worker host: the control plane runs them.
LOCAL_HOST = "this server"


def age_text(seconds: float | None) -> str:
    """`4 s ago`, `3 min ago`, `2 h ago`, or `never`."""
    if seconds is None:
        return "never"
    if seconds < 60:
        return f"{seconds:.0f} s ago"
    if seconds < 3600:
        return f"{seconds / 60:.0f} min ago"
    return f"{seconds / 3600:.0f} h ago"


def when_text(value: str | None) -> str:
    """An ISO time as `2026-05-01 18:00` in the server's zone ("" when none)."""
    if not value:
        return ""
    return datetime.fromisoformat(value).astimezone().strftime("%Y-%m-%d %H:%M")


def loaded_text(printer: dict[str, Any]) -> str:
    """`red PETG, 0.6 mm` or `nothing set`."""
    words = " ".join(w for w in (printer["colour"], printer["material"]) if w)
    nozzle = printer["nozzle_diameter"]
    parts = [words, f"{nozzle:g} mm nozzle" if nozzle else ""]
    return ", ".join(p for p in parts if p) or "nothing set"


def host_groups(
    printers: list[dict[str, Any]], hosts: list[dict[str, Any]]
) -> list[dict[str, Any]]:
    """Printers under their worker host (with its heartbeat), the control plane's
    own printers first; hosts without printers are listed too."""
    by_host: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for printer in printers:
        by_host[printer["host"]].append(printer)
    groups = []
    if by_host.get(""):
        groups.append({"name": LOCAL_HOST, "local": True, "printers": by_host[""]})
    for host in hosts:
        average, cpus = load_figures(host.get("load"))
        groups.append(
            {
                "name": host["name"],
                "local": False,
                "online": host["online"],
                "age": age_text(host["heartbeat_age"]),
                "version": host["version"],
                "load": "" if average is None else f"{average:.2f}",
                "cpus": cpus,
                "clock_warning": host.get("clock_warning", ""),
                "printers": by_host.get(host["name"], []),
            }
        )
    return groups


def material_groups(printers: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Farm printers by what they have loaded (material and colour), most first."""
    by_material: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for printer in printers:
        if printer["farm"]:
            words = " ".join(w for w in (printer["colour"], printer["material"]) if w)
            by_material[words or "nothing set"].append(printer)
    return [
        {"material": name, "printers": members}
        for name, members in sorted(
            by_material.items(), key=lambda i: (-len(i[1]), i[0])
        )
    ]


def farm_context(caller: Caller) -> dict[str, Any]:
    """What the page shows; `operator` says whether the caller may change the queue,
    and each printer's `can_load` whether they may set what it has loaded."""
    data = overview()
    operable = {p.slug for p in caller.printers(Role.OPERATOR)}
    printers = data["printers"]
    for printer in printers:
        printer["loaded_text"] = loaded_text(printer)
        printer["can_load"] = printer["slug"] in operable
        printer["loaded_when"] = when_text(printer["loaded_at"])
        # The state's badge already says printing, waiting for the bed, offline...
        idle = printer["state"] == Printer.State.IDLE
        printer["note"] = printer["busy"] if idle else ""
    for job in data["jobs"]:
        job["deadline_text"] = when_text(job["deadline"])
    waiting = [j for j in data["jobs"] if j["state"] == "waiting"]
    return {
        "jobs": data["jobs"],
        "waiting": len(waiting),
        "free": sum(1 for p in printers if p["farm"] and p["free"]),
        "farm_printers": sum(1 for p in printers if p["farm"]),
        "hosts": host_groups(printers, data["hosts"]),
        "materials": material_groups(printers),
        "operator": caller.can(None, Role.OPERATOR) and caller.bound_printer_id is None,
        "states": dict(Printer.State.choices),
    }
