"""Django settings for printhost, read from PRINTHOST_* / DATABASE_URL / REDIS_URL."""

from __future__ import annotations

from pathlib import Path

import dj_database_url
from django.core.exceptions import ImproperlyConfigured

from printhost.env import env_bool, env_float, env_list, env_positive, env_str
from printhost.logformat import FORMATTERS

BASE_DIR = Path(__file__).resolve().parent.parent

#: Where jobs, the SQLite database and simulator links live unless told otherwise.
DATA_DIR = Path(env_str("PRINTHOST_DATA_DIR", str(BASE_DIR / "var"))).resolve()
#: Uploaded job files, one folder per printer (`/sd/` and `/fs/` in [ESP700]).
JOB_STORAGE_DIR = Path(env_str("PRINTHOST_JOB_DIR", str(DATA_DIR / "jobs"))).resolve()
DATA_DIR.mkdir(parents=True, exist_ok=True)

DEBUG = env_bool("PRINTHOST_DEBUG", default=False)
SECRET_KEY = env_str(
    "PRINTHOST_SECRET_KEY", "printhost-insecure-development-key-change-me"
)
if not SECRET_KEY.strip():
    # An env file with the line left empty: stop now, not at the first login.
    raise ImproperlyConfigured(
        "PRINTHOST_SECRET_KEY is empty: set it to 50+ random characters, e.g. "
        '`python -c "import secrets; print(secrets.token_urlsafe(50))"`'
    )
ALLOWED_HOSTS = env_list("PRINTHOST_ALLOWED_HOSTS", ["127.0.0.1", "localhost", "[::1]"])
CSRF_TRUSTED_ORIGINS = env_list("PRINTHOST_CSRF_TRUSTED_ORIGINS", [])

# Behind HTTPS (directly or through a proxy that sets X-Forwarded-Proto), cookies are
# secure-only and browsers are told to stay on HTTPS. A print server on a home LAN
# often has no certificate, so this is opt-in; `check --deploy` is clean with it on.
HTTPS = env_bool("PRINTHOST_HTTPS", default=False)
if HTTPS:
    SECURE_SSL_REDIRECT = True
    SESSION_COOKIE_SECURE = True
    CSRF_COOKIE_SECURE = True
    SECURE_HSTS_SECONDS = int(env_float("PRINTHOST_HSTS_SECONDS", 31536000))
    SECURE_HSTS_INCLUDE_SUBDOMAINS = True
    SECURE_HSTS_PRELOAD = True
    # A Prometheus on the control plane itself may scrape daphne directly over
    # loopback HTTP (a redirect to HTTPS would fail it); the proxy redirects the rest.
    SECURE_REDIRECT_EXEMPT = [r"^metrics$"]
if env_bool("PRINTHOST_BEHIND_PROXY", default=False):
    SECURE_PROXY_SSL_HEADER = ("HTTP_X_FORWARDED_PROTO", "https")
X_FRAME_OPTIONS = "DENY"

#: Apps only a process that serves pages needs: daphne's `runserver` and the API
#: docs pages of django-ninja (their templates and static files). runhost starts
#: its other children (printer workers, Celery, the fetcher...) with
#: PRINTHOST_WEB_APPS=0: a printer worker then starts in about half the CPU time
#: and with two thirds of the memory (no Twisted, no pydantic).
WEB_APPS = env_bool("PRINTHOST_WEB_APPS", default=True)

INSTALLED_APPS = [
    *(["daphne"] if WEB_APPS else []),  # before staticfiles (daphne's check)
    "django.contrib.admin",
    "django.contrib.auth",
    "django.contrib.contenttypes",
    "django.contrib.sessions",
    "django.contrib.messages",
    "django.contrib.staticfiles",
    "channels",
    *(["ninja"] if WEB_APPS else []),
    "printhost",
    "printers",
    "jobs",
]

MIDDLEWARE = [
    # First: it times everything below it (printhost/metrics_web.py).
    "printhost.metrics_web.request_latency",
    "printhost.slashes.collapse_slashes",
    "printhost.shared_clock.learn_clock_offset",
    "django.middleware.security.SecurityMiddleware",
    "django.contrib.sessions.middleware.SessionMiddleware",
    "django.middleware.common.CommonMiddleware",
    "django.middleware.csrf.CsrfViewMiddleware",
    "django.contrib.auth.middleware.AuthenticationMiddleware",
    "django.contrib.messages.middleware.MessageMiddleware",
    "django.middleware.clickjacking.XFrameOptionsMiddleware",
]

