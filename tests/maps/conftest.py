"""Makes maps_support importable from the map tests."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
