"""Mutated shipped maps: each is refused with one sentence, or loads and makes a graph."""

from __future__ import annotations

import copy
import json

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from support import ROOT
from support.fuzz import NASTY, assert_one_sentence, examples, paths_of, set_at, time_limit

from guadal_cli.errors import GuadalError
from guadal_cli.graph import NavGraph
from guadal_cli.maps.format import check_node_limit, load_map

MAPS = {p.stem: json.loads(p.read_text()) for p in sorted((ROOT / "maps").glob("*.json"))}
#: a few grids of coordinates to mutate too (the shipped maps are north-up and give none)
SMALL = copy.deepcopy(MAPS["urban_lake"])


def _with_latlon(data: dict) -> dict:
    from guadal_cli.maps.format import map_from_dict

    m = map_from_dict(data)
    return {**data, "latlon": {"lat": m.lat.round(9).tolist(), "lon": m.lon.round(9).tolist()}}


MAPS["urban_lake_latlon"] = _with_latlon(SMALL)
#: values a grid of numbers may get
CELLS = st.one_of(st.floats(), st.sampled_from([float("nan"), float("inf"), 1e300, -1e300, 0.0, 500.0]))


def load_then_build(data, folder) -> None:
    path = folder / "map.json"
    try:
        path.write_text(json.dumps(data))
    except (ValueError, UnicodeEncodeError):
        return
    with time_limit(60):
        try:
            map_ = load_map(path)
            check_node_limit(map_)
        except GuadalError as exc:
            assert_one_sentence(exc)
            return
        graph = NavGraph(map_)
        map_.summary()
        node = graph.nearest_node(float(graph.lat[0]), float(graph.lon[0]))
        assert 0 <= node < graph.n_nodes
        assert all(length > 0 for length in graph.adjacency.data)


@settings(
    max_examples=examples(60),
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(data=st.data(), name=st.sampled_from(sorted(MAPS)))
def test_a_mutated_map_is_refused_in_one_sentence_or_builds_a_graph(data, name, tmp_path_factory):
    doc = copy.deepcopy(MAPS[name])
    for _ in range(data.draw(st.integers(1, 3), label="mutations")):
        paths = [p for p in paths_of(doc) if not (len(p) > 2 and p[0] in ("mask", "latlon"))]
        path = data.draw(st.sampled_from(paths), label="path")
        grids = doc.get("latlon") if isinstance(doc, dict) else None
        if isinstance(grids, dict) and data.draw(st.booleans(), label="poke a coordinate"):
            grid = grids.get(data.draw(st.sampled_from(["lat", "lon"]), label="grid"))
            if isinstance(grid, list) and grid and isinstance(grid[0], list) and grid[0]:
                r = data.draw(st.integers(0, len(grid) - 1), label="row")
                c = data.draw(st.integers(0, len(grid[0]) - 1), label="col")
                if isinstance(grid[r], list) and c < len(grid[r]):
                    grid[r][c] = data.draw(CELLS, label="coordinate")
        else:
            doc = set_at(doc, path, data.draw(NASTY, label="value"))
    load_then_build(doc, tmp_path_factory.mktemp("map"))
