"""Printers, the script/emergency queue rows other processes write, and the response log."""

from __future__ import annotations

from django.core.exceptions import ValidationError
from django.core.validators import MaxValueValidator, MinValueValidator, RegexValidator
from django.db import models

from printers.hosts import HostJSONField, WorkerHost
from printers.validators import (
    validate_build_volume,
    validate_motion_profile,
    validate_port,
    validate_script,
    validate_simulator,
    validate_tags,
)

_SLUG = RegexValidator(r"^[a-z0-9][a-z0-9_-]*$", "lowercase letters, digits, - and _")
#: Slugs no printer may take: `farm` is the farm queue's in upload URLs.
RESERVED_SLUGS = frozenset({"farm"})


class Printer(models.Model):
    """One machine on one port, driven by exactly one worker (the lease says which)."""

    class Firmware(models.TextChoices):
        MARLIN = "marlin", "Marlin"
        REPRAP = "reprap", "RepRapFirmware"
        REPETIER = "repetier", "Repetier firmware"
        GRBL = "grbl", "GRBL 1.1"

    class Checksums(models.TextChoices):
        ALWAYS = "always", "always"
        PRINTING = "printing", "only while printing"
        NEVER = "never", "never"

    class Flow(models.TextChoices):
        AUTO = "auto", "ping-pong until ADVANCED_OK is seen"
        PING_PONG = "ping_pong", "ping-pong (one command in flight)"
        BUFFERED = "buffered", "byte and line budget (Repetier-Host style)"

    class State(models.TextChoices):
        OFFLINE = "offline", "offline"
        CONNECTING = "connecting", "connecting"
        IDLE = "idle", "idle"
        PRINTING = "printing", "printing"
        PAUSED = "paused", "paused"
        WAITSTART = "waitstart", "waiting for the bed to be cleared"
        ERROR = "error", "error"

    name = models.CharField(max_length=100)
    slug = models.SlugField(max_length=50, unique=True, validators=[_SLUG])
    enabled = models.BooleanField(default=True, help_text="runhost starts a worker")
    port = models.CharField(
        max_length=255,
        validators=[validate_port],
        help_text="/dev/ttyUSB0, /dev/serial/by-id/..., a simulator's link in the data "
        "directory, or socket://host:port / rfc2217://host:port to a host listed in "
        "PRINTHOST_PORT_HOSTS",
    )
    baud = models.PositiveIntegerField(default=115200)
    firmware = models.CharField(
        max_length=16, choices=Firmware.choices, default=Firmware.MARLIN
    )
    checksums = models.CharField(
        max_length=16, choices=Checksums.choices, default=Checksums.PRINTING
    )
    flow = models.CharField(max_length=16, choices=Flow.choices, default=Flow.AUTO)
    rx_buffer = models.PositiveIntegerField(
        default=127,
        validators=[MinValueValidator(16), MaxValueValidator(65536)],
        help_text="bytes the firmware's serial receive buffer holds (window budget)",
    )
    bufsize = models.PositiveIntegerField(
        default=4,
        validators=[MinValueValidator(1), MaxValueValidator(256)],
        help_text="commands the firmware queues (Marlin BUFSIZE)",
    )
    max_line_length = models.PositiveIntegerField(
        default=0, help_text="longest command line; 0 = the firmware's default"
    )
    ack_timeout = models.FloatField(default=10.0, validators=[MinValueValidator(0.1)])
    busy_timeout = models.FloatField(default=30.0, validators=[MinValueValidator(0.1)])
    max_resends = models.PositiveIntegerField(default=10)
    temperature_interval = models.FloatField(
        default=2.0, help_text="seconds between temperature reports (0 = off)"
    )
    status_interval = models.FloatField(
        default=0.2, help_text="GRBL: seconds between `?` status polls (0 = off)"
    )
    connect_script = models.TextField(blank=True, validators=[validate_script])
    start_script = models.TextField(
        blank=True, validators=[validate_script], help_text="runs before each job"
    )
    end_script = models.TextField(
        blank=True, validators=[validate_script], help_text="runs after a completed job"
    )
    pause_script = models.TextField(blank=True, validators=[validate_script])
    resume_script = models.TextField(blank=True, validators=[validate_script])
    abort_script = models.TextField(blank=True, validators=[validate_script])
    quickstop_on_abort = models.BooleanField(
        default=False,
        help_text="Marlin: a job that is aborted or fails gets M410 (quickstop) ahead "
        "of the abort script, so the moves in the planner (seconds of motion, a "
        "laser's beam or a spindle's cut among them) stop where the tool is. Marlin "
        "may lose steps stopping mid-move: home in the abort script before moving "
        "again. For lasers and CNC; off, the planned moves run out (as OctoPrint "
        "does)",
    )
    auto_start = models.BooleanField(
        default=False, help_text="start the next job without waiting for a clear bed"
    )
    response_log_limit = models.PositiveIntegerField(
        default=20000, help_text="response lines kept in the database"
    )
    job_file_days = models.PositiveIntegerField(
        default=30,
        help_text="days a finished job's file is kept after it ends (0 = forever); "
        "the job stays in the history; a file a queued job uses, or an interrupted "
        "run not resumed yet, is kept",
    )
    resume_home_z = models.BooleanField(
        default=False,
        help_text="resuming a print homes Z too (off: the part is on the bed; the "
        "nozzle is taken to be where the interrupted print left it)",
    )
    resume_lift_mm = models.FloatField(
        default=5.0,
        help_text="how far a resume raises Z above the part before moving over it",
    )
    simulator = models.CharField(
        max_length=255,
        blank=True,
        validators=[validate_simulator],
        help_text="simulate_printer arguments; runhost starts this simulator (its "
        "--link, --record and --control paths inside the data directory)",
    )
    terminal_port = models.PositiveIntegerField(
        null=True,
        blank=True,
        unique=True,
        validators=[MinValueValidator(1), MaxValueValidator(65535)],
        help_text="TCP port of the raw terminal (socket://host:port; API key as the "
        "first line); empty = no terminal",
    )
    motion_profile = models.JSONField(
        default=dict,
        blank=True,
        validators=[validate_motion_profile],
        help_text="the firmware's motion limits for time estimates, overriding its "
        'defaults: e.g. {"max_acceleration": [1000, 1000, 200, 5000], '
        '"print_acceleration": 1000, "classic_jerk": true, "jerk": [8, 8, 0.4, 5]} '
        "(mm, s; axes X Y Z E). The file's own M201-M205 still apply.",
    )
    filament_diameter = models.FloatField(
        default=1.75, validators=[MinValueValidator(0.1), MaxValueValidator(10)]
    )
    filament_density = models.FloatField(
        default=1.24,
        validators=[MinValueValidator(0.1), MaxValueValidator(25)],
        help_text="g/cm³ (PLA 1.24, PETG 1.27, ABS 1.04); a file's own value wins",
    )

    # -- the farm: where the printer runs and what a farm job may ask of it --------
    worker_host = models.ForeignKey(
        WorkerHost,
        on_delete=models.PROTECT,
        null=True,
        blank=True,
        related_name="printer_set",
        help_text="the worker host the printer is plugged into (runhost --worker-host "
        "NAME runs its worker); empty = the control plane's own runhost",
    )
    farm = models.BooleanField(
        default=True, help_text="the farm queue may give this printer jobs"
    )
    profile = models.CharField(
        max_length=100,
        blank=True,
        help_text="printer profile a farm job may ask for (e.g. MK4, Voron 2.4 350)",
    )
    tags = models.JSONField(
        default=list,
        blank=True,
        validators=[validate_tags],
        help_text='words a farm job may ask for, e.g. ["enclosed", "hardened"]',
    )
    build_volume = models.JSONField(
        default=dict,
        blank=True,
        validators=[validate_build_volume],
        help_text='{"min": [x, y, z], "max": [x, y, z]} in mm: a farm job\'s analysed '
        "bounding box must fit in it; {} = unknown (no farm job fits)",
    )
    #: What is loaded, set by operators (UI, API) or by the firmware's reports.
    material = models.CharField(
        max_length=32, blank=True, help_text="loaded material (PLA, PETG, ...)"
    )
    colour = models.CharField(max_length=32, blank=True, help_text="loaded colour")
    nozzle_diameter = models.FloatField(
        null=True,
        blank=True,
        validators=[MinValueValidator(0.05), MaxValueValidator(5)],
        help_text="mm",
    )
    loaded_by = models.CharField(
        max_length=100, blank=True, help_text="who set the loaded material last"
    )
    loaded_at = models.DateTimeField(null=True, blank=True)

    # Written by the worker only.
    state = models.CharField(
        max_length=16, choices=State.choices, default=State.OFFLINE
    )
    state_message = models.TextField(blank=True)
    #: An emergency stop's halt (printers/worker/emergency.py) until an operator's
    #: reconnect ends it: kept here so a worker started again keeps it too.
    emergency_halt = models.TextField(blank=True, editable=False)
    firmware_name = models.CharField(max_length=255, blank=True)
    capabilities = HostJSONField(default=dict, blank=True)
    temperatures = HostJSONField(default=dict, blank=True)
    machine_status = HostJSONField(default=dict, blank=True)
    #: The printer's own SD card as its last M20 listed it: {"present", "files":
    #: [{"name", "size", "long_name"}], "listed" (ISO time), "message"}.
    sd_card = HostJSONField(default=dict, blank=True)
    lease_owner = models.CharField(max_length=100, blank=True)
    lease_expires_at = models.DateTimeField(null=True, blank=True)
    worker_seen_at = models.DateTimeField(null=True, blank=True)
    #: The link's figures, saved with the status about once a second: {"at",
    #: "connected_at" (ISO), "lines_sent", "lines_acked", "resends", "timeouts",
    #: "bytes_sent", "bytes_received" (since the connect), "rtt_ms" (mean ack round
    #: trip), "lines_per_s", "link_use" (0..1: bits sent over what the baud rate
    #: carries; both over the last few seconds), "cpu_s" (the worker's CPU seconds)}.
    link_stats = HostJSONField(default=dict, blank=True)

    class Meta:
        ordering = ["name"]

    def __str__(self) -> str:
        return f"{self.name} ({self.slug})"

    def clean(self) -> None:
        """`farm` names the farm queue in upload URLs (/printer/job/farm, /p/farm/);
        the quickstop is Marlin's M410."""
        if self.slug in RESERVED_SLUGS:
            raise ValidationError(
                {"slug": f"{self.slug!r} is reserved for the farm queue"},
                code="reserved",
            )
        if self.quickstop_on_abort and self.firmware != self.Firmware.MARLIN:
            raise ValidationError(
                {
                    "quickstop_on_abort": "the quickstop is Marlin's M410: GRBL holds "
                    "and resets on an abort by itself; other firmware runs the abort "
                    "script"
                },
                code="marlin_only",
            )

    @property
    def is_grbl(self) -> bool:
        return self.firmware == self.Firmware.GRBL

    def scripts(self) -> dict[str, str]:
        """The printer's scripts by name, as the stream host takes them."""
        return {
            "connect": self.connect_script,
            "start": self.start_script,
            "end": self.end_script,
            "pause": self.pause_script,
            "resume": self.resume_script,
            "abort": self.abort_script,
        }


