"""Marlin's fixed wording: boot banner, line errors, M115 capabilities, canned replies."""

from __future__ import annotations

__all__ = [
    "BOOT",
    "BOOT_NOISE",
    "ERR_CHECKSUM",
    "ERR_LINE_NO",
    "ERR_NO_CHECKSUM",
    "FIXED_REPLIES",
    "RRF_INFO",
    "SILENT",
    "VERSION",
    "firmware_info",
]

VERSION = "2.1.2.4"
UUID = "cede2a2f-41a2-4748-9b12-c55c62f367ff"

#: setup() output after a reset (the empty line is Marlin's too).
BOOT = (
    "start",
    f"echo:Marlin {VERSION}",
    "",
    "echo: Last Updated: 2024-06-20 | Author: (printhost simulator)",
    "echo:Compiled: Jun 20 2024",
    "echo: Free Memory: 2683  PlannerBufferBytes: 1600",
)

#: M115 of the reprapfirmware dialect (RepRapFirmware 3 answers in one line).
RRF_INFO = (
    "FIRMWARE_NAME: RepRapFirmware for Duet 3 MB6HC FIRMWARE_VERSION: 3.5.0 "
    "ELECTRONICS: Duet 3 MB6HC v1.01 FIRMWARE_DATE: 2024-04-19 (printhost simulator)"
)

#: What a bootloader or a UART waking up may put before `start` (no line end).
BOOT_NOISE = "\xfe\xff\x00"

# language.h: STR_ERR_LINE_NO, STR_ERR_CHECKSUM_MISMATCH, STR_ERR_NO_CHECKSUM.
ERR_LINE_NO = "Line Number is not Last Line Number+1, Last Line: "
ERR_CHECKSUM = "checksum mismatch, Last Line: "
ERR_NO_CHECKSUM = "No Checksum with line number, Last Line: "

#: Commands a stock build accepts and answers with a bare ok.
SILENT = (
    "M17",
    "M18",
    "M73",
    "M75",
    "M76",
    "M77",
    "M84",
    "M106",
    "M107",
    "M108",
    "M112",
    "M117",
    "M201",
    "M203",
    "M204",
    "M205",
    "M206",
    "M220",
    "M221",
    "M300",
    "M410",
    "M420",
    "M851",
    "M876",
    "M900",
    "M999",
)

FIXED_REPLIES: dict[str, tuple[str, ...]] = {
    "M500": ("echo:Settings Stored (662 bytes; crc 43524)",),
    "M501": ("echo:V86 stored settings retrieved (662 bytes; crc 43524)",),
    "M502": ("echo:Hardcoded Default Settings Loaded",),
    "M503": (
        "echo:; Linear Units:",
        "echo:  G21 ; (mm)",
        "echo:; Steps per unit:",
        "echo:  M92 X80.00 Y80.00 Z400.00 E93.00",
        "echo:; Maximum feedrates (units/s):",
        "echo:  M203 X300.00 Y300.00 Z5.00 E25.00",
    ),
}

_CAPABILITIES = (
    ("SERIAL_XON_XOFF", 0),
    ("BINARY_FILE_TRANSFER", 0),
    ("EEPROM", 1),
    ("VOLUMETRIC", 1),
    ("AUTOREPORT_POS", 0),
    ("AUTOREPORT_TEMP", 1),
    ("PROGRESS", 0),
    ("PRINT_JOB", 1),
    ("AUTOLEVEL", 0),
    ("RUNOUT", 0),
    ("Z_PROBE", 0),
    ("LEVELING_DATA", 0),
    ("BUILD_PERCENT", 0),
    ("SOFTWARE_POWER", 0),
    ("TOGGLE_LIGHTS", 0),
    ("CASE_LIGHT_BRIGHTNESS", 0),
    ("EMERGENCY_PARSER", None),
    ("HOST_ACTION_COMMANDS", 1),
    ("PROMPT_SUPPORT", 1),
    ("SDCARD", "sd"),
    ("AUTOREPORT_SD_STATUS", "sd"),
    ("LONG_FILENAME", "sd"),
    ("THERMAL_PROTECTION", 1),
    ("MOTION_MODES", 0),
    ("ARCS", 1),
    ("BABYSTEPPING", 0),
    ("CHAMBER_TEMPERATURE", 0),
    ("MEATPACK", 0),
)


def firmware_info(*, emergency_parser: bool, sd_card: bool = False) -> str:
    """M115's reply (before its ok), lines joined with newlines."""
    lines = [
        f"FIRMWARE_NAME:Marlin {VERSION} (printhost simulator) "
        "SOURCE_CODE_URL:github.com/MarlinFirmware/Marlin PROTOCOL_VERSION:1.0 "
        f"MACHINE_TYPE:printhost-sim EXTRUDER_COUNT:1 UUID:{UUID}"
    ]
    for name, value in _CAPABILITIES:
        on = int(emergency_parser) if value is None else value
        if value == "sd":
            on = int(sd_card)
        lines.append(f"Cap:{name}:{on}")
    return "\n".join(lines)
