"""The shipped trained policy (examples/rl): its ONNX graph computes what training computed, and it
plays through ``guadal run`` at sim and, unchanged, at sitl with the launched stack."""

from __future__ import annotations

import csv
import json
import sys
import uuid

import numpy as np
import onnxruntime as ort
import yaml
from support import ROOT, base_mission
from support.fleet import processes_marked

from guadal_cli.mission import prepare
from guadal_cli.runner import MissionRunner

sys.path.insert(0, str(ROOT / "examples" / "rl"))
import patch_policy  # noqa: E402

MODEL = ROOT / "examples" / "rl" / "lake_policy.onnx"


def test_the_onnx_export_computes_the_numpy_policy():
    rng = np.random.default_rng(1)
    shape, hidden = (7, 30, 49), 4
    params = rng.normal(size=patch_policy.n_params(7, hidden))
    images = rng.random((4, *shape)).astype(np.float32)
    images[:, 0] = 0
    for i, (r, c) in enumerate([(0, 0), (29, 48), (12, 20), (3, 40)]):  # corners and middle
        images[i, 0, r, c] = 1
    model = patch_policy.to_onnx(params, shape, hidden, {"mode": "sequential"})
    session = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    onnx_scores = session.run(None, {"observations": images})[0]
    np.testing.assert_allclose(onnx_scores, patch_policy.scores(params, images, hidden), atol=1e-4)


def plan_rows(run):
    with open(run / "trajectory.csv") as f:
        return [(r["step"], r["vehicle"], r["node"]) for r in csv.DictReader(f) if r["source"] == "plan"]


def final_mean_std(run):
    with open(run / "metrics.csv") as f:
        return float(list(csv.DictReader(f))[-1]["mean_std"])


def test_the_trained_policy_leaves_far_less_uncertainty_than_random(tmp_path):
    """At sim, through the runner ``guadal run`` uses (tests/test_run.py runs the mission file
    through the command itself, as every example mission)."""
    final = {}
    for name in ("lake_policy", "lake_random"):
        result = MissionRunner(prepare(ROOT / "missions" / f"{name}.yaml"), output=tmp_path / name).run()
        assert result.status == "complete"
        final[name] = final_mean_std(tmp_path / name)
    assert final["lake_policy"] < 0.5 * final["lake_random"]


def test_the_trained_policy_plays_unchanged_at_sitl(tmp_path, monkeypatch):
    """The sitl twin differs only in its backend section; the budget is cut to keep it short."""
    sim = yaml.safe_load((ROOT / "missions" / "lake_policy.yaml").read_text())
    sitl = yaml.safe_load((ROOT / "missions" / "lake_policy_sitl.yaml").read_text())
    assert {k: v for k, v in sim.items() if k != "backend"} == {
        k: v for k, v in sitl.items() if k != "backend"
    }
    mark = uuid.uuid4().hex
    monkeypatch.setenv("GUADAL_TEST_MARK", mark)
    runs = {}
    for level, mission in (("sim", sim), ("sitl", sitl)):
        mission["map"] = str(ROOT / "maps" / "urban_lake.json")
        mission["algorithm"]["model"] = str(MODEL)
        mission["fleet"]["max_distance"] = 40
        if level == "sitl":
            mission["backend"].update(speedup=200)
        path = tmp_path / f"{level}.yaml"
        path.write_text(yaml.safe_dump(mission))
        runs[level] = tmp_path / f"run-{level}"
        assert MissionRunner(prepare(path), output=runs[level]).run().status == "complete"
    assert len(plan_rows(runs["sim"])) > 3 * 4
    assert plan_rows(runs["sitl"]) == plan_rows(runs["sim"])
    assert processes_marked(f"GUADAL_TEST_MARK={mark}") == [], "the launched stack left processes behind"


def test_the_training_example_exports_a_policy_guadal_runs(tmp_path, write_mission):
    """examples/rl/train.py end to end on a short mission: train, export, play with guadal's planner."""
    import train

    mission = base_mission()
    mission["fleet"]["max_distance"] = 40.0
    path = write_mission(mission, "short.yaml")
    out = tmp_path / "policy.onnx"
    train.main(["--mission", str(path), "--out", str(out), "--generations", "2", "--population", "4"])
    assert json.loads(out.with_suffix(".json").read_text())["curve"]
    mission["algorithm"] = {"type": "policy", "model": "policy.onnx"}
    result = MissionRunner(prepare(write_mission(mission, "deploy.yaml")), output=tmp_path / "run").run()
    assert result.status == "complete"
