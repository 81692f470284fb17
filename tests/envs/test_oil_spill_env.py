"""The oil-spill environment: mass balance, no-flux land, drift, the observed map and its metrics."""

import math

import numpy as np
import pytest
from support import LAKE

from guadal_cli.envs.oil_spill import OilSpillConfig, OilSpillEnvironment
from guadal_cli.fleet.base import Measurement
from guadal_cli.graph import NavGraph
from guadal_cli.maps.format import Map, load_map


@pytest.fixture(scope="module")
def lake():
    return NavGraph(load_map(LAKE))


def make(graph, seed=0, **params):
    env = OilSpillEnvironment(OilSpillConfig(**params), graph)
    env.reset(seed)
    return env


def sample(env, graph, vehicle, node, t):
    return Measurement(
        vehicle, int(node), env.sense(vehicle, node), float(graph.lat[node]), float(graph.lon[node]), float(t)
    )


def centroid(env, graph):
    return (env.mass[:, None] * graph.xy).sum(axis=0) / env.mass.sum()


def test_mass_is_conserved_without_a_sink_while_the_slick_spreads_and_drifts(lake):
    env = make(
        lake,
        sources=[{"row": 10, "col": 12, "mass": 1000.0, "radius_m": 5}],
        diffusivity=0.2,
        drift={"current": [0.02, 0.01]},
    )
    start_peak, start_centre = env.mass.max(), centroid(env, lake)
    for t in np.arange(37.0, 4000.0, 37.0):  # uneven hops, like a mission's
        env.advance(float(t))
        assert env.mass.sum() == pytest.approx(1000.0, rel=1e-9)
        assert env.mass.min() >= -1e-12
    assert env.mass.max() < start_peak / 5  # it spread
    shift = centroid(env, lake) - start_centre
    assert shift[0] > 10 and shift[1] > 0  # downstream: east and north


def test_land_is_a_no_flux_boundary_mass_stays_in_its_own_water_body():
    mask = np.zeros((7, 12), bool)
    mask[1:6, 1:5] = True  # west pond
    mask[1:6, 6:11] = True  # east pond, one land column between them
    graph = NavGraph(
        Map(mask=mask, cell_size_m=5.0, reference={"row": 3, "col": 5, "lat": 37.0, "lon": -6.0})
    )
    env = make(
        graph,
        sources=[{"row": 3, "col": 4, "mass": 500.0, "radius_m": 0}],
        diffusivity=1.0,
        drift={"current": [0.5, 0.0]},
    )  # pushed hard towards the other pond
    env.advance(3000.0)
    west = graph.cols < 5
    assert env.mass[west].sum() == pytest.approx(500.0, rel=1e-9)
    assert env.mass[~west].sum() == 0.0
    east_shore = west & (graph.cols == 4)
    assert env.mass[east_shore].sum() > env.mass[west & (graph.cols == 1)].sum()  # it piles up downwind


def test_decay_and_continuous_release_are_the_only_changes_of_mass(lake):
    env = make(
        lake,
        sources=[{"node": 40, "mass": 300.0, "rate": 0.5, "start_s": 0, "duration_s": 200}],
        decay_rate=0.0,
    )
    env.advance(1000.0)
    assert env.mass.sum() == pytest.approx(300.0 + 0.5 * 200, rel=1e-9)
    decaying = make(lake, sources=[{"node": 40, "mass": 300.0}], decay_rate=1e-3)
    decaying.advance(700.0)
    assert decaying.mass.sum() == pytest.approx(300.0 * math.exp(-0.7), rel=1e-9)
    late = make(lake, sources=[{"node": 40, "mass": 300.0, "start_s": 500}])
    late.advance(400.0)
    assert late.mass.sum() == 0.0
    late.advance(600.0)
    assert late.mass.sum() == pytest.approx(300.0)


