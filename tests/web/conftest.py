"""Makes console_support (and the slow planner the missions load by name) importable here."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
