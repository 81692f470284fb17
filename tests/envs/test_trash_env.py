"""The trash environment: detection within the radius, pick-up once, capacity, drift, metrics."""

import math

import numpy as np
import pytest
from support import LAKE

from guadal_cli.envs.trash import TrashConfig, TrashEnvironment
from guadal_cli.envs.world import CellLocator
from guadal_cli.fleet.base import Measurement
from guadal_cli.graph import NavGraph
from guadal_cli.maps.format import load_map


@pytest.fixture(scope="module")
def lake():
    return NavGraph(load_map(LAKE))


def make(lake, seed=1, **params):
    env = TrashEnvironment(TrashConfig(**params), lake)
    env.reset(seed)
    return env


def sample(graph, vehicle, node, t):
    return Measurement(vehicle, int(node), 0.0, float(graph.lat[node]), float(graph.lon[node]), float(t))


def random_walks(lake, steps, seed, vehicles=3):
    """Per hop, the node of every vehicle on a random walk over the lake."""
    rng = np.random.default_rng(seed)
    body = np.nonzero(lake.component == np.argmax(np.bincount(lake.component)))[0]
    positions = {v: int(body[rng.integers(len(body))]) for v in range(vehicles)}
    hops = []
    for _ in range(steps):
        positions = {v: int(rng.choice(lake.neighbors(n))) for v, n in positions.items()}
        hops.append(dict(positions))
    return hops


def test_items_start_on_water_around_their_spots(lake):
    env = make(lake, items=200, spots=[{"row": 8, "col": 12}, {"row": 12, "col": 30}], spot_radius_m=6.0)
    assert (CellLocator(lake).nodes(env.items_xy) >= 0).all()
    centres = lake.xy[[lake.node_at(8, 12), lake.node_at(12, 30)]]
    nearest = np.hypot(*(env.items_xy[:, None, :] - centres[None]).transpose(2, 0, 1)).min(axis=1)
    assert np.median(nearest) < 2 * 6.0
    assert env.ground_truth.sum() == 200


def test_same_seed_same_world_other_seed_other_world(lake):
    a, b, c = make(lake, seed=5), make(lake, seed=5), make(lake, seed=6)
    assert np.array_equal(a.items_xy, b.items_xy)
    assert not np.array_equal(a.items_xy, c.items_xy)


def test_detection_pickup_and_capacity_rules_hold_over_a_drifting_mission(lake):
    """New detections lie within the radius of a sample of that hop; pick-ups happen in the
    sampled cell, once per item, within capacity; the sensor reads what is picked."""
    radius, capacity = 7.5, 12
    env = make(
        lake,
        items=150,
        vision_radius_m=radius,
        capacity=capacity,
        drift={"current": [0.03, 0.01]},
        jitter=0.05,
    )
    locator = CellLocator(lake)
    first_picker = np.full(150, -1)
    for k, positions in enumerate(random_walks(lake, steps=120, seed=2), start=1):
        env.advance(10.0 * k)
        xy = env.items_xy.copy()
        batch = [sample(lake, v, n, 10.0 * k) for v, n in positions.items()]
        readings = {m.vehicle: env.sense(m.vehicle, m.node) for m in batch}
        seen_before, collected_before = env.detected.copy(), env.collected.copy()
        env.update(batch)
        for i in np.nonzero(env.detected & ~seen_before)[0]:
            gap = min(math.hypot(*(xy[i] - lake.xy[m.node])) for m in batch)
            assert gap <= radius + 1e-9, f"item {i} detected {gap:.2f} m from the nearest vehicle"
        taken = np.nonzero(env.collected & ~collected_before)[0]
        assert (first_picker[taken] == -1).all()  # nobody had it before
        first_picker[taken] = env.collected_by[taken]
        for i in taken:
            assert locator.nodes(xy[i : i + 1])[0] == positions[env.collected_by[i]] == env.collected_at[i]
        for v, reading in readings.items():
            assert reading == np.count_nonzero(env.collected_by[taken] == v)
    assert np.array_equal(first_picker, env.collected_by)  # no item changed hands afterwards
    per_vehicle = np.bincount(env.collected_by[env.collected], minlength=3)
    assert per_vehicle.max() == capacity  # someone filled up, nobody overfilled
    assert env.task_state()["capacity_left"] == {v: capacity - per_vehicle[v] for v in range(3)}
    assert env.detected.sum() >= env.collected.sum() > 0


