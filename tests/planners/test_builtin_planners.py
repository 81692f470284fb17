import numpy as np
import pytest

from guadal_cli.envs.base import Observation
from guadal_cli.graph import NavGraph
from guadal_cli.maps.format import load_map
from guadal_cli.planners.expected_improvement import EIConfig, ExpectedImprovement
from guadal_cli.planners.greedy import GreedyStd
from guadal_cli.planners.lawnmower import Lawnmower, boustrophedon_routes
from guadal_cli.planners.random_walk import RandomPlanner


@pytest.fixture(scope="module")
def lake():
    return NavGraph(load_map("maps/urban_lake.json"))


def observe(graph, positions, std=None, mean=None, remaining=1e9, visits=None):
    n = graph.n_nodes
    return Observation(
        step=0,
        time_s=0.0,
        graph=graph,
        positions=positions,
        remaining={v: remaining for v in positions},
        done={v: False for v in positions},
        visits=np.zeros(n, int) if visits is None else visits,
        fields={"std": np.ones(n) if std is None else std, "mean": np.zeros(n) if mean is None else mean},
    )


def test_greedy_moves_to_the_most_uncertain_free_neighbour(lake):
    start = lake.node_at(12, 15)
    nbrs = lake.neighbors(start)
    std = np.zeros(lake.n_nodes)
    std[nbrs[2]] = 0.9
    std[nbrs[5]] = 0.5
    planner = GreedyStd()
    planner.reset(lake, 2, "sequential", 0)
    # vehicle 1 sits on the best neighbour: vehicle 0 must take the second best
    targets = planner.next_targets(observe(lake, {0: start, 1: nbrs[2]}, std=std))
    assert targets[0] == nbrs[5]
    assert targets[0] in lake.neighbors(start)


def test_greedy_vehicles_never_claim_the_same_node(lake):
    a = lake.node_at(12, 15)
    b = lake.node_at(12, 17)  # two cells apart: they share neighbours
    std = np.zeros(lake.n_nodes)
    std[lake.node_at(12, 16)] = 1.0  # the shared neighbour is best for both
    planner = GreedyStd()
    planner.reset(lake, 2, "sequential", 0)
    targets = planner.next_targets(observe(lake, {0: a, 1: b}, std=std))
    assert targets[0] == lake.node_at(12, 16)
    assert targets[1] != targets[0]


def test_greedy_respects_the_remaining_budget(lake):
    planner = GreedyStd()
    planner.reset(lake, 1, "sequential", 0)
    assert planner.next_targets(observe(lake, {0: lake.node_at(12, 15)}, remaining=4.0)) == {}


def test_expected_improvement_spreads_vehicles_over_distinct_regions(lake):
    mean = np.zeros(lake.n_nodes)
    std = np.full(lake.n_nodes, 0.2)
    peak = lake.node_at(10, 12)
    mean[lake.nodes_within(peak, 12.0)] = 0.8  # one attractive region
    planner = ExpectedImprovement(EIConfig(exclusion_radius=30.0))
    planner.reset(lake, 3, "target", 0)
    starts = {0: lake.node_at(14, 20), 1: lake.node_at(15, 20), 2: lake.node_at(16, 20)}
    targets = planner.next_targets(observe(lake, starts, std=std, mean=mean))
    assert np.hypot(*(lake.xy[targets[0]] - lake.xy[peak])) <= 12.0
    chosen = list(targets.values())
    for i in range(3):
        for j in range(i + 1, 3):
            assert np.hypot(*(lake.xy[chosen[i]] - lake.xy[chosen[j]])) > 30.0


def test_lawnmower_routes_cover_every_node_once_and_split_evenly(lake):
    starts = {0: lake.node_at(12, 10), 1: lake.node_at(12, 20), 2: lake.node_at(12, 30)}
    routes = boustrophedon_routes(lake, starts)
    all_nodes = sorted(n for r in routes.values() for n in r)
    reachable = np.nonzero(lake.component == lake.component[starts[0]])[0].tolist()
    assert all_nodes == reachable
    sizes = [len(r) for r in routes.values()]
    assert max(sizes) - min(sizes) <= 1
    # consecutive nodes of a sweep are mostly neighbours (a lawnmower, not a jump list)
    adjacent = sum(b in lake.neighbors(a) for r in routes.values() for a, b in zip(r, r[1:]))
    assert adjacent / sum(len(r) - 1 for r in routes.values()) > 0.85


def test_lawnmower_finishes_when_everything_is_visited(lake):
    planner = Lawnmower()
    planner.reset(lake, 1, "target", 0)
    start = lake.node_at(12, 15)
    visits = np.zeros(lake.n_nodes, int)
    assert planner.next_targets(observe(lake, {0: start}, visits=visits))
    visits[:] = 1
    assert planner.next_targets(observe(lake, {0: start}, visits=visits)) == {}
    assert planner.done


def test_random_planner_is_reproducible_from_its_seed(lake):
    def draws(seed):
        p = RandomPlanner()
        p.reset(lake, 2, "target", seed)
        obs = observe(lake, {0: lake.node_at(12, 15), 1: lake.node_at(12, 20)})
        return [tuple(sorted(p.next_targets(obs).items())) for _ in range(5)]

    assert draws(1) == draws(1)
    assert draws(1) != draws(2)
