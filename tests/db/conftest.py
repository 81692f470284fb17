"""Makes db_support importable from the database tests and shares its fixtures."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from db_support import db_url, pg_database  # noqa: E402, F401 - fixtures for this folder
