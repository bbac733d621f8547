"""Who may do what: API keys, roles per printer, Cura's app-key pairing, the audit log."""

from __future__ import annotations

from django.conf import settings
from django.db import models

from jobs.models import Job
from printers.models import Printer


class Role(models.IntegerChoices):
    """Ordered: each role may do everything the ones below it may."""

    VIEWER = 10, "viewer (watch)"
    OPERATOR = 20, "operator (send commands, manage jobs)"
    ADMIN = 30, "admin (configure printers and users)"


class PrinterRole(models.Model):
    """A user's role on one printer, or on every printer when `printer` is empty."""

    user = models.ForeignKey(
        settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="printer_roles"
    )
    printer = models.ForeignKey(
        Printer,
        on_delete=models.CASCADE,
        null=True,
        blank=True,
        related_name="+",
        help_text="empty = every printer",
    )
    role = models.PositiveSmallIntegerField(choices=Role.choices, default=Role.VIEWER)

    class Meta:
        constraints = [
            models.UniqueConstraint(
                fields=["user", "printer"], name="printerrole_one_per_printer"
            ),
            models.UniqueConstraint(
                fields=["user"],
                condition=models.Q(printer__isnull=True),
                name="printerrole_one_global",
            ),
        ]

    def __str__(self) -> str:
        where = self.printer.slug if self.printer_id else "all printers"
        return f"{self.user} is {Role(self.role).label.split()[0]} on {where}"


class UserProfile(models.Model):
    """What printhost remembers per user: the printer an upload goes to by default."""

    user = models.OneToOneField(
        settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="printhost"
    )
    default_printer = models.ForeignKey(
        Printer, on_delete=models.SET_NULL, null=True, blank=True, related_name="+"
    )

    def __str__(self) -> str:
        return f"profile of {self.user}"


class ApiKey(models.Model):
    """A user's API key. Only a SHA-256 of the key is stored; the key is shown once.

    Keys are 160 random bits, so a plain hash is enough (nothing to brute-force);
    `prefix` finds the row without scanning and is safe to show.
    """

    user = models.ForeignKey(
        settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="api_keys"
    )
    name = models.CharField(max_length=100, help_text="what the key is for")
    prefix = models.CharField(max_length=16, unique=True)
    key_hash = models.CharField(max_length=64)
    printer = models.ForeignKey(
        Printer,
        on_delete=models.CASCADE,
        null=True,
        blank=True,
        related_name="+",
        help_text="bind the key to one printer (uploads go there; others are refused)",
    )
    #: The most this key may do: the user's role is capped at it (empty = no cap).
    role = models.PositiveSmallIntegerField(
        choices=Role.choices,
        null=True,
        blank=True,
        help_text="at most this role (empty = the user's own roles)",
    )
    created_at = models.DateTimeField(auto_now_add=True)
    last_used_at = models.DateTimeField(null=True, blank=True)
    revoked_at = models.DateTimeField(null=True, blank=True)

    class Meta:
        ordering = ["-created_at"]

    def __str__(self) -> str:
        return f"{self.name} ({self.prefix}…)"

    @property
    def active(self) -> bool:
        return self.revoked_at is None


class AppKeyRequest(models.Model):
    """OctoPrint's app-key pairing (Cura): an app asks, a user approves in the UI."""

    class State(models.TextChoices):
        PENDING = "pending", "pending"
        GRANTED = "granted", "granted"
        DENIED = "denied", "denied"
        EXPIRED = "expired", "expired"

    app = models.CharField(max_length=100)
    user_hint = models.CharField(max_length=150, blank=True)
    app_token = models.CharField(max_length=64, unique=True)
    user_token = models.CharField(max_length=64, unique=True)
    state = models.CharField(
        max_length=16, choices=State.choices, default=State.PENDING
    )
    api_key = models.ForeignKey(
        ApiKey, on_delete=models.SET_NULL, null=True, blank=True, related_name="+"
    )
    #: The printer the app asked through (`/p/<slug>/...`): its key is bound to it.
    printer = models.ForeignKey(
        Printer, on_delete=models.CASCADE, null=True, blank=True, related_name="+"
    )
    #: The granted key in clear, kept only until the app has fetched it once.
    handover = models.CharField(max_length=100, blank=True)
    created_at = models.DateTimeField(auto_now_add=True)
    polled_at = models.DateTimeField(auto_now_add=True)
    #: The requesting address (at most a few requests per address wait at once).
    origin = models.CharField(max_length=100, blank=True)

    class Meta:
        ordering = ["-created_at"]
        indexes = [
            # Counting the pending requests of one address (`appkeys.open_request`).
            models.Index(fields=["origin", "state"], name="appkeyrequest_origin_state"),
        ]

    def __str__(self) -> str:
        return f"{self.app} ({self.state})"


class AuditEntry(models.Model):
    """Who did what to which printer or job, from which client (ESP3D client types)."""

    time = models.DateTimeField(auto_now_add=True, db_index=True)
    user = models.ForeignKey(
        settings.AUTH_USER_MODEL,
        on_delete=models.SET_NULL,
        null=True,
        blank=True,
        related_name="+",
    )
    client = models.CharField(max_length=16, help_text="http, websocket, telnet, admin")
    origin = models.CharField(max_length=200, blank=True, help_text="address and key")
    action = models.CharField(max_length=50)
    printer = models.ForeignKey(
        Printer, on_delete=models.SET_NULL, null=True, blank=True, related_name="+"
    )
    job = models.ForeignKey(
        Job, on_delete=models.SET_NULL, null=True, blank=True, related_name="+"
    )
    detail = models.TextField(blank=True)

    class Meta:
        ordering = ["-time"]
        verbose_name_plural = "audit entries"

    def __str__(self) -> str:
        return f"{self.time:%Y-%m-%d %H:%M:%S} {self.user} {self.action}"


class LoginFailure(models.Model):
    """One failed password check, kept for the throttling window (`printhost.logins`).

    In the database, not a cache: printhost configures no shared cache, and every
    daphne process (and every host behind one database) must see the same counts.
    """

    time = models.DateTimeField(auto_now_add=True)
    #: As typed, case-folded: whether such a user exists is never looked up.
    username = models.CharField(max_length=150)
    address = models.CharField(max_length=64, blank=True)

    class Meta:
        indexes = [
            # Counting one user's and one address's recent failures at each login.
            models.Index(fields=["username", "time"], name="loginfailure_user_time"),
            models.Index(fields=["address", "time"], name="loginfailure_addr_time"),
        ]

    def __str__(self) -> str:
        return f"{self.time:%Y-%m-%d %H:%M:%S} {self.username} from {self.address}"