def test_a_full_vehicle_leaves_the_items_and_its_reading_is_zero(lake):
    node = lake.node_at(10, 15)
    env = make(lake, items=5, spots=[{"node": node}], spot_radius_m=0.01, capacity=2)
    assert env.sense(0, node) == 2.0
    env.update([sample(lake, 0, node, 0.0)])
    assert env.collected.sum() == 2 and env.sense(0, node) == 0.0
    env.update([sample(lake, 0, node, 0.0)])
    assert env.collected.sum() == 2
    assert env.observation_fields()["belief"][node] == 3  # seen, still there
    env.update([sample(lake, 1, node, 0.0)])
    assert env.collected.sum() == 4 and sorted(env.collected_by[env.collected]) == [0, 0, 1, 1]


def test_drift_moves_items_with_mission_time_and_keeps_them_on_water(lake):
    env = make(lake, items=80, drift={"current": [0.02, 0.0], "wind": [0.0, 1.0], "wind_factor": 0.03})
    locator = CellLocator(lake)
    start = env.items_xy.copy()
    env.advance(0.0)
    assert np.array_equal(env.items_xy, start)  # no time, no motion
    env.advance(100.0)
    moved = env.items_xy - start
    free = np.all(np.isclose(moved, [2.0, 3.0]), axis=1)  # 100 s of 0.02 east + 3% of 1 m/s north
    assert free.mean() > 0.5
    assert (locator.nodes(env.items_xy) >= 0).all()
    env.advance(5000.0)  # long enough to push every item onto the north-east shore
    assert (locator.nodes(env.items_xy) >= 0).all()
    assert (env.items_xy[:, 0] >= start[:, 0] - 1e-9).all() and (
        env.items_xy[:, 1] >= start[:, 1] - 1e-9
    ).all()
    assert env.items_xy[:, 1].mean() > start[:, 1].mean() + 10


def test_a_still_world_does_not_move(lake):
    env = make(lake, items=30)
    start = env.items_xy.copy()
    env.advance(1000.0)
    assert np.array_equal(env.items_xy, start)


def test_belief_forgets_items_that_drifted_out_of_sight(lake):
    node = lake.node_at(12, 12)
    env = make(
        lake,
        items=1,
        spots=[{"node": node}],
        spot_radius_m=0.01,
        vision_radius_m=6.0,
        drift={"current": [0.1, 0.0]},
    )
    far = lake.node_at(12, 20)
    env.update([sample(lake, 0, far, 0.0)])  # vehicle 0 far away: sees nothing
    env.update([sample(lake, 1, lake.node_at(12, 11), 0.0)])  # vehicle 1 next to it
    assert env.observation_fields()["belief"][node] == 1
    env.advance(100.0)  # 10 m east: out of the cell, and of sight from node (12, 11)
    env.update([sample(lake, 1, lake.node_at(12, 11), 100.0)])
    belief = env.observation_fields()["belief"]
    assert belief[node] == 0 and belief.sum() == 0
    assert env.detected.sum() == 1


def test_metrics_count_collection_distance_and_milestones(lake):
    nodes = [lake.node_at(10, 12), lake.node_at(10, 13)]
    env = make(lake, items=4, spots=[{"node": n} for n in nodes], spot_radius_m=0.01)
    per_node = env.ground_truth[nodes]
    assert per_node.sum() == 4
    m = env.metrics()
    assert (
        m["fraction_collected"] == 0 and math.isnan(m["distance_per_item"]) and math.isnan(m["time_to_50pct"])
    )
    env.update([sample(lake, 0, lake.node_at(10, 11), 0.0)])
    env.update([sample(lake, 0, nodes[0], 10.0)])
    m = env.metrics()
    assert m["items_collected"] == per_node[0]
    assert m["items_detected"] == 4
    assert m["distance_per_item"] == pytest.approx(5.0 / per_node[0])
    env.update([sample(lake, 0, nodes[1], 20.0)])
    m = env.metrics()
    assert m["fraction_collected"] == 1.0 and m["distance_per_item"] == pytest.approx(10.0 / 4)
    assert m["time_to_90pct"] == 20.0
    assert m["time_to_50pct"] == (10.0 if per_node[0] >= 2 else 20.0)