class QueuedCommand(models.Model):
    """A request written by any client for the printer's worker: the database queue.

    Commands go to the script queue, emergencies out ahead of everything, actions
    (pause, resume, abort, clear the bed, reconnect) to the stream controller.
    """

    class Kind(models.TextChoices):
        COMMAND = "command", "command"
        EMERGENCY = "emergency", "emergency"
        ACTION = "action", "action"

    class Action(models.TextChoices):
        PAUSE = "pause", "pause"
        RESUME = "resume", "resume"
        ABORT = "abort", "abort"
        BED_CLEAR = "bed_clear", "bed is clear"
        RECONNECT = "reconnect", "reconnect"
        DISCONNECT = "disconnect", "disconnect"
        #: `prompt:<n>`: answer the firmware's host prompt with button n (M876).
        PROMPT = "prompt", "answer the printer's prompt"
        #: Read the printer's SD card listing again (M20).
        SD_LIST = "sd_list", "list the SD card"
        #: `sd_delete:<name>`: delete a file from the printer's SD card (M30).
        SD_DELETE = "sd_delete", "delete from the SD card"

    class State(models.TextChoices):
        PENDING = "pending", "pending"
        SENT = "sent", "sent"
        DONE = "done", "done"
        FAILED = "failed", "failed"

    printer = models.ForeignKey(Printer, on_delete=models.CASCADE, related_name="+")
    kind = models.CharField(max_length=16, choices=Kind.choices, default=Kind.COMMAND)
    text = models.TextField()
    origin = models.CharField(max_length=100, blank=True, help_text="who asked")
    state = models.CharField(
        max_length=16, choices=State.choices, default=State.PENDING
    )
    reply = models.TextField(blank=True)
    created_at = models.DateTimeField(auto_now_add=True)
    done_at = models.DateTimeField(null=True, blank=True)

    class Meta:
        ordering = ["id"]
        indexes = [
            # Used by the worker's poll: the pending requests of one printer.
            models.Index(
                fields=["printer", "id"],
                name="queuedcommand_pending",
                condition=models.Q(state="pending"),
            )
        ]

    def __str__(self) -> str:
        return f"{self.kind} {self.text!r} -> {self.printer_id}"


