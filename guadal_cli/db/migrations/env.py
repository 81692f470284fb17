"""Alembic environment: migrations run on the connection guadal hands over (see db/engine.py)."""

from alembic import context

from guadal_cli.db.models import Base

connection = context.config.attributes["connection"]
context.configure(connection=connection, target_metadata=Base.metadata, render_as_batch=True)
with context.begin_transaction():
    context.run_migrations()
