"""Makes console_support (and the slow planner the missions load by name) importable here, and
shares the database tests' fixtures: a fresh SQLite file or PostgreSQL database per test."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from support.db import db_url, pg_database  # noqa: E402, F401 - fixtures for this folder
