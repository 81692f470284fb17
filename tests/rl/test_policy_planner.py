"""The ``policy`` algorithm: a trained policy (ONNX or module:function) played as a planner."""

from __future__ import annotations

import csv
import sys

import numpy as np
import pytest
from support import LAKE, base_mission, run_cli
from support.rl import linear_onnx, std_ahead

from guadal_cli.envs.base import Observation
from guadal_cli.errors import GuadalError
from guadal_cli.graph import NavGraph
from guadal_cli.maps.format import load_map
from guadal_cli.mission import prepare
from guadal_cli.planners.policy import PolicyConfig, PolicyPlanner
from guadal_cli.rl.observation import OFFSETS, ObservationBuilder
from guadal_cli.runner import MissionRunner

SHAPE = (7, 30, 49)  # the paper lake's grid, seven channels


@pytest.fixture(scope="module")
def lake():
    return NavGraph(load_map(LAKE))


def observe(graph, positions, std, remaining=100.0):
    return Observation(
        step=0,
        time_s=0.0,
        graph=graph,
        positions=positions,
        remaining={v: remaining for v in positions},
        done={v: False for v in positions},
        visits=np.zeros(graph.n_nodes, int),
        fields={"mean": np.zeros(graph.n_nodes), "std": std},
    )


def planner_for(graph, n, **params):
    planner = PolicyPlanner(PolicyConfig(**params))
    planner.reset(graph, n, "sequential", seed=5)
    return planner


def test_the_policy_goes_where_its_scores_are_highest(lake):
    start = lake.node_at(12, 15)
    std = np.full(lake.n_nodes, 0.1)
    east = lake.node_at(12, 16)
    std[east] = 0.9
    targets = planner_for(lake, 1, model="support.rl:std_ahead").next_targets(observe(lake, {0: start}, std))
    assert targets == {0: east}


def test_actions_off_the_water_or_beyond_the_budget_are_never_taken(lake):
    # a boat on the northern shore: north is land, yet the policy scores north highest
    shore = next(
        n for n in range(lake.n_nodes) if lake.node_at(int(lake.rows[n]) - 1, int(lake.cols[n])) is None
    )
    planner = planner_for(lake, 1, model="support.rl:everything_north")
    target = planner.next_targets(observe(lake, {0: shore}, np.ones(lake.n_nodes)))[0]
    assert target == shore or target in lake.neighbors(shore)
    # with 1 m of budget left no hop fits: the boat stays
    assert planner.next_targets(observe(lake, {0: shore}, np.ones(lake.n_nodes), remaining=1.0)) == {0: shore}


def test_sampling_is_seeded(lake):
    start = lake.node_at(12, 15)
    std = np.random.default_rng(0).random(lake.n_nodes)

    def picks():
        planner = planner_for(lake, 1, model="support.rl:std_ahead", sample=True)
        return [planner.next_targets(observe(lake, {0: start}, std))[0] for _ in range(20)]

    first = picks()
    assert first == picks()
    assert len(set(first)) > 1  # sampling, not argmax


def test_a_sequential_policy_sees_the_actions_in_compass_order(lake):
    builder = ObservationBuilder(lake, 1, 100.0, fields=("mean", "std"))
    node = lake.node_at(12, 15)
    for action, (dr, dc) in enumerate(OFFSETS):
        assert builder.action_nodes[node, action] == lake.node_at(12 + dr, 15 + dc)


def mission_with(tmp_path, write_mission, model, **algorithm):
    mission = base_mission(algorithm={"type": "policy", "model": str(model), **algorithm})
    return write_mission(mission)


def trajectory(run):
    with open(run / "trajectory.csv") as f:
        return [(r["step"], r["vehicle"], r["node"]) for r in csv.DictReader(f)]


def test_an_onnx_policy_runs_a_mission_at_sim_deterministically(tmp_path, write_mission):
    model = linear_onnx(
        tmp_path / "p.onnx", SHAPE, 9, metadata={"mode": "sequential", "fields": ["mean", "std"]}
    )
    path = mission_with(tmp_path, write_mission, "p.onnx")  # relative to the mission file
    runs = [MissionRunner(prepare(path), output=tmp_path / f"run{i}").run() for i in range(2)]
    assert [r.status for r in runs] == ["complete", "complete"]
    assert trajectory(runs[0].directory) == trajectory(runs[1].directory)
    assert runs[0].steps > 3
    assert model.is_file()


def expect_refusal(path, *words):
    with pytest.raises(GuadalError) as info:
        prepare(path)
    message = str(info.value)
    assert "algorithm.model" in message or "algorithm.mode" in message, message
    for word in words:
        assert word in message, message
    assert "\n" not in message


def test_validate_names_a_missing_policy_file(tmp_path, write_mission):
    path = mission_with(tmp_path, write_mission, "nowhere.onnx")
    proc = run_cli("validate", path)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "nowhere.onnx" in proc.stderr and "does not exist" in proc.stderr


def test_validate_refuses_a_policy_trained_on_another_grid(tmp_path, write_mission):
    linear_onnx(tmp_path / "small.onnx", (7, 10, 10), 9)
    expect_refusal(mission_with(tmp_path, write_mission, "small.onnx"), "(7, 10, 10)", "(7, 30, 49)")


def test_validate_refuses_a_policy_with_the_wrong_number_of_actions(tmp_path, write_mission):
    expect_refusal(mission_with(tmp_path, write_mission, "support.rl:wrong_width"), "(3, 5)", "(3, 9)")


def test_validate_refuses_a_file_that_is_not_onnx(tmp_path, write_mission):
    (tmp_path / "junk.onnx").write_text("not a model")
    expect_refusal(mission_with(tmp_path, write_mission, "junk.onnx"), "not a readable ONNX model")


def test_validate_refuses_a_policy_trained_in_the_other_mode(tmp_path, write_mission):
    linear_onnx(tmp_path / "t.onnx", SHAPE, 351, metadata={"mode": "target"})
    expect_refusal(mission_with(tmp_path, write_mission, "t.onnx"), "target mode", "algorithm.mode: target")


def test_validate_says_how_to_install_onnxruntime(tmp_path, write_mission, monkeypatch):
    linear_onnx(tmp_path / "p.onnx", SHAPE, 9)
    monkeypatch.setitem(sys.modules, "onnxruntime", None)  # import fails as if not installed
    expect_refusal(mission_with(tmp_path, write_mission, "p.onnx"), "onnxruntime", "pip install 'guadal[rl]'")


def test_a_target_mode_policy_sends_reachable_nodes(tmp_path, write_mission):
    linear_onnx(tmp_path / "t.onnx", SHAPE, 351, metadata={"mode": "target"})
    path = mission_with(tmp_path, write_mission, "t.onnx", mode="target")
    result = MissionRunner(prepare(path), output=tmp_path / "run").run()
    assert result.status == "complete" and result.steps > 3


def test_std_ahead_is_a_valid_policy_for_the_lake():
    assert std_ahead(np.zeros((2, *SHAPE), np.float32)).shape == (2, 9)


def test_a_vector_layout_policy_reads_the_water_nodes(tmp_path, write_mission):
    linear_onnx(tmp_path / "v.onnx", (6 * 351,), 9)  # six channels at the lake's 351 water nodes
    result = MissionRunner(
        prepare(mission_with(tmp_path, write_mission, "v.onnx")), output=tmp_path / "run"
    ).run()
    assert result.status == "complete" and result.steps > 3
