import math

import networkx as nx
import numpy as np
import pytest

from guadal_cli.errors import GuadalError
from guadal_cli.graph import NavGraph
from guadal_cli.maps.format import Map, haversine_m, load_map


def l_lake() -> Map:
    """An L of water: a vertical arm (col 0) and a horizontal arm (row 4), 5 m cells."""
    mask = np.zeros((5, 5), dtype=bool)
    mask[:, 0] = True
    mask[4, :] = True
    return Map(mask=mask, cell_size_m=5.0, reference={"row": 0, "col": 0, "lat": 37.0, "lon": -6.0})


def _open_water_3x3() -> NavGraph:
    """Nine water cells of 5 m, the centre at the reference."""
    return NavGraph(
        Map(
            mask=np.ones((3, 3), bool),
            cell_size_m=5.0,
            reference={"row": 1, "col": 1, "lat": 37.0, "lon": -6.0},
        )
    )


def test_eight_connected_with_metric_lengths():
    g = _open_water_3x3()
    centre = g.node_at(1, 1)
    assert len(g.neighbors(centre)) == 8
    assert g.edge_length(centre, g.node_at(0, 1)) == pytest.approx(5.0)
    assert g.edge_length(centre, g.node_at(0, 0)) == pytest.approx(5.0 * math.sqrt(2))
    with pytest.raises(KeyError):
        g.edge_length(g.node_at(0, 0), g.node_at(2, 2))  # not neighbours


def test_hops_within_a_budget_and_the_cheapest_hop():
    g = _open_water_3x3()
    centre, corner = g.node_at(1, 1), g.node_at(0, 0)
    straight = [n for n in g.neighbors(centre) if g.edge_length(centre, n) < 6.0]
    assert g.neighbours_within(centre, 7.0) == straight and len(straight) == 4  # diagonals cost 7.07 m
    assert g.neighbours_within(centre, 5.0 * math.sqrt(2)) == list(g.neighbors(centre))
    assert g.neighbours_within(centre, 4.99) == []
    assert g.shortest_edge(centre) == pytest.approx(5.0) and g.shortest_edge(corner) == pytest.approx(5.0)
    island = NavGraph(  # one cell of water
        Map(
            mask=np.ones((1, 1), bool),
            cell_size_m=5.0,
            reference={"row": 0, "col": 0, "lat": 37.0, "lon": -6.0},
        )
    )
    assert island.shortest_edge(0) == math.inf and island.neighbours_within(0, 100.0) == []


def test_distances_searched_within_a_limit_and_paths_beyond_it():
    g = NavGraph(load_map("maps/urban_lake.json"))
    full = g.distances_from(0).copy()
    g._trees.clear()
    near = g.distances_from(0, limit=40.0)
    assert np.array_equal(near[full <= 40.0], full[full <= 40.0])
    assert np.isinf(near[full > 40.0]).all() and (full > 40.0).any()
    far = int(np.argmax(np.where(np.isfinite(full), full, -1)))
    path = g.shortest_path(0, far)  # beyond the limited search: the whole tree is searched then
    assert path[0] == 0 and path[-1] == far
    assert sum(g.edge_length(a, b) for a, b in zip(path, path[1:])) == pytest.approx(full[far])
    assert np.array_equal(g.distances_from(0, limit=40.0), full)  # the whole tree serves a limit


def test_to_networkx_is_the_same_graph_with_its_attributes():
    g = NavGraph(l_lake())
    g.fill_graph_attribute("depth", np.arange(g.n_nodes, dtype=float))
    nxg = g.to_networkx()
    assert nxg.number_of_nodes() == g.n_nodes
    assert nxg.number_of_edges() == g.adjacency.nnz // 2
    corner = g.node_at(4, 0)
    assert set(nxg.neighbors(corner)) == set(g.neighbors(corner))
    assert nxg.nodes[corner]["depth"] == float(corner)
    assert nxg.nodes[corner]["row"] == 4 and nxg.nodes[corner]["lat"] == pytest.approx(g.lat[corner])
    a, b = g.node_at(0, 0), g.node_at(4, 4)
    assert nx.shortest_path_length(nxg, a, b, weight="weight") == pytest.approx(g.distance(a, b))


def test_path_cache_is_bounded_in_memory(monkeypatch):
    monkeypatch.setattr(NavGraph, "PATH_CACHE_BYTES", 0)  # as on a lake too big for more than a few
    g = NavGraph(
        Map(mask=np.ones((6, 6), bool), cell_size_m=5.0, reference={"row": 0, "col": 0, "lat": 37, "lon": -6})
    )
    first = g.distances_from(0).copy()
    for source in range(g.n_nodes):
        g.distances_from(source)
    assert len(g._trees) == 4  # the floor: the most recent sources only
    assert np.array_equal(g.distances_from(0), first)  # evicted trees are recomputed identically


def test_shortest_path_stays_on_water_around_the_corner():
    g = NavGraph(l_lake())
    top, right = g.node_at(0, 0), g.node_at(4, 4)
    path = g.shortest_path(top, right)
    assert all(l_lake().mask[g.rows[n], g.cols[n]] for n in path)
    # down the arm (4 straight hops) and along the bottom (4 straight), except one diagonal at the corner
    assert g.distance(top, right) == pytest.approx(3 * 5 + 5 * math.sqrt(2) + 3 * 5)