ROOT_URLCONF = "printhost.urls"
WSGI_APPLICATION = None
ASGI_APPLICATION = "printhost.asgi.application"

TEMPLATES = [
    {
        "BACKEND": "django.template.backends.django.DjangoTemplates",
        "DIRS": [BASE_DIR / "templates"],
        "APP_DIRS": True,
        "OPTIONS": {
            "context_processors": [
                "django.template.context_processors.request",
                "django.contrib.auth.context_processors.auth",
                "django.contrib.messages.context_processors.messages",
            ],
        },
    },
]

# SQLite by default: WAL lets the web process read while a worker writes, and the
# busy timeout makes a writer wait for the lock instead of failing at once.
_SQLITE_URL = f"sqlite:///{DATA_DIR / 'printhost.sqlite3'}"
DATABASES = {
    "default": dj_database_url.parse(
        env_str("DATABASE_URL", _SQLITE_URL), conn_max_age=0
    )
}
if DATABASES["default"]["ENGINE"] == "django.db.backends.postgresql":
    _pg_options = DATABASES["default"].setdefault("OPTIONS", {})
    # A database that went away must fail a connection in seconds, not hang a
    # worker's loop (libpq waits forever by default).
    _pg_options.setdefault(
        "connect_timeout", int(env_positive("PRINTHOST_DB_CONNECT_TIMEOUT", 3))
    )
    # printhost's queries are all short: PostgreSQL's JIT compiles a plan for
    # hundreds of milliseconds when a table's statistics are stale (seen on the
    # farm view's printer list), and never pays that back here.
    _pg_options.setdefault("options", "-c jit=off")
    # The web server (printhost.serve sets it) answers each request on a thread of
    # its own, which would open a connection, and PostgreSQL fork a backend, for
    # each one: a pool of this many connections is kept instead. 0 (the default,
    # workers and Celery) is one connection a thread, as before.
    _pool = int(env_positive("PRINTHOST_DB_POOL_SIZE", 0, zero=True))
    if _pool:
        _pg_options["pool"] = {"min_size": 1, "max_size": _pool, "timeout": 10}
if DATABASES["default"]["ENGINE"] == "django.db.backends.sqlite3":
    DATABASES["default"]["OPTIONS"] = {
        "timeout": 20,
        "transaction_mode": "IMMEDIATE",
        "init_command": "PRAGMA journal_mode=WAL; PRAGMA synchronous=NORMAL;",
    }

DEFAULT_AUTO_FIELD = "django.db.models.BigAutoField"

REDIS_URL = env_str("REDIS_URL", "")
if REDIS_URL:
    CHANNEL_LAYERS = {
        "default": {
            "BACKEND": "printhost.channel_layer.ResilientRedisChannelLayer",
            "CONFIG": {
                "hosts": [REDIS_URL],
                "prefix": env_str("PRINTHOST_CHANNEL_PREFIX", "printhost"),
            },
        }
    }
else:
    CHANNEL_LAYERS = {"default": {"BACKEND": "channels.layers.InMemoryChannelLayer"}}

# Celery (printhost/celery.py says why this broker): tasks never run eagerly, so
# no analysis ever runs inside a web request.
CELERY_BROKER_URL = (
    env_str("PRINTHOST_CELERY_BROKER", "") or REDIS_URL or "filesystem://"
)
if CELERY_BROKER_URL.startswith("filesystem://"):
    _CELERY_QUEUE = DATA_DIR / "celery"
    for _folder in ("queue", "control"):
        (_CELERY_QUEUE / _folder).mkdir(parents=True, exist_ok=True)
    CELERY_BROKER_TRANSPORT_OPTIONS = {
        "data_folder_in": str(_CELERY_QUEUE / "queue"),
        "data_folder_out": str(_CELERY_QUEUE / "queue"),
        "control_folder": str(_CELERY_QUEUE / "control"),
        "store_processed": False,
    }
