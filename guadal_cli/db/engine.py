"""Which database, how to open it, and how to bring its schema up to date.

A database is named by a SQLAlchemy URL: ``sqlite:///path/guadal.db`` (the default, a file
beside the runs) or ``postgresql://user@host/db`` (a team server; needs ``guadal[postgres]``).
The first found wins: an explicit URL (``--db``), the ``GUADAL_DB`` environment variable, the
mission's ``output.database``, then the SQLite file. ``none`` turns the database off.
"""

from __future__ import annotations

import os
from functools import cache
from pathlib import Path

from ..errors import GuadalError

ENV_VAR = "GUADAL_DB"
DEFAULT_FILE = "guadal.db"
OFF = ("none", "off", "")
#: a locked SQLite file makes a writer wait this long before it spools instead
SQLITE_BUSY_MS = 2000


def resolve_url(explicit: str | None = None, mission_value: str | None = None, runs_dir=None) -> str | None:
    """The database URL in force, or None when the database is turned off."""
    for value in (explicit, os.environ.get(ENV_VAR), mission_value):
        if value is not None:
            return None if value.strip().lower() in OFF else value.strip()
    folder = Path(runs_dir) if runs_dir is not None else Path("runs")
    return f"sqlite:///{folder / DEFAULT_FILE}"


def redact(url: str | None) -> str | None:
    """The URL with its password replaced by ***, for logs, manifests and messages."""
    if url is None or "@" not in url:
        return url  # no credentials in it (and no need to load SQLAlchemy to say so)
    from sqlalchemy.engine import make_url
    from sqlalchemy.exc import ArgumentError

    try:
        return make_url(url).render_as_string(hide_password=True)
    except ArgumentError:
        return _shape(url)


def _parse(url: str):
    from sqlalchemy.engine import make_url
    from sqlalchemy.exc import ArgumentError

    try:
        parsed = make_url(url)
    except ArgumentError:
        raise GuadalError(
            f"'{_shape(url)}' is not a database URL; use sqlite:///FILE or postgresql://USER@HOST/DATABASE."
        ) from None
    backend = parsed.get_backend_name()
    if backend == "sqlite" and parsed.database in (None, "", ":memory:"):
        raise GuadalError(
            f"'{_shape(url)}' is a database in memory, gone when the process ends; use sqlite:///FILE."
        )
    if backend not in ("sqlite", "postgresql"):
        raise GuadalError(
            f"database '{backend}' is not supported; use sqlite:///FILE or postgresql://USER@HOST/DATABASE."
        )
    if backend == "postgresql" and parsed.drivername == "postgresql":
        parsed = parsed.set(drivername="postgresql+psycopg")
    return parsed


def _shape(url: str) -> str:
    """A URL as it may be shown: anything between '://' and '@' (credentials) hidden."""
    if "://" in url and "@" in url:
        head, rest = url.split("://", 1)
        return f"{head}://***@{rest.rsplit('@', 1)[1]}"
    return url


def check_url(url: str) -> None:
    """Raise the one-sentence error a bad URL or a missing driver would cause, before any work starts."""
    if url.startswith("sqlite:///") and url[len("sqlite:///") :] not in ("", ":memory:"):
        return  # the default's form: nothing to check, nothing to load
    if _parse(url).get_backend_name() == "postgresql":
        try:
            import psycopg  # noqa: F401
        except ImportError:
            raise GuadalError(
                "a PostgreSQL database needs the psycopg driver; install it with pip install 'guadal[postgres]'."
            ) from None


def make_engine(url: str, *, writer: bool = False):
    """An engine for ``url``: SQLite in WAL mode with a short busy timeout, PostgreSQL via psycopg 3.

    A writer's SQLite transactions start with ``BEGIN IMMEDIATE``: two missions writing the
    same file then queue for the lock instead of failing half-way through a batch.
    """
    from sqlalchemy import create_engine, event

    check_url(url)
    parsed = _parse(url)
    if parsed.get_backend_name() == "postgresql":
        return create_engine(parsed, pool_pre_ping=True, connect_args={"connect_timeout": 5})
    if parsed.database and parsed.database != ":memory:":
        Path(parsed.database).parent.mkdir(parents=True, exist_ok=True)
    engine = create_engine(parsed, connect_args={"timeout": SQLITE_BUSY_MS / 1000})

    @event.listens_for(engine, "connect")
    def _on_connect(dbapi_connection, _record):
        dbapi_connection.isolation_level = None  # SQLAlchemy emits BEGIN itself (below)
        cursor = dbapi_connection.cursor()
        cursor.execute(f"PRAGMA busy_timeout = {SQLITE_BUSY_MS}")
        cursor.execute("PRAGMA journal_mode = WAL")
        cursor.execute("PRAGMA synchronous = NORMAL")
        cursor.execute("PRAGMA foreign_keys = ON")
        cursor.close()

    @event.listens_for(engine, "begin")
    def _on_begin(connection):
        connection.exec_driver_sql("BEGIN IMMEDIATE" if writer else "BEGIN")

    return engine


# --- schema versions (Alembic, shipped inside the package) ------------------------------------
def _alembic_config():
    from alembic.config import Config

    cfg = Config()
    cfg.set_main_option("script_location", str(Path(__file__).parent / "migrations"))
    return cfg


@cache
def head_revision() -> str:
    from alembic.script import ScriptDirectory

    return ScriptDirectory.from_config(_alembic_config()).get_current_head()


def current_revision(engine) -> str | None:
    from alembic.migration import MigrationContext

    with engine.connect() as conn:
        return MigrationContext.configure(conn).get_current_revision()


def upgrade(engine) -> str:
    """Create or migrate the schema to this version's head; safe when two processes race."""
    from alembic import command
    from sqlalchemy import text

    with engine.begin() as conn:  # SQLite: BEGIN IMMEDIATE serialises racing upgrades
        if conn.dialect.name == "postgresql":
            conn.execute(text("SELECT pg_advisory_xact_lock(4823001)"))
        cfg = _alembic_config()
        cfg.attributes["connection"] = conn
        command.upgrade(cfg, "head")
    return head_revision()


#: the newest migration in migrations/versions (a test checks it): lets a mission see that its
#: database is current with one SELECT, without loading Alembic
SCHEMA_VERSION = "0003"


def ensure_schema(engine) -> None:
    """Upgrade unless the database is already at this version's head (the common, cheap case)."""
    from sqlalchemy import text
    from sqlalchemy.exc import SQLAlchemyError

    try:
        with engine.connect() as conn:
            if conn.execute(text("SELECT version_num FROM alembic_version")).scalar() == SCHEMA_VERSION:
                return
    except SQLAlchemyError:
        pass  # no version table yet: Alembic decides below
    current = current_revision(engine)
    if current == head_revision():
        return
    if current is not None and current not in _known_revisions():
        raise GuadalError(
            f"database {redact(str(engine.url))} has schema version {current}, which is newer than "
            f"this guadal knows (up to {head_revision()}); upgrade guadal."
        )
    upgrade(engine)


@cache
def _known_revisions() -> frozenset[str]:
    from alembic.script import ScriptDirectory

    return frozenset(s.revision for s in ScriptDirectory.from_config(_alembic_config()).walk_revisions())
