"""End to end at level sim: `guadal run` as users run it, and the properties they rely on."""

import csv
import json
import signal
import subprocess
import sys

import numpy as np
import pytest
import yaml
from support import ROOT, base_mission, run_cli

SIM_MISSIONS = sorted(
    p
    for p in (ROOT / "missions").glob("*.yaml")
    if yaml.safe_load(p.read_text()).get("backend", {}).get("level", "sim") == "sim"
)


def read_csv(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.parametrize("mission", SIM_MISSIONS, ids=[p.stem for p in SIM_MISSIONS])
def test_every_example_mission_runs_and_writes_its_files(mission, tmp_path):
    out = tmp_path / "run"
    proc = run_cli("run", mission, "--output", out, "--quiet")
    assert proc.returncode == 0, proc.stderr
    for name in (
        "mission.resolved.yaml",
        "manifest.json",
        "metrics.csv",
        "trajectory.csv",
        "measurements.csv",
        "fields.csv",
    ):
        assert (out / name).is_file(), name
    manifest = json.loads((out / "manifest.json").read_text())
    assert (
        manifest["status"] == "complete" and manifest["seed"] == yaml.safe_load(mission.read_text())["seed"]
    )
    assert manifest["plugins"]["algorithm"]["name"] and manifest["guadal_version"]
    metrics = read_csv(out / "metrics.csv")
    assert len(metrics) == manifest["steps"] + 1
    budget = yaml.safe_load(mission.read_text())["fleet"]["max_distance"]
    assert all(float(v) <= budget + 1e-6 for k, v in metrics[-1].items() if k.startswith("distance_v"))


def test_same_mission_and_seed_give_byte_identical_csvs(tmp_path, write_mission):
    mission = write_mission(
        base_mission(
            algorithm={"type": "expected_improvement"}, environment={"type": "gp", "noise_std": 0.05}
        )
    )
    for name in ("a", "b"):
        assert run_cli("run", mission, "-o", tmp_path / name, "-q").returncode == 0
    for name in ("metrics.csv", "trajectory.csv", "measurements.csv", "fields.csv"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    assert run_cli("run", mission, "-o", tmp_path / "c", "-q", "--seed", "4").returncode == 0
    assert (tmp_path / "a" / "measurements.csv").read_bytes() != (
        tmp_path / "c" / "measurements.csv"
    ).read_bytes()


@pytest.mark.parametrize("algorithm", ["greedy", "expected_improvement"])
def test_the_model_improves_over_informed_missions(algorithm, tmp_path):
    out = tmp_path / algorithm
    assert run_cli("run", ROOT / "missions" / f"lake_{algorithm}.yaml", "-o", out, "-q").returncode == 0
    rows = read_csv(out / "metrics.csv")
    rmse = np.array([float(r["rmse"]) for r in rows])
    std = np.array([float(r["mean_std"]) for r in rows])
    assert rmse[-1] < 0.1 * rmse[0] and std[-1] < 0.2 * std[0]
    # the estimate never gets worse than the prior: no overshoot between dense samples
    assert rmse.max() <= rmse[0] + 1e-9
    # mean std never rises: every sample only removes uncertainty
    assert np.all(np.diff(std) <= 1e-9)


def test_vehicles_never_share_a_node_and_hop_one_edge_per_step(tmp_path, write_mission):
    from guadal_cli.graph import NavGraph
    from guadal_cli.maps.format import load_map

    graph = NavGraph(load_map(ROOT / "maps" / "urban_lake.json"))
    mission = write_mission(
        base_mission(
            algorithm={"type": "random", "mode": "target"}, fleet={"vehicles": 4, "max_distance": 300}
        )
    )
    assert run_cli("run", mission, "-o", tmp_path / "r", "-q").returncode == 0
    by_step = {}
    for row in read_csv(tmp_path / "r" / "trajectory.csv"):
        by_step.setdefault(int(row["step"]), {})[int(row["vehicle"])] = int(row["node"])
    for step, nodes in by_step.items():
        assert len(set(nodes.values())) == len(nodes), f"shared node at step {step}"
        if step:
            for v, node in nodes.items():
                prev = by_step[step - 1][v]
                assert node == prev or node in graph.neighbors(prev)


def test_target_mode_measures_at_every_intermediate_node(tmp_path, write_mission):
    mission = write_mission(
        base_mission(algorithm={"type": "expected_improvement"}, fleet={"vehicles": 1, "max_distance": 150})
    )
    assert run_cli("run", mission, "-o", tmp_path / "r", "-q").returncode == 0
    traj = [r for r in read_csv(tmp_path / "r" / "trajectory.csv") if r["source"] == "plan"]
    meas = read_csv(tmp_path / "r" / "measurements.csv")
    assert [r["node"] for r in traj] == [r["node"] for r in meas]
    # the model is updated only when a target is reached: std is flat between arrivals
    std = [float(r["mean_std"]) for r in read_csv(tmp_path / "r" / "metrics.csv")]
    assert sum(b == a for a, b in zip(std, std[1:])) > len(std) / 3


@pytest.mark.parametrize("stop", ["ctrl-c", "terminate"])
def test_ctrl_c_leaves_a_readable_run_marked_interrupted(stop, tmp_path, write_mission):
    mission = write_mission(
        base_mission(
            map=str(ROOT / "maps" / "reservoir.json"),
            environment={"type": "gp", "kernel": {"length_scale": 25.0}},
            fleet={"vehicles": 3, "max_distance": 100000},
        )
    )
    out = tmp_path / "r"
    proc = subprocess.Popen(
        [sys.executable, "-m", "guadal_cli", "run", str(mission), "-o", str(out), "-q"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    metrics = out / "metrics.csv"
    # wait until the mission has written a few steps, then interrupt it as a user would
    deadline = 120
    import time

    start = time.monotonic()
    while time.monotonic() - start < deadline:
        if metrics.exists() and metrics.read_text().count("\n") > 5:
            break
        if proc.poll() is not None:
            pytest.fail(f"mission ended early: {proc.stderr.read()}")
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM if stop == "terminate" else signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["status"] == "interrupted" and manifest["ended_at"]
    rows = read_csv(metrics)
    assert len(rows) >= 5 and all(r["step"] for r in rows)


PLUGIN = '''
from guadal_cli.planners.base import Planner, SEQUENTIAL
from pydantic import BaseModel, ConfigDict

class Config(BaseModel):
    model_config = ConfigDict(extra="forbid")
    prefer: str = "north"

class Northward(Planner):
    """Goes to the neighbour with the largest y: easy to recognise in a trajectory."""
    Config = Config
    modes = (SEQUENTIAL,)

    def next_targets(self, obs):
        out, taken = {}, set(obs.positions.values())
        for v, node in sorted(obs.positions.items()):
            options = [n for n in obs.graph.neighbors(node) if n not in taken]
            if options:
                best = max(options, key=lambda n: (obs.graph.y[n], -n))
                if obs.graph.y[best] > obs.graph.y[node]:
                    out[v] = best
                    taken.add(best)
        return out
'''


def _northward_run(tmp_path, write_mission, algorithm_type, env=None):
    mission = write_mission(
        base_mission(
            algorithm={"type": algorithm_type, "prefer": "north"}, fleet={"vehicles": 1, "max_distance": 500}
        )
    )
    out = tmp_path / "run"
    proc = run_cli("run", mission, "-o", out, "-q", env=env)
    assert proc.returncode == 0, proc.stderr
    ys = [float(r["lat"]) for r in read_csv(out / "trajectory.csv")]
    assert len(ys) > 2 and all(b > a for a, b in zip(ys, ys[1:]))
    return json.loads((out / "manifest.json").read_text())


def test_algorithm_from_outside_the_package_by_module_and_class(tmp_path, write_mission):
    (tmp_path / "northward.py").write_text(PLUGIN)
    manifest = _northward_run(
        tmp_path, write_mission, "northward:Northward", env={"PYTHONPATH": str(tmp_path)}
    )
    assert manifest["plugins"]["algorithm"]["name"] == "northward:Northward"


def test_algorithm_registered_by_another_package_through_its_entry_point(tmp_path, write_mission):
    site = tmp_path / "site"
    site.mkdir()
    (site / "northward.py").write_text(PLUGIN)
    info = site / "guadal_northward-1.2.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: guadal-northward\nVersion: 1.2.0\n")
    (info / "entry_points.txt").write_text("[guadal.algorithms]\nnorthward = northward:Northward\n")
    listing = run_cli("plugins", "--json", env={"PYTHONPATH": str(site)})
    assert {
        "kind": "algorithm",
        "name": "northward",
        "target": "northward:Northward",
        "package": "guadal-northward 1.2.0",
    } in json.loads(listing.stdout)
    manifest = _northward_run(tmp_path, write_mission, "northward", env={"PYTHONPATH": str(site)})
    assert manifest["plugins"]["algorithm"] == {
        "name": "northward",
        "distribution": "guadal-northward",
        "version": "1.2.0",
    }


STUBBORN = '''
from guadal_cli.planners.base import Planner, TARGET

class Stubborn(Planner):
    """Always sends every vehicle to node 0, which vehicle 0 already holds: nobody can ever arrive."""
    modes = (TARGET,)

    def next_targets(self, obs):
        return {v: 0 for v in obs.positions if v != 0}
'''


def test_a_planner_whose_targets_can_never_be_reached_ends_the_mission(tmp_path, write_mission):
    (tmp_path / "stubborn.py").write_text(STUBBORN)
    mission = write_mission(
        base_mission(
            algorithm={"type": "stubborn:Stubborn"},
            fleet={"vehicles": 2, "initial_positions": [0, 40], "max_distance": 500},
        )
    )
    proc = run_cli("run", mission, "-o", tmp_path / "r", "-q", env={"PYTHONPATH": str(tmp_path)}, timeout=120)
    assert proc.returncode == 0, proc.stderr
    manifest = json.loads((tmp_path / "r" / "manifest.json").read_text())
    assert manifest["status"] == "complete" and "moved no vehicle" in manifest["stop_reason"]


def test_detours_avoid_the_nodes_they_are_told_to():
    from guadal_cli.graph import NavGraph
    from guadal_cli.maps.format import load_map

    g = NavGraph(load_map(ROOT / "maps" / "urban_lake.json"))
    a, b = g.node_at(12, 10), g.node_at(12, 20)
    direct = g.shortest_path(a, b)
    blocked = set(direct[1:-1])
    detour = g.shortest_path(a, b, avoid=blocked)
    assert detour and not blocked & set(detour)
    assert g.distance(a, b) < sum(g.edge_length(p, q) for p, q in zip(detour, detour[1:]))
