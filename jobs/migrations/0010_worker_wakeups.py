"""PostgreSQL only: a request or a queued job wakes its printer's worker
(printers/worker/wakeup.py). Triggers, so every writer (the API, the admin, Celery,
the farm's dispatcher, a bulk update) is covered; NOTIFY goes out at commit."""

from django.db import migrations

CREATE = (
    """
CREATE OR REPLACE FUNCTION printhost_wake_worker() RETURNS trigger AS $$
BEGIN
    IF NEW.printer_id IS NOT NULL THEN
        PERFORM pg_notify('printhost_printer_' || NEW.printer_id, '');
    END IF;
    RETURN NULL;
END
$$ LANGUAGE plpgsql
""",
    """
CREATE TRIGGER printhost_wake_on_request
    AFTER INSERT ON printers_queuedcommand
    FOR EACH ROW EXECUTE FUNCTION printhost_wake_worker()
""",
    """
CREATE TRIGGER printhost_wake_on_job
    AFTER INSERT OR UPDATE OF state, printer_id ON jobs_job
    FOR EACH ROW WHEN (NEW.state = 'queued') EXECUTE FUNCTION printhost_wake_worker()
""",
)

DROP = (
    "DROP TRIGGER IF EXISTS printhost_wake_on_job ON jobs_job",
    "DROP TRIGGER IF EXISTS printhost_wake_on_request ON printers_queuedcommand",
    "DROP FUNCTION IF EXISTS printhost_wake_worker()",
)


def _on_postgresql(statements: tuple[str, ...]):  # noqa: ANN202 (RunPython's callable)
    def run(apps, schema_editor) -> None:  # noqa: ANN001, ARG001
        if schema_editor.connection.vendor == "postgresql":
            for sql in statements:
                schema_editor.execute(sql, params=None)

    return run


class Migration(migrations.Migration):
    dependencies = [
        ("jobs", "0009_farm_job"),
        ("printers", "0010_farm_and_worker_hosts"),
    ]

    operations = [
        migrations.RunPython(_on_postgresql(CREATE), _on_postgresql(DROP)),
    ]