def test_a_sample_overwrites_the_observed_map_within_the_view_radius_and_nowhere_else(lake):
    env = make(lake, sources=[{"row": 10, "col": 12, "mass": 2000.0}], diffusivity=0.1, view_radius_m=10.0)
    env.advance(300.0)
    node = lake.node_at(10, 14)
    env.update([sample(env, lake, 0, node, 300.0)])
    view = np.zeros(lake.n_nodes, bool)
    view[lake.nodes_within(node, 10.0)] = True
    fields = env.observation_fields()
    assert np.array_equal(fields["concentration"][view], env.ground_truth[view])
    assert (fields["concentration"][~view] == 0).all()
    assert np.array_equal(fields["observed"] > 0, view)
    assert (fields["age"][view] == 0).all() and np.isnan(fields["age"][~view]).all()
    env.advance(400.0)
    assert (env.observation_fields()["age"][view] == 100.0).all()


def test_a_leg_folded_in_late_is_judged_against_the_field_at_each_sample_time(lake):
    """Target mode: samples of a whole leg reach update() together, after the field moved on."""
    env = make(
        lake,
        sources=[{"row": 10, "col": 12, "mass": 2000.0}],
        diffusivity=0.1,
        drift={"current": [0.05, 0.0]},
    )
    node = lake.node_at(10, 15)
    env.advance(100.0)
    early = sample(env, lake, 0, node, 100.0)
    truth_then = env.ground_truth.copy()
    env.advance(900.0)
    env.update([early])
    view = lake.nodes_within(node, env.config.view_radius_m)
    assert np.array_equal(env.observation_fields()["concentration"][view], truth_then[view])
    assert not np.allclose(truth_then[view], env.ground_truth[view])


def test_metrics_iou_coverage_and_error(lake):
    env = make(
        lake, sources=[{"row": 10, "col": 12, "mass": 2000.0, "radius_m": 8}], diffusivity=0.05, threshold=0.5
    )
    env.advance(200.0)
    m = env.metrics()
    assert m["iou"] == 0 and m["detection_coverage"] == 0 and m["observed_fraction"] == 0
    assert m["concentration_rmse"] == pytest.approx(float(np.sqrt(np.mean(env.ground_truth**2))))
    truth = env.ground_truth > 0.5
    env.update([sample(env, lake, v, n, 200.0) for v, n in enumerate(range(lake.n_nodes))])  # look everywhere
    m = env.metrics()
    assert m["iou"] == 1.0 and m["detection_coverage"] == 1.0 and m["concentration_rmse"] == 0.0
    assert m["observed_fraction"] == 1.0 and truth.sum() > 3
    assert m["total_mass"] == pytest.approx(2000.0)


def test_leads_mark_unobserved_or_stale_water_on_and_beside_the_slick(lake):
    env = make(
        lake,
        sources=[{"row": 10, "col": 12, "mass": 2000.0}],
        diffusivity=0.05,
        threshold=0.5,
        view_radius_m=5.0,
        stale_after_s=100.0,
    )
    env.advance(10.0)
    env.update([sample(env, lake, 0, lake.node_at(10, 12), 10.0)])
    fields = env.observation_fields()
    contaminated = fields["concentration"] > 0.5
    assert contaminated.any()
    leads = fields["evidence"] > 0
    assert leads.any() and not (leads & (fields["observed"] > 0)).any()  # fresh nodes are no lead
    for n in np.nonzero(leads)[0]:
        assert contaminated[list(lake.neighbors(n))].any()
    env.advance(200.0)  # observations grow stale: the slick itself becomes a lead again
    assert (env.observation_fields()["evidence"][contaminated] > 0).all()


def test_random_sources_depend_on_the_seed_only(lake):
    a, b, c = (make(lake, seed=s, sources=2) for s in (3, 3, 4))
    assert np.array_equal(a.mass, b.mass) and not np.array_equal(a.mass, c.mass)
    assert a.mass.sum() == pytest.approx(2 * 1000.0)
