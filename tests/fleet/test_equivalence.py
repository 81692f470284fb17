"""The product's claim: the same mission at ``sim`` and at ``sitl`` visits the same nodes.

The sitl twin differs only in its backend section (``launch: true`` brings up broker, MAVLink
emulator and bridges for the run and stops them after); the budget is cut to keep it short.
"""

from __future__ import annotations

import csv
import json
import uuid
from pathlib import Path

import pytest
import yaml
from support import ROOT
from support.fleet import processes_marked

from guadal_cli.mission import prepare
from guadal_cli.runner import MissionRunner


def plan_rows(run: Path) -> list[tuple[str, str, str]]:
    with open(run / "trajectory.csv") as f:
        return [(r["step"], r["vehicle"], r["node"]) for r in csv.DictReader(f) if r["source"] == "plan"]


def distances(run: Path) -> list[list[float]]:
    with open(run / "metrics.csv") as f:
        rows = list(csv.DictReader(f))
    return [[round(float(r[f"distance_v{i}"]), 6) for i in range(3)] for r in rows]


@pytest.mark.parametrize(
    "name, broker", [("lake_greedy", "mosquitto"), ("lake_expected_improvement", "embedded")]
)
def test_sim_and_sitl_send_the_same_targets(name, broker, tmp_path, monkeypatch):
    """Mosquitto for one, the embedded broker (a machine without Mosquitto) for the other."""
    sim = yaml.safe_load((ROOT / "missions" / f"{name}.yaml").read_text())
    sitl = yaml.safe_load((ROOT / "missions" / f"{name}_sitl.yaml").read_text())
    assert {k: v for k, v in sim.items() if k != "backend"} == {
        k: v for k, v in sitl.items() if k != "backend"
    }
    runs = {}
    mark = uuid.uuid4().hex
    monkeypatch.setenv("GUADAL_TEST_MARK", mark)  # inherited by every process the run starts
    for level, mission in (("sim", sim), ("sitl", sitl)):
        mission["map"] = str(ROOT / "maps" / "urban_lake.json")
        mission["fleet"]["max_distance"] = 45
        if level == "sitl":
            mission["backend"].update(speedup=200, broker_kind=broker)
        path = tmp_path / f"{level}.yaml"
        path.write_text(yaml.safe_dump(mission))
        runs[level] = tmp_path / f"run-{level}"
        result = MissionRunner(prepare(path), output=runs[level]).run()
        assert result.status == "complete"
    sim_plan, sitl_plan = plan_rows(runs["sim"]), plan_rows(runs["sitl"])
    assert len(sim_plan) > 3 * 4  # several steps for each of the three boats
    assert sitl_plan == sim_plan
    assert distances(runs["sitl"]) == distances(runs["sim"])
    with open(runs["sitl"] / "trajectory.csv") as f:
        assert any(r["source"] == "gps" for r in csv.DictReader(f))  # the boats really sailed
    assert processes_marked(f"GUADAL_TEST_MARK={mark}") == [], "the launched stack left processes behind"
    manifest = json.loads((runs["sitl"] / "manifest.json").read_text())
    assert manifest["fleet"]["problems"] == []  # a clean run says so in its manifest