CELERY_TASK_IGNORE_RESULT = True
#: Hosts sharing one Redis keep their tasks apart by queue name.
CELERY_TASK_DEFAULT_QUEUE = env_str("PRINTHOST_CELERY_QUEUE", "printhost")
# A broker that is away must not hold a request up: the sweep sends later.
CELERY_TASK_PUBLISH_RETRY_POLICY = {
    "max_retries": 1,
    "interval_start": 0,
    "interval_step": 0.5,
    "interval_max": 0.5,
}
CELERY_BROKER_CONNECTION_TIMEOUT = 2.0
# A task is acknowledged when it ends: a worker killed mid-task leaves it queued
# (Redis), and the analysis sweep sends again what a broker forgot (filesystem).
CELERY_TASK_ACKS_LATE = True
CELERY_TASK_REJECT_ON_WORKER_LOST = True
CELERY_WORKER_PREFETCH_MULTIPLIER = 1
CELERY_BROKER_CONNECTION_RETRY_ON_STARTUP = True
CELERY_WORKER_HIJACK_ROOT_LOGGER = False
CELERY_BEAT_SCHEDULE_FILENAME = str(DATA_DIR / "celerybeat-schedule")
#: An analysis whose worker has not reported for this long is sent again (s).
PRINTHOST_ANALYSIS_STALE_SECONDS = env_float("PRINTHOST_ANALYSIS_STALE_SECONDS", 60.0)

# Upkeep, run by Celery beat (printers/upkeep.py, jobs/upkeep.py): never in a request
# or a printer's worker. Intervals in seconds; each must be more than 0.
#: How often each printer's response log is trimmed to its `response_log_limit`.
PRINTHOST_UPKEEP_RESPONSE_LOG_SECONDS = env_positive(
    "PRINTHOST_UPKEEP_RESPONSE_LOG_SECONDS", 60.0
)
#: Temperature samples (the chart's history) older than this many hours are deleted,
#: every PRINTHOST_UPKEEP_TEMPERATURE_SECONDS.
PRINTHOST_TEMPERATURE_KEEP_HOURS = env_positive(
    "PRINTHOST_TEMPERATURE_KEEP_HOURS", 24.0
)
PRINTHOST_UPKEEP_TEMPERATURE_SECONDS = env_positive(
    "PRINTHOST_UPKEEP_TEMPERATURE_SECONDS", 600.0
)
#: Partial uploads untouched for this many hours are deleted with their files,
#: checked every PRINTHOST_UPKEEP_UPLOADS_SECONDS.
PRINTHOST_UPLOAD_EXPIRE_HOURS = env_positive("PRINTHOST_UPLOAD_EXPIRE_HOURS", 24.0)
PRINTHOST_UPKEEP_UPLOADS_SECONDS = env_positive(
    "PRINTHOST_UPKEEP_UPLOADS_SECONDS", 3600.0
)
#: How often finished jobs' files past their printer's `job_file_days` are removed.
PRINTHOST_UPKEEP_JOB_FILES_SECONDS = env_positive(
    "PRINTHOST_UPKEEP_JOB_FILES_SECONDS", 3600.0
)
#: How often analyses (rows, thumbnails, previews) of files no job holds are removed.
PRINTHOST_UPKEEP_ANALYSES_SECONDS = env_positive(
    "PRINTHOST_UPKEEP_ANALYSES_SECONDS", 3600.0
)


def _every(task: str, seconds: float) -> dict[str, object]:
    """A beat entry; a run not started within its interval (at least a minute: the
    filesystem broker delivers within a second or so) is dropped and the next one
    comes, so a worker busy with a long analysis never finds a pile of them."""
    expires = max(seconds, 60.0)
    return {"task": task, "schedule": seconds, "options": {"expires": expires}}


CELERY_BEAT_SCHEDULE = {
    "analysis-sweep": {
        "task": "jobs.tasks.sweep_analyses",
        "schedule": max(5.0, PRINTHOST_ANALYSIS_STALE_SECONDS / 2),
    },
    "upkeep-response-log": _every(
        "printers.tasks.trim_response_logs", PRINTHOST_UPKEEP_RESPONSE_LOG_SECONDS
    ),
    "upkeep-temperature-samples": _every(
        "printers.tasks.prune_temperature_samples",
        PRINTHOST_UPKEEP_TEMPERATURE_SECONDS,
    ),
    "upkeep-partial-uploads": _every(
        "jobs.tasks.expire_uploads", PRINTHOST_UPKEEP_UPLOADS_SECONDS
    ),
    "upkeep-job-files": _every(
        "jobs.tasks.remove_expired_job_files", PRINTHOST_UPKEEP_JOB_FILES_SECONDS
    ),
    "upkeep-orphaned-analyses": _every(
        "jobs.tasks.remove_orphaned_analyses", PRINTHOST_UPKEEP_ANALYSES_SECONDS
    ),
}
#: Analyses running at once in runhost's Celery worker.
PRINTHOST_CELERY_CONCURRENCY = max(1, int(env_float("PRINTHOST_CELERY_CONCURRENCY", 1)))
# A Celery worker started on its own (a systemd unit) runs as many as runhost's.
CELERY_WORKER_CONCURRENCY = PRINTHOST_CELERY_CONCURRENCY
#: Thumbnails and other files derived from job files, by SHA-256.
ANALYSIS_DIR = Path(
    env_str("PRINTHOST_ANALYSIS_DIR", str(DATA_DIR / "analysis"))
).resolve()

