"""SqliteWrites: an SQLite worker skips its poll's reads only while nobody wrote."""

from __future__ import annotations

import sqlite3
from typing import TYPE_CHECKING

import pytest

from printers.worker.wakeup import FALLBACK_SECONDS, SqliteWrites

if TYPE_CHECKING:
    from collections.abc import Iterator
    from pathlib import Path


@pytest.fixture
def database(tmp_path: Path) -> Iterator[tuple[sqlite3.Connection, sqlite3.Connection]]:
    """The worker's connection and another one (the web process), one file, WAL."""
    path = tmp_path / "db.sqlite3"
    mine = sqlite3.connect(path, isolation_level=None)
    mine.execute("PRAGMA journal_mode=WAL")
    mine.execute("CREATE TABLE requests (id INTEGER PRIMARY KEY, text TEXT)")
    other = sqlite3.connect(path, isolation_level=None)
    yield mine, other
    mine.close()
    other.close()


def test_nothing_written_is_quiet_after_the_first_look(database) -> None:
    mine, _ = database
    writes = SqliteWrites(alone=True)
    assert not writes.quiet(mine, 0.0)  # the first look always reads
    assert writes.quiet(mine, 0.1)
    assert writes.quiet(mine, 0.2)


@pytest.mark.parametrize(
    ("writer", "alone", "quiet_after"),
    [
        ("other", True, False),  # the web process queued a request
        ("mine", True, True),  # the worker's own log batch, alone on its connection
        ("mine", False, False),  # a test's request on the connection it shares
    ],
)
def test_a_write_ends_the_quiet_unless_it_is_the_lone_workers_own(
    database, writer, alone, quiet_after
) -> None:
    mine, other = database
    writes = SqliteWrites(alone=alone)
    writes.quiet(mine, 0.0)
    connection = mine if writer == "mine" else other
    connection.execute("INSERT INTO requests (text) VALUES ('M112')")
    assert writes.quiet(mine, 0.1) is quiet_after
    assert writes.quiet(mine, 0.2)  # nothing new since


def test_the_poll_reads_at_least_every_fallback_interval(database) -> None:
    mine, _ = database
    writes = SqliteWrites(alone=True)
    writes.quiet(mine, 0.0)
    assert writes.quiet(mine, FALLBACK_SECONDS - 0.01)
    assert not writes.quiet(mine, FALLBACK_SECONDS)
    assert writes.quiet(mine, FALLBACK_SECONDS + 0.1)


def test_a_new_or_closed_connection_is_never_quiet(database, tmp_path) -> None:
    mine, _ = database
    writes = SqliteWrites(alone=True)
    writes.quiet(mine, 0.0)
    again = sqlite3.connect(tmp_path / "db.sqlite3", isolation_level=None)
    assert not writes.quiet(again, 0.1)
    again.close()
    assert not writes.quiet(again, 0.2)
    assert not writes.quiet(None, 0.3)
    assert not writes.quiet(mine, 0.4)  # back on a connection: a fresh look
    assert writes.quiet(mine, 0.5)
