import numpy as np
import pytest
from support import LAKE

from guadal_cli.envs.base import Observation
from guadal_cli.graph import NavGraph
from guadal_cli.maps.format import load_map
from guadal_cli.planners._spreading import frontier_mask
from guadal_cli.planners.detection_greedy import DetectionGreedy, DetectionGreedyConfig


@pytest.fixture(scope="module")
def lake():
    return NavGraph(load_map(LAKE))


def observe(graph, positions, evidence, observed=None, capacity=None, remaining=1e9):
    observed = np.ones(graph.n_nodes, bool) if observed is None else observed
    return Observation(
        step=0,
        time_s=0.0,
        graph=graph,
        positions=positions,
        remaining={v: remaining for v in positions},
        done={v: False for v in positions},
        visits=np.zeros(graph.n_nodes, int),
        fields={"evidence": evidence, "observed": observed.astype(float)},
        task={} if capacity is None else {"capacity_left": capacity},
    )


def planner(graph, n, mode="target", **params):
    p = DetectionGreedy(DetectionGreedyConfig(**params))
    p.reset(graph, n, mode, 0)
    return p


@pytest.fixture(scope="module")
def scene(lake):
    """A lone item near the vehicle, a cluster of five farther away."""
    start = lake.node_at(12, 15)
    lone = lake.node_at(12, 18)
    cluster = [lake.node_at(6, 12), lake.node_at(6, 13), lake.node_at(7, 12), lake.node_at(7, 13)]
    evidence = np.zeros(lake.n_nodes)
    evidence[lone] = 1
    evidence[cluster] = [2, 1, 1, 1]
    return start, lone, cluster, evidence


def test_nearest_goes_for_the_closest_evidence(lake, scene):
    start, lone, cluster, evidence = scene
    assert planner(lake, 1, strategy="nearest").next_targets(observe(lake, {0: start}, evidence)) == {0: lone}


def test_densest_goes_for_the_cluster(lake, scene):
    start, lone, cluster, evidence = scene
    target = planner(lake, 1, strategy="densest").next_targets(observe(lake, {0: start}, evidence))[0]
    assert target in cluster


def test_the_next_vehicle_does_not_chase_the_same_cluster(lake, scene):
    start, lone, cluster, evidence = scene
    starts = {0: start, 1: lake.node_at(12, 16)}
    targets = planner(lake, 2, strategy="densest", separation_m=15.0).next_targets(
        observe(lake, starts, evidence)
    )
    assert targets[0] in cluster and targets[1] == lone


def test_a_full_vehicle_explores_instead(lake, scene):
    start, lone, cluster, evidence = scene
    observed = np.zeros(lake.n_nodes, bool)
    observed[lake.nodes_within(start, 10.0)] = True
    targets = planner(lake, 1).next_targets(
        observe(lake, {0: start}, evidence, observed=observed, capacity={0: 0})
    )
    assert frontier_mask(lake, observed)[targets[0]] and evidence[targets[0]] == 0


def test_without_evidence_it_explores_the_nearest_frontier(lake):
    start = lake.node_at(12, 15)
    observed = np.zeros(lake.n_nodes, bool)
    observed[lake.nodes_within(start, 10.0)] = True
    target = planner(lake, 1).next_targets(
        observe(lake, {0: start}, np.zeros(lake.n_nodes), observed=observed)
    )[0]
    edge = frontier_mask(lake, observed)
    assert edge[target] and lake.distance(start, target) == lake.distances_from(start)[edge].min()


def test_evidence_beyond_the_budget_is_ignored(lake, scene):
    start, lone, cluster, evidence = scene
    targets = planner(lake, 1, strategy="densest").next_targets(
        observe(lake, {0: start}, evidence, remaining=20.0)
    )
    assert targets == {0: lone}


def test_sequential_mode_takes_the_first_hop_towards_the_evidence(lake, scene):
    start, lone, cluster, evidence = scene
    hop = planner(lake, 1, mode="sequential").next_targets(observe(lake, {0: start}, evidence))[0]
    assert hop in lake.neighbors(start)
    assert lake.distance(hop, lone) < lake.distance(start, lone)