AUTH_PASSWORD_VALIDATORS = [
    {
        "NAME": "django.contrib.auth.password_validation."
        "UserAttributeSimilarityValidator"
    },
    {"NAME": "django.contrib.auth.password_validation.MinimumLengthValidator"},
    {"NAME": "django.contrib.auth.password_validation.CommonPasswordValidator"},
    {"NAME": "django.contrib.auth.password_validation.NumericPasswordValidator"},
]

LANGUAGE_CODE = "en-us"
TIME_ZONE = env_str("PRINTHOST_TIME_ZONE", "UTC")
USE_I18N = True
USE_TZ = True

STATIC_URL = "static/"
STATICFILES_DIRS = [BASE_DIR / "static"]
STATIC_ROOT = DATA_DIR / "static"

#: Largest job file accepted, in bytes.
PRINTHOST_MAX_JOB_BYTES = int(env_float("PRINTHOST_MAX_JOB_BYTES", 2 * 1024**3))
#: Seconds a worker's claim on its printer lasts without renewal.
PRINTHOST_LEASE_SECONDS = env_float("PRINTHOST_LEASE_SECONDS", 10.0)
#: How long (s) `/printer/send` waits for the worker's answer to an [ESPxxx] command.
PRINTHOST_ESP_REPLY_SECONDS = env_float("PRINTHOST_ESP_REPLY_SECONDS", 5.0)
#: How often (s) a worker looks in the database for new requests.
PRINTHOST_POLL_SECONDS = env_float("PRINTHOST_POLL_SECONDS", 0.1)
#: On PostgreSQL a request or a queued job wakes its worker at once (LISTEN/NOTIFY);
#: the worker still looks this often (s), in case a notification was lost.
PRINTHOST_FALLBACK_POLL_SECONDS = env_float("PRINTHOST_FALLBACK_POLL_SECONDS", 1.0)
#: Address the raw TCP terminals listen on (one port per printer, `terminal_port`).
PRINTHOST_TERMINAL_BIND = env_str("PRINTHOST_TERMINAL_BIND", "127.0.0.1")

#: `text` (default) or `json`: one JSON object a line (printhost/logformat.py) in
#: every process that configures logging from here (daphne, runhost, the printer
#: workers, Celery).
PRINTHOST_LOG_FORMAT = env_str("PRINTHOST_LOG_FORMAT", "text").strip().lower()
if PRINTHOST_LOG_FORMAT not in FORMATTERS:
    raise ImproperlyConfigured(
        f"PRINTHOST_LOG_FORMAT={PRINTHOST_LOG_FORMAT!r}: use one of "
        + ", ".join(sorted(FORMATTERS))
    )
LOGGING = {
    "version": 1,
    "disable_existing_loggers": False,
    "formatters": {"plain": FORMATTERS[PRINTHOST_LOG_FORMAT]},
    "handlers": {"console": {"class": "logging.StreamHandler", "formatter": "plain"}},
    "root": {"handlers": ["console"], "level": env_str("PRINTHOST_LOG_LEVEL", "INFO")},
}
LOGIN_URL = "/accounts/login/"
LOGIN_REDIRECT_URL = "/"
LOGOUT_REDIRECT_URL = "/accounts/login/"

# -- Printer ports (printers/ports.py) ---------------------------------------------
#: `host:port` pairs a printer's port may reach as socket:// or rfc2217:// (comma
#: separated; empty = none). Device paths and links in the data directory need none.
PRINTHOST_PORT_HOSTS = env_list("PRINTHOST_PORT_HOSTS", [])

