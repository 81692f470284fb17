"""Episode: the mission loop as a value, driven step by step as the runner and RL drive it."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from support import base_mission

from guadal_cli.episode import Episode
from guadal_cli.errors import GuadalError
from guadal_cli.maps.format import Map
from guadal_cli.mission import prepare_dict
from guadal_cli.runner import MissionRunner


@pytest.fixture(scope="module")
def pond(tmp_path_factory):
    """A 9 x 9 pond with a 3 x 3 island in the middle: small, and detours are possible."""
    mask = np.ones((9, 9), dtype=bool)
    mask[3:6, 3:6] = False
    path = tmp_path_factory.mktemp("pond") / "pond.json"
    Map(mask=mask, cell_size_m=10.0, reference={"row": 4, "col": 4, "lat": 37.418, "lon": -5.98}).save(path)
    return path


def mission(pond, **overrides) -> dict:
    fleet = {"vehicles": 2, "initial_positions": [{"node": 0}, {"node": 8}], "max_distance": 200.0}
    data = base_mission(
        map=str(pond), fleet={**fleet, **overrides.pop("fleet", {})}, output={"database": "none"}
    )
    data.update(overrides)
    return data


def episode(pond, tmp_path, **kw) -> Episode:
    overrides = {k: kw.pop(k) for k in list(kw) if k in ("algorithm", "fleet", "max_steps", "seed")}
    return Episode(prepare_dict(mission(pond, **overrides), tmp_path), **kw)


@pytest.mark.parametrize("algorithm", ["greedy", "expected_improvement"])
def test_an_episode_driven_by_its_planner_walks_the_runners_steps(algorithm, pond, tmp_path):
    """The runner is an Episode plus records: the same planner through the API makes the same run."""
    data = mission(pond, algorithm={"type": algorithm})
    run = MissionRunner(prepare_dict(data, tmp_path), output=tmp_path / "run").run()
    with open(run.directory / "trajectory.csv", newline="") as fh:
        recorded = [(int(r["step"]), int(r["vehicle"]), int(r["node"])) for r in csv.DictReader(fh)]

    prep = prepare_dict(data, tmp_path)
    planner = prep.algorithm_cls(prep.algorithm_config)
    walked = []

    def on_hop(ep, fleet, measurements):
        walked.extend((ep.step_count, v, n) for v, n in sorted(fleet.positions.items()))

    ep = Episode(prep, on_hop=on_hop)
    obs = ep.reset()
    planner.reset(ep.graph, ep.n_vehicles, ep.mode, ep.planner_seed)
    walked.extend((0, v, n) for v, n in sorted(obs.positions.items()))
    terminated = truncated = False
    while not (terminated or truncated):
        obs, _, terminated, truncated, info = ep.step(planner.next_targets(obs))
    assert walked == recorded and ep.step_count == run.steps
    assert ep.stop_reason == "every vehicle spent its budget" and terminated and not truncated


def test_reset_draws_the_same_world_for_a_seed_and_another_for_another_seed(pond, tmp_path):
    ep = episode(pond, tmp_path)

    def first_samples(seed):
        ep.reset(seed=seed)
        return [m.value for m in ep.last_measurements], ep.environment.ground_truth.copy()

    first, truth = first_samples(5)
    ep.step({0: 1, 1: 7})
    again, truth_again = first_samples(5)
    other, other_truth = first_samples(6)
    assert first == again and np.array_equal(truth, truth_again)
    assert first != other and not np.array_equal(truth, other_truth)
    obs = ep.reset(seed=5)
    assert obs.step == 0 and ep.samples == 2 and obs.positions == {0: 0, 1: 8} and ep.visits.sum() == 2


def test_invalid_targets_raise_by_default_and_leave_the_vehicle_in_place_when_asked(pond, tmp_path):
    ep = episode(pond, tmp_path)
    ep.reset()
    with pytest.raises(GuadalError, match="where targets must be neighbours"):
        ep.step({0: 40})

    ep = episode(pond, tmp_path, invalid_targets="stay")
    ep.reset()
    obs, measurements, terminated, truncated, info = ep.step({0: 40, 1: 7, 5: 3, 2: "x"})
    assert obs.positions == {0: 0, 1: 7} and [m.vehicle for m in measurements] == [1]
    assert set(info["invalid"]) == {0, 5, 2}
    assert "where targets must be neighbours" in info["invalid"][0]
    assert "vehicles are 0..1" in info["invalid"][5]
    assert info["moved"] == [1] and info["hops"] == 1 and not (terminated or truncated)
    obs, measurements, *_, info = ep.step([3, 4])  # not even a mapping: nobody moves, nothing raised
    assert (
        obs.positions == {0: 0, 1: 7}
        and not measurements
        and "targets are a mapping" in info["invalid"][None]
    )
    strict = episode(pond, tmp_path)
    strict.reset()
    with pytest.raises(GuadalError, match="returned list; targets are a mapping"):
        strict.step([3, 4])


def test_two_boats_wanting_one_node_the_lower_id_goes_first(pond, tmp_path):
    ep = episode(pond, tmp_path, fleet={"vehicles": 2, "initial_positions": [{"node": 0}, {"node": 2}]})
    obs = ep.reset()
    obs, _, _, _, info = ep.step({0: 1, 1: 1})
    assert obs.positions == {0: 1, 1: 2} and info["moved"] == [0]


def test_target_mode_measures_every_node_and_updates_the_model_on_arrival(pond, tmp_path):
    ep = episode(pond, tmp_path, algorithm={"type": "lawnmower"})
    assert ep.mode == "target"
    ep.reset()
    std_seen = []
    ep.on_hop = lambda ep, fleet, m: std_seen.append(ep.environment.observation_fields()["std"].copy())
    before = ep.observation().fields["std"].copy()
    obs, measurements, *_, info = ep.step({0: 6, 1: 44})
    assert info["hops"] == 6 == len(std_seen) and obs.positions == {0: 6, 1: 44}
    assert [m.node for m in measurements if m.vehicle == 0] == [1, 2, 3, 4, 5, 6]
    assert all(np.array_equal(s, before) for s in std_seen[:-1])  # nothing learnt on the way
    assert std_seen[-1].sum() < before.sum()  # all of it once every boat arrived


def test_sequential_steps_search_no_path(pond, tmp_path):
    ep = episode(pond, tmp_path)
    ep.reset()
    ep.graph._trees.clear()
    for node in (1, 2, 3):
        ep.step({0: node})
    assert ep.observation().positions[0] == 3 and not ep.graph._trees


def test_budget_ends_the_episode_and_max_steps_truncates_it(pond, tmp_path):
    ep = episode(
        pond, tmp_path, fleet={"vehicles": 1, "initial_positions": [{"node": 0}], "max_distance": 25}
    )
    ep.reset()
    ep.step({0: 1})
    *_, terminated, truncated, info = ep.step({0: 2})
    assert terminated and not truncated and info["stop_reason"] == "every vehicle spent its budget"
    obs, measurements, terminated, truncated, info = ep.step({0: 3})  # after the end: nothing happens
    assert obs.positions == {0: 2} and measurements == [] and terminated and info["hops"] == 0

    ep = episode(pond, tmp_path, max_steps=2)
    ep.reset()
    ep.step({0: 1})
    *_, terminated, truncated, info = ep.step({0: 2})
    assert truncated and not terminated and ep.stop_reason == "max_steps reached"


def test_decisions_that_move_nobody_end_the_episode(pond, tmp_path):
    ep = episode(pond, tmp_path)
    ep.reset()
    for _ in range(2):
        assert not ep.step({0: 0})[2]
    *_, terminated, truncated, info = ep.step({})
    assert terminated and info["stop_reason"] == "the algorithm's last 3 decisions moved no vehicle"


def test_a_held_boat_stays_while_the_others_go_on(pond, tmp_path):
    ep = episode(pond, tmp_path, algorithm={"type": "lawnmower"})
    ep.reset()
    ep.before_hop = lambda ep, fleet: ep.hold(1)
    obs, *_, info = ep.step({0: 3, 1: 44})
    assert obs.positions == {0: 3, 1: 8} and info["moved"] == [0] and info["hops"] == 3
