"""Test helpers shared by every folder: the repository's paths, the real CLI, a small mission."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LAKE = ROOT / "maps" / "urban_lake.json"


def run_cli(*args, cwd=None, env=None, timeout=300) -> subprocess.CompletedProcess:
    """Run ``guadal`` as a user would: a real process, output captured."""
    full_env = {**os.environ, **(env or {})}
    return subprocess.run(
        [sys.executable, "-m", "guadal_cli", *map(str, args)],
        cwd=cwd,
        env=full_env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def base_mission(**overrides) -> dict:
    """A small, fast gp mission on the paper-scale lake."""
    mission = {
        "name": "t",
        "seed": 3,
        "map": str(LAKE),
        "environment": {
            "type": "gp",
            "ground_truth": {"type": "shekel", "peaks": 3},
            "kernel": {"type": "rbf", "length_scale": 20.0, "noise": 1e-4},
        },
        "algorithm": {"type": "greedy"},
        "fleet": {"vehicles": 3, "initial_positions": "auto", "max_distance": 120.0, "speed": 0.5},
        "backend": {"level": "sim"},
    }
    for key, value in overrides.items():
        mission[key] = value
    return mission
