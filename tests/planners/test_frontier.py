import numpy as np
import pytest
from support import LAKE

from guadal_cli.envs.base import Observation
from guadal_cli.graph import NavGraph
from guadal_cli.maps.format import load_map
from guadal_cli.planners._spreading import frontier_mask
from guadal_cli.planners.frontier import Frontier, FrontierConfig


@pytest.fixture(scope="module")
def lake():
    return NavGraph(load_map(LAKE))


def observe(graph, positions, observed, age=None, remaining=1e9, done=None):
    fields = {"observed": observed.astype(float)}
    if age is not None:
        fields["age"] = age
    return Observation(
        step=0,
        time_s=0.0,
        graph=graph,
        positions=positions,
        remaining={v: remaining for v in positions},
        done=done or {v: False for v in positions},
        visits=np.zeros(graph.n_nodes, int),
        fields=fields,
    )


def seen_around(graph, nodes, radius=10.0):
    observed = np.zeros(graph.n_nodes, bool)
    for n in nodes:
        observed[graph.nodes_within(n, radius)] = True
    return observed


def planner(graph, n, mode="target", **params):
    p = Frontier(FrontierConfig(**params))
    p.reset(graph, n, mode, 0)
    return p


def test_frontier_is_the_unobserved_edge_of_what_is_known(lake):
    observed = seen_around(lake, [lake.node_at(12, 15)])
    edge = frontier_mask(lake, observed)
    assert edge.any() and not (edge & observed).any()
    for n in np.nonzero(edge)[0]:
        assert observed[list(lake.neighbors(n))].any()
    assert frontier_mask(lake, np.zeros(lake.n_nodes, bool)).all()


def test_each_vehicle_goes_to_its_nearest_frontier_and_they_spread(lake):
    starts = {0: lake.node_at(12, 15), 1: lake.node_at(12, 16), 2: lake.node_at(12, 17)}
    observed = seen_around(lake, starts.values())
    targets = planner(lake, 3, separation_m=15.0).next_targets(observe(lake, starts, observed))
    assert sorted(targets) == [0, 1, 2]
    edge = frontier_mask(lake, observed)
    dist0 = lake.distances_from(starts[0])
    assert dist0[targets[0]] == dist0[edge].min()  # the first chooser gets its nearest frontier
    for _v, t in targets.items():
        assert edge[t]
    chosen = list(targets.values())
    for i in range(3):
        for j in range(i + 1, 3):
            assert np.hypot(*(lake.xy[chosen[i]] - lake.xy[chosen[j]])) > 15.0


def test_budget_and_parked_vehicles_are_respected(lake):
    starts = {0: lake.node_at(12, 15), 1: lake.node_at(12, 25)}
    observed = seen_around(lake, starts.values())
    targets = planner(lake, 2).next_targets(observe(lake, starts, observed, done={0: True, 1: False}))
    assert list(targets) == [1]
    assert planner(lake, 2).next_targets(observe(lake, starts, observed, remaining=4.0)) == {}


def test_once_all_is_observed_it_renews_the_stalest_or_stops(lake):
    observed = np.ones(lake.n_nodes, bool)
    age = np.full(lake.n_nodes, 10.0)
    stale = lake.node_at(18, 15)
    age[stale] = 500.0
    start = {0: lake.node_at(12, 30)}
    assert planner(lake, 1).next_targets(observe(lake, start, observed, age=age)) == {0: stale}
    assert planner(lake, 1, revisit=False).next_targets(observe(lake, start, observed, age=age)) == {}
    assert planner(lake, 1).next_targets(observe(lake, start, observed)) == {}  # no age: nothing to renew


def test_sequential_mode_sends_a_free_neighbour_towards_the_frontier(lake):
    starts = {0: lake.node_at(12, 15), 1: lake.node_at(12, 16)}
    observed = seen_around(lake, starts.values(), radius=20.0)
    targets = planner(lake, 2, mode="sequential").next_targets(observe(lake, starts, observed))
    for v, t in targets.items():
        assert t in lake.neighbors(starts[v]) and t not in starts.values()
    assert len(set(targets.values())) == len(targets)


def test_a_target_the_vehicle_could_not_move_towards_is_not_sent_again(lake):
    start = {0: lake.node_at(12, 15)}
    observed = seen_around(lake, start.values())
    p = planner(lake, 1)
    first = p.next_targets(observe(lake, start, observed))[0]
    second = p.next_targets(observe(lake, start, observed))[0]  # it did not move: blocked
    assert second != first
