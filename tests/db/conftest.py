"""The database tests' fixtures, from the support package."""

from support.db import db_url, pg_database  # noqa: F401 - fixtures for this folder
