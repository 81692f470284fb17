"""Real databases for the tests: a fresh SQLite file or a fresh PostgreSQL database for each test.

PostgreSQL runs on 127.0.0.1:5432 with trust authentication on the development and CI machines.
Other people's tests share that server, so every database gets a unique name and is dropped
after the test. Without the server the PostgreSQL cases skip, except in CI, where they fail.
"""

from __future__ import annotations

import csv
import os
import uuid
from pathlib import Path

import pytest

PG_ADMIN = os.environ.get("GUADAL_TEST_PG", "postgresql://postgres@127.0.0.1:5432/test")
RUN_FILES = ("metrics.csv", "trajectory.csv", "measurements.csv", "vehicles.csv", "targets.csv", "fields.csv")


def _admin():
    import psycopg

    return psycopg.connect(PG_ADMIN, autocommit=True, connect_timeout=5)


def pg_available() -> str | None:
    """None if the server answers, else why not."""
    try:
        _admin().close()
    except Exception as exc:  # noqa: BLE001 - any failure means "no server here"
        return str(exc).splitlines()[0]
    return None


class PgDatabase:
    """A uniquely named PostgreSQL database, created now and dropped by :meth:`drop`."""

    def __init__(self):
        self.name = f"guadal_t_{os.getpid()}_{uuid.uuid4().hex[:10]}"
        with _admin() as conn:
            conn.execute(f'CREATE DATABASE "{self.name}"')
        base = PG_ADMIN.rsplit("/", 1)[0]
        self.url = f"{base}/{self.name}"

    def sql(self, statement: str, params=None):
        """Run one statement as the administrator (from the server's maintenance database)."""
        with _admin() as conn:
            return (
                conn.execute(statement, params).fetchall()
                if statement.lstrip().upper().startswith("SELECT")
                else conn.execute(statement, params)
            )

    def outage(self) -> None:
        """Nobody may connect, and every open connection is cut: the database is down."""
        self.sql(f'ALTER DATABASE "{self.name}" ALLOW_CONNECTIONS false')
        self.sql("SELECT pg_terminate_backend(pid) FROM pg_stat_activity WHERE datname = %s", (self.name,))

    def restore(self) -> None:
        self.sql(f'ALTER DATABASE "{self.name}" ALLOW_CONNECTIONS true')

    def drop(self) -> None:
        self.restore()
        self.sql(f'DROP DATABASE IF EXISTS "{self.name}" WITH (FORCE)')


@pytest.fixture(params=["sqlite", "postgresql"])
def db_url(request, tmp_path):
    """A fresh, empty database of each engine."""
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path / 'test.db'}"
        return
    yield request.getfixturevalue("pg_database").url


@pytest.fixture
def pg_database():
    why = pg_available()
    if why is not None:
        if os.environ.get("CI"):
            pytest.fail(f"PostgreSQL at {PG_ADMIN} is not reachable: {why}")
        pytest.skip(f"PostgreSQL at {PG_ADMIN} is not reachable: {why}")
    db = PgDatabase()
    yield db
    db.drop()


def csv_rows(path: Path) -> list[list[str]]:
    with open(path, newline="") as f:
        return list(csv.reader(f))


def assert_same_run_files(a: Path, b: Path) -> None:
    """The CSVs of two run directories are byte-identical."""
    for name in RUN_FILES:
        assert (a / name).read_bytes() == (b / name).read_bytes(), f"{name} differs"