class ResponseLine(models.Model):
    """One line of Repetier's response log: ids increase per printer, `kind` is a filter bit."""

    # No index of its own: the unique (printer, seq) below starts with it, and
    # every line stored would keep a second index up to date for nothing.
    printer = models.ForeignKey(
        Printer, on_delete=models.CASCADE, related_name="+", db_index=False
    )
    seq = models.BigIntegerField()
    time = models.DateTimeField()
    text = models.TextField()
    kind = models.PositiveSmallIntegerField(
        help_text="1 command, 2 ack, 4 other response, 8 non-maskable"
    )

    class Meta:
        ordering = ["printer", "seq"]
        constraints = [
            # Reading `?start=<id>` walks this index; pruning deletes below a seq.
            models.UniqueConstraint(fields=["printer", "seq"], name="responseline_seq")
        ]

    def __str__(self) -> str:
        return f"{self.seq}: {self.text}"


class TemperatureSample(models.Model):
    """One temperature reading of a printer, kept for a day: the printer page's chart.

    The worker writes one when it saves temperatures, at most every few seconds
    (`printers/worker/status.py`); the upkeep deletes those older than
    PRINTHOST_TEMPERATURE_KEEP_HOURS (`printers/upkeep.py`).
    """

    printer = models.ForeignKey(Printer, on_delete=models.CASCADE, related_name="+")
    time = models.DateTimeField()
    temperatures = HostJSONField(default=dict)

    class Meta:
        ordering = ["printer", "time"]
        indexes = [
            # Used by GET /printer/temperatures/<slug> (a time range of one printer)
            # and by the upkeep's pruning.
            models.Index(fields=["printer", "time"], name="temperaturesample_time")
        ]

    def __str__(self) -> str:
        return f"{self.printer_id} {self.time:%H:%M:%S}"
