"""The boat's own path planning: refined grid, water-only legs, geofence."""

from __future__ import annotations

import numpy as np
import pytest
from support.vehicle import LAKE

from guadal_cli.errors import GuadalError
from guadal_cli.graph import NavGraph
from guadal_cli.maps.format import Map, haversine_m
from guadal_cli.vehicle.lowlevel import LowLevelPlanner, refine_map


def lake(latlon: bool = False) -> Map:
    mask = np.array([[c == "1" for c in row] for row in LAKE])
    flat = Map(mask=mask, cell_size_m=5.0, reference={"row": 3, "col": 4, "lat": 37.418, "lon": -5.983})
    if not latlon:
        return flat
    return Map(mask=mask, cell_size_m=5.0, reference=flat.reference, latlon_grid=(flat.lat, flat.lon))


def water_everywhere_along(map_: Map, a, b, step_m: float = 0.1) -> bool:
    """Every point of the straight leg a->b lies in a water cell of the planner's map."""
    n = int(haversine_m(a[0], a[1], b[0], b[1]) / step_m) + 2
    for t in np.linspace(0, 1, n):
        cell = map_.rowcol_of(a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]))
        if cell is None or not map_.mask[cell]:
            return False
    return True


@pytest.mark.parametrize("latlon", [False, True])
def test_refined_grid_keeps_water_and_cell_centres(latlon):
    coarse = lake(latlon)
    fine = refine_map(coarse, 3)
    assert fine.shape == (21, 27)
    assert fine.cell_size_m == pytest.approx(5.0 / 3)
    assert np.array_equal(fine.mask[1::3, 1::3], coarse.mask)
    assert fine.water_nodes == 9 * coarse.water_nodes
    # the middle fine cell of every coarse cell sits on the coarse centre
    assert np.abs(fine.lat[1::3, 1::3] - coarse.lat).max() < 1e-9
    assert np.abs(fine.lon[1::3, 1::3] - coarse.lon).max() < 1e-9
    # neighbouring fine cells are a third of a coarse cell apart
    d = haversine_m(fine.lat[10, 10], fine.lon[10, 10], fine.lat[10, 11], fine.lon[10, 11])
    assert d == pytest.approx(5.0 / 3, rel=1e-3)


def test_refine_factor_must_be_a_positive_whole_number():
    with pytest.raises(GuadalError, match="at least 1"):
        refine_map(lake(), 0)
    m = lake()
    assert refine_map(m, 1) is m


def test_path_around_the_land_tongue_stays_on_water():
    m = lake()
    g = NavGraph(m)
    planner = LowLevelPlanner(m, 3, graph=g)
    a, b = g.node_at(1, 2), g.node_at(1, 6)  # north of each basin: the straight line crosses land
    assert not water_everywhere_along(m, (g.lat[a], g.lon[a]), (g.lat[b], g.lon[b]))
    wps = planner.plan(g.lat[a], g.lon[a], g.lat[b], g.lon[b])
    legs = [(g.lat[a], g.lon[a])] + [(w.lat, w.lon) for w in wps]
    for p, q in zip(legs, legs[1:]):
        assert water_everywhere_along(m, p, q), f"leg {p} -> {q} crosses land"
    assert (wps[-1].lat, wps[-1].lon) == (g.lat[b], g.lon[b])
    # pulled tight: a handful of waypoints, not one per fine cell (the fine path has ~30 cells)
    assert 2 <= len(wps) <= 6
    # and it goes round the tongue's southern tip (row 5), the only way across
    assert max(m.rowcol_of(w.lat, w.lon)[0] for w in wps) == 5


def test_a_leg_in_open_water_is_one_waypoint():
    m = lake()
    g = NavGraph(m)
    planner = LowLevelPlanner(m, 3, graph=g)
    a, b = g.node_at(1, 1), g.node_at(5, 3)
    wps = planner.plan(g.lat[a], g.lon[a], g.lat[b], g.lon[b])
    assert len(wps) == 1 and (wps[0].lat, wps[0].lon) == (g.lat[b], g.lon[b])


def test_geofence_accepts_water_and_names_each_refusal():
    m = lake()
    g = NavGraph(m)
    planner = LowLevelPlanner(m, 3, graph=g)
    n = g.node_at(2, 2)
    assert planner.check_target(n, g.lat[n], g.lon[n]) is None
    assert "on land" in planner.check_target(n, m.lat[2, 4], m.lon[2, 4])
    assert "outside the map" in planner.check_target(n, m.lat[0, 0] + 0.01, m.lon[0, 0])
    other = g.node_at(2, 6)
    reason = planner.check_target(n, g.lat[other], g.lon[other])
    assert f"is node {other}, not the node {n}" in reason


def test_no_water_path_between_two_ponds_is_an_error():
    mask = np.array([[c == "1" for c in row] for row in ["11011", "11011"]])
    m = Map(mask=mask, cell_size_m=5.0, reference={"row": 0, "col": 0, "lat": 37.0, "lon": -5.0})
    g = NavGraph(m)
    planner = LowLevelPlanner(m, 3, graph=g)
    a, b = g.node_at(0, 0), g.node_at(0, 4)
    with pytest.raises(GuadalError, match="no water path"):
        planner.plan(g.lat[a], g.lon[a], g.lat[b], g.lon[b])