# -- Logins and pairing (printhost/logins.py, printhost/appkeys.py) --------------------
#: Every password check is throttled per user name and per address.
AUTHENTICATION_BACKENDS = ["printhost.logins.ThrottledModelBackend"]
#: Failed logins within the window that lock a user name / an address out.
PRINTHOST_LOGIN_USER_FAILURES = int(env_float("PRINTHOST_LOGIN_USER_FAILURES", 5))
PRINTHOST_LOGIN_ADDRESS_FAILURES = int(
    env_float("PRINTHOST_LOGIN_ADDRESS_FAILURES", 20)
)
#: The throttling window (s): a lockout lifts this long after its failures.
PRINTHOST_LOGIN_WINDOW_SECONDS = env_float("PRINTHOST_LOGIN_WINDOW_SECONDS", 900.0)
#: A Cura pairing request expires this long (s) after it was made.
PRINTHOST_APPKEY_REQUEST_SECONDS = env_float("PRINTHOST_APPKEY_REQUEST_SECONDS", 600.0)
#: At most this many pairing requests of one address wait for a decision at once.
PRINTHOST_APPKEY_PENDING_PER_ADDRESS = int(
    env_float("PRINTHOST_APPKEY_PENDING_PER_ADDRESS", 3)
)

# Request bodies before authentication, and the raw TCP terminal's limits
# (printhost/bodylimits.py, printhost/bodygate.py, printers/terminal.py).
#: Largest body of a request that is not an upload (forms, JSON), in bytes.
PRINTHOST_MAX_BODY_BYTES = int(env_float("PRINTHOST_MAX_BODY_BYTES", 1024**2))
#: Uploads one user may have in flight at once (more get 429).
PRINTHOST_UPLOADS_PER_CALLER = int(env_float("PRINTHOST_UPLOADS_PER_CALLER", 2))
#: Free space (bytes) the job storage must keep beyond an upload's size (else 507).
PRINTHOST_UPLOAD_SPARE_BYTES = int(
    env_float("PRINTHOST_UPLOAD_SPARE_BYTES", 64 * 1024**2)
)
#: Terminal clients at once on one printer's port, and from one address.
PRINTHOST_TERMINAL_MAX_CLIENTS = int(env_float("PRINTHOST_TERMINAL_MAX_CLIENTS", 8))
PRINTHOST_TERMINAL_MAX_PER_ADDRESS = int(
    env_float("PRINTHOST_TERMINAL_MAX_PER_ADDRESS", 4)
)
#: Live feeds (websockets) one user may have open at once on one server process;
#: more are closed with 4429. Tablets, phones and dashboards need a handful each.
PRINTHOST_WS_MAX_PER_USER = int(env_float("PRINTHOST_WS_MAX_PER_USER", 200))
#: Seconds a terminal client has to send its key line before it is closed.
PRINTHOST_TERMINAL_LOGIN_SECONDS = env_float("PRINTHOST_TERMINAL_LOGIN_SECONDS", 30.0)

# -- worker hosts of a print farm (printers/hosts.py, printers/worker/files.py) ----
#: The control plane's address as a worker host reaches it (job files are fetched
#: from it); empty on the control plane itself and on a single-computer set-up.
PRINTHOST_CONTROL_URL = env_str("PRINTHOST_CONTROL_URL", "").rstrip("/")
#: The worker host a printer's worker runs on (runhost --worker-host sets it for
#: its workers; empty = the control plane's own runhost).
PRINTHOST_WORKER_HOST = env_str("PRINTHOST_WORKER_HOST", "")
#: This worker host's key (`manage.py worker_host add NAME` shows it once).
PRINTHOST_HOST_KEY = env_str("PRINTHOST_HOST_KEY", "")
#: Bytes of fetched job files a worker host keeps (least recently used go first).
PRINTHOST_FILE_CACHE_BYTES = int(
    env_positive("PRINTHOST_FILE_CACHE_BYTES", 8 * 1024**3, zero=False)
)
#: Seconds between a worker host's heartbeats.
PRINTHOST_HEARTBEAT_SECONDS = env_positive("PRINTHOST_HEARTBEAT_SECONDS", 5.0)

# -- metrics (printhost/metrics*.py, `/metrics`, `manage.py serve_metrics`) --------
#: A scrape must send `Authorization: Bearer <this>`; empty = only an admin's session
#: or API key may read /metrics. Stripped: a token pasted with a newline or a space
#: would match no request.
PRINTHOST_METRICS_TOKEN = env_str("PRINTHOST_METRICS_TOKEN", "").strip()
#: Where each daphne process keeps its request-latency histogram (one file each,
#: summed by a scrape); one folder per computer.
PRINTHOST_METRICS_DIR = Path(
    env_str("PRINTHOST_METRICS_DIR", str(DATA_DIR / "metrics"))
).resolve()
