"""Run directories shared by the report tests: two algorithms, two seeds each, plus one GPS run."""

from __future__ import annotations

import pytest
from support.report import run_mission


@pytest.fixture(scope="session")
def runs_root(tmp_path_factory):
    """Folder with greedy and lawnmower runs for seeds 1 and 2 (real missions, small budgets)."""
    root = tmp_path_factory.mktemp("runs")
    for algorithm in ("greedy", "lawnmower"):
        for seed in (1, 2):
            run_mission(root, algorithm, seed, algorithm={"type": algorithm})
    return root


@pytest.fixture(scope="session")
def gps_run(tmp_path_factory):
    """One run whose fleet reported GPS fixes, as sitl and real runs do."""
    root = tmp_path_factory.mktemp("gps")
    return run_mission(root, "gps", 1, backend={"level": "support.report:GpsTrackBackend"})
