"""`kill -9` of `guadal run` at sitl, then `guadal resume`: the mission completes over MQTT and
MAVLink, with no measurement lost or taken twice.

The proof is the product's equivalence: the resumed sitl run visits the same nodes, covers the
same distances and records the same samples as the same mission at sim, uninterrupted.
"""

from __future__ import annotations

import csv
import json
import signal
import subprocess
import sys
import uuid

import yaml
from support import ROOT, run_cli
from support.fleet import processes_marked, wait_for

from guadal_cli.mission import prepare
from guadal_cli.runner import MissionRunner


def rows(run, name, source=None):
    with open(run / name, newline="") as fh:
        return [r for r in csv.DictReader(fh) if source is None or r["source"] == source]


def test_a_sitl_run_killed_mid_mission_resumes_to_the_sim_result(tmp_path, monkeypatch):
    mark = uuid.uuid4().hex
    monkeypatch.setenv("GUADAL_TEST_MARK", mark)  # inherited by every process the runs start
    sitl = yaml.safe_load((ROOT / "missions" / "lake_greedy_sitl.yaml").read_text())
    sitl["map"] = str(ROOT / "maps" / "urban_lake.json")
    sitl["fleet"]["max_distance"] = 60
    sitl["backend"].update(speedup=200)
    sim = {**sitl, "backend": {"level": "sim"}}
    for level, mission in (("sim", sim), ("sitl", sitl)):
        (tmp_path / f"{level}.yaml").write_text(yaml.safe_dump(mission))
    MissionRunner(prepare(tmp_path / "sim.yaml"), output=tmp_path / "run-sim").run()

    out = tmp_path / "run-sitl"
    proc = subprocess.Popen(
        [sys.executable, "-m", "guadal_cli", "run", str(tmp_path / "sitl.yaml"), "-o", str(out), "-q"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    try:
        wait_for(
            lambda: (out / "metrics.csv").exists() and (out / "metrics.csv").read_text().count("\n") > 5,
            180,
            "the sitl run wrote no steps",
        )
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.communicate(timeout=60)
    killed_at = len(rows(out, "metrics.csv")) - 1
    assert json.loads((out / "manifest.json").read_text())["status"] == "running"
    # the killed run's own stack notices and goes down
    wait_for(lambda: not processes_marked(mark), 60, "the killed run's stack is still up")

    done = run_cli("resume", out, "--json", timeout=600)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["status"] == "complete"
    sim_out = tmp_path / "run-sim"
    plan = [(r["step"], r["vehicle"], r["node"], r["distance"]) for r in rows(out, "trajectory.csv", "plan")]
    assert plan == [
        (r["step"], r["vehicle"], r["node"], r["distance"]) for r in rows(sim_out, "trajectory.csv", "plan")
    ]
    samples = [(r["step"], r["vehicle"], r["node"], r["value"]) for r in rows(out, "measurements.csv")]
    assert samples == [
        (r["step"], r["vehicle"], r["node"], r["value"]) for r in rows(sim_out, "measurements.csv")
    ]
    assert len(set((s, v) for s, v, _, _ in samples)) == len(samples)  # none taken twice
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["status"] == "complete" and manifest["steps"] > killed_at
    assert [r["after_step"] for r in manifest["resumes"]] == [killed_at]
    # nothing left running: the resumed run took its stack down too
    wait_for(lambda: not processes_marked(mark), 60, "the resumed run's stack is still up")
