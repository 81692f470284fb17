"""Test helpers, in one package: import what a test needs from the module named after its area.

- ``support`` (here): the repository's paths, the real CLI as a process, a small gp mission.
- ``support.fleet``: a recording paho client, polling with a deadline, processes by env mark.
- ``support.sitl``: ``guadal sitl`` as a process and a pymavlink ground station for it.
- ``support.vehicle``: emulator + bridge + planner client stacks for the bridge tests.
- ``support.maps``: lakes of known geometry drawn as images, grids and outlines.
- ``support.report``: real missions run in-process and a backend that reports GPS fixes.
- ``support.fuzz``: how hard the property tests try, and their shared checks.
- ``support.db``: a fresh SQLite or PostgreSQL database per test, and run files compared.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
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


def start_cli(*args) -> subprocess.Popen:
    """Start ``guadal`` as a user would in a terminal, to stop it part-way: output piped (text)."""
    return subprocess.Popen(
        [sys.executable, "-m", "guadal_cli", *map(str, args)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def wait_for_steps(proc: subprocess.Popen, run_dir: Path, n: int, timeout: float = 180) -> None:
    """Until the run in ``run_dir`` has written more than ``n`` steps; fails if ``proc`` ended first."""
    import pytest

    metrics = Path(run_dir) / "metrics.csv"
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if metrics.exists() and metrics.read_text().count("\n") > n:
            return
        if proc.poll() is not None:
            pytest.fail(f"mission ended early: {proc.stderr.read()}")
        time.sleep(0.02)
    pytest.fail(f"the mission in {run_dir} wrote no more than {n} steps in {timeout} s")


def stop_after_steps(
    mission: Path, run_dir: Path, n: int, sig: int = signal.SIGKILL, timeout: float = 180
) -> None:
    """``guadal run MISSION`` in its own process, sent ``sig`` (default: ``kill -9``) once it has
    written more than ``n`` steps to ``run_dir``, and reaped."""
    proc = start_cli("run", mission, "-o", run_dir, "-q")
    try:
        wait_for_steps(proc, run_dir, n, timeout)
    finally:
        proc.send_signal(sig)
        proc.communicate(timeout=60)


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
