"""Shared fixtures (helpers that are not fixtures live in the support package)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml


@pytest.fixture
def write_mission(tmp_path):
    """Write a mission dict (or raw text) to a YAML file in the test's folder."""

    def _write(mission, name="mission.yaml") -> Path:
        path = tmp_path / name
        path.write_text(mission if isinstance(mission, str) else yaml.safe_dump(mission, sort_keys=False))
        return path

    return _write
