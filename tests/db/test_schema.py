"""The schema is created from an empty database by the shipped migrations, on both engines."""

from __future__ import annotations

import sqlalchemy as sa
from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext

from guadal_cli.db.engine import (
    SCHEMA_VERSION,
    current_revision,
    ensure_schema,
    head_revision,
    make_engine,
    upgrade,
)
from guadal_cli.db.models import Base

TABLES = {
    "maps",
    "runs",
    "run_vehicles",
    "steps",
    "measurements",
    "trajectory",
    "events",
    "fields",
    "vehicle_status",
    "targets",
}


def test_migrations_build_the_schema_from_empty_and_match_the_models(db_url):
    engine = make_engine(db_url)
    assert current_revision(engine) is None
    assert head_revision() == SCHEMA_VERSION  # the constant a mission checks without loading Alembic
    assert upgrade(engine) == head_revision()
    assert current_revision(engine) == head_revision()
    names = set(sa.inspect(engine).get_table_names())
    assert TABLES <= names
    with engine.connect() as conn:
        # the migration creates exactly what the models describe (no forgotten column or index)
        assert compare_metadata(MigrationContext.configure(conn), Base.metadata) == []
    ensure_schema(engine)  # at head already: a no-op
    upgrade(engine)
    assert current_revision(engine) == head_revision()


def test_the_queries_users_make_are_indexed(db_url):
    engine = make_engine(db_url)
    upgrade(engine)
    inspector = sa.inspect(engine)
    run_indexes = {tuple(ix["column_names"]) for ix in inspector.get_indexes("runs")}
    for column in ("map_id", "algorithm", "level", "status", "started_at"):
        assert (column,) in run_indexes
    sample_indexes = {tuple(ix["column_names"]) for ix in inspector.get_indexes("measurements")}
    assert ("map_id", "taken_at") in sample_indexes
    assert ("map_id", "lat", "lon") in sample_indexes