def test_nearest_node_and_georeference_agree():
    m = l_lake()
    g = NavGraph(m)
    n = g.node_at(4, 3)
    assert g.nearest_node(g.lat[n], g.lon[n]) == n
    # one cell east is 5 m on the ground
    assert haversine_m(g.lat[g.node_at(4, 2)], g.lon[g.node_at(4, 2)], g.lat[n], g.lon[n]) == pytest.approx(
        5.0, rel=1e-3
    )


def test_fill_graph_attribute_accepts_node_vectors_and_grids():
    g = NavGraph(l_lake())
    g.fill_graph_attribute("depth", np.arange(g.n_nodes, dtype=float))
    assert g.node_attribute("depth")[3] == 3.0
    grid = np.full((5, 5), 7.0)
    g.fill_graph_attribute("temp", grid)
    assert set(g.node_attribute("temp")) == {7.0}
    with pytest.raises(GuadalError, match="needs 9 values"):
        g.fill_graph_attribute("bad", [1.0, 2.0])


def test_separate_water_bodies_are_separate_components():
    mask = np.zeros((3, 7), bool)
    mask[:, :2] = True
    mask[:, 5:] = True
    g = NavGraph(Map(mask=mask, cell_size_m=5, reference={"row": 0, "col": 0, "lat": 37, "lon": -6}))
    assert g.n_components == 2
    assert g.shortest_path(g.node_at(0, 0), g.node_at(0, 6)) == []


def test_map_round_trip_and_shipped_maps(tmp_path):
    m = l_lake()
    m.name = "ell"
    m.save(tmp_path / "ell.json")
    back = load_map(tmp_path / "ell.json")
    assert (back.mask == m.mask).all() and back.summary() == m.summary()
    small = load_map("maps/urban_lake.json").summary()
    assert small["shape"] == [30, 49] and small["water_nodes"] == 351 and small["cell_size_m"] == 5.0
    assert load_map("maps/reservoir.json").summary()["water_nodes"] >= 5000


def test_full_latlon_grid_maps_take_positions_from_coordinates(tmp_path):
    lat = 37.0 + np.arange(3)[:, None] * -1e-4 + np.zeros((3, 4))
    lon = -6.0 + np.arange(4)[None, :] * 1.2e-4 + np.zeros((3, 4))
    m = Map(
        mask=np.ones((3, 4), bool),
        cell_size_m=10,
        reference={"row": 0, "col": 0, "lat": 37.0, "lon": -6.0},
        latlon_grid=(lat, lon),
    )
    m.save(tmp_path / "grid.json")
    g = NavGraph(load_map(tmp_path / "grid.json"))
    # non-square cells: ~11.1 m north-south, ~10.6 m east-west at 37 degrees
    assert g.edge_length(g.node_at(0, 0), g.node_at(1, 0)) == pytest.approx(11.12, abs=0.05)
    assert g.edge_length(g.node_at(0, 0), g.node_at(0, 1)) == pytest.approx(10.65, abs=0.05)


def test_a_map_from_a_mask_and_latlon_matrices_keeps_every_cell_where_it_is(tmp_path):
    lat = 37.0 + np.arange(3)[:, None] * -1e-4 + np.zeros((3, 4))
    lon = -6.0 + np.arange(4)[None, :] * 1.2e-4 + np.zeros((3, 4))
    mask = np.array([[1, 1, 1, 0], [1, 0, 1, 1], [1, 1, 1, 1]])
    m = Map.from_grids(mask, lat, lon, name="pond")
    m.save(tmp_path / "pond.json")
    g = NavGraph(load_map(tmp_path / "pond.json"))
    assert g.n_nodes == 10 and g.node_at(1, 1) is None and g.node_at(0, 3) is None
    assert np.allclose(g.lat, lat[mask == 1]) and np.allclose(g.lon, lon[mask == 1])
    assert m.cell_size_m == pytest.approx(10.65, abs=0.05)  # the median spacing of neighbours
    with pytest.raises(GuadalError, match=r"^a map's mask must hold 0 \(land\) and 1 \(water\) only\.$"):
        Map.from_grids(mask * 2, lat, lon)
    with pytest.raises(GuadalError, match=r"must have the mask's shape \(3, 4\) \(got \(3, 3\)"):
        Map.from_grids(mask, lat[:, :3], lon)


@pytest.mark.parametrize(
    "content, fragment",
    [
        ("not json", "not readable JSON"),
        ('{"format": "other"}', "not a guadal map"),
        (
            '{"format": "guadal-map", "version": 1, "mask": ["01", "1"], "cell_size_m": 5, '
            '"reference": {"row": 0, "col": 0, "lat": 0, "lon": 0}}',
            "mask row 1",
        ),
        (
            '{"format": "guadal-map", "version": 1, "mask": ["00"], "cell_size_m": 5, '
            '"reference": {"row": 0, "col": 0, "lat": 0, "lon": 0}}',
            "no water",
        ),
        (
            '{"format": "guadal-map", "version": 1, "mask": ["01"], "cell_size_m": -1, '
            '"reference": {"row": 0, "col": 0, "lat": 0, "lon": 0}}',
            "cell_size_m",
        ),
    ],
)
def test_bad_map_files_get_one_sentence(tmp_path, content, fragment):
    path = tmp_path / "bad.json"
    path.write_text(content)
    with pytest.raises(GuadalError, match=fragment):
        load_map(path)
