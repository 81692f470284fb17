"""Map files a careless or hostile user writes: one sentence from every command, never a crash.

Each case once got past ``map info`` and crashed ``map show``, ``validate`` or ``run`` (in the
KD-tree, the graph, or by exhausting memory), or made ``run`` hang.
"""

import copy
import json

import pytest
import yaml
from support import LAKE, base_mission, run_cli
from typer.testing import CliRunner

from guadal_cli.app import app
from guadal_cli.errors import GuadalError
from guadal_cli.maps.format import load_map, map_from_dict

LAKE_DATA = json.loads(LAKE.read_text())


def lake(**changes) -> dict:
    data = copy.deepcopy(LAKE_DATA)
    for key, value in changes.items():
        if key.startswith("reference_"):
            data["reference"][key.removeprefix("reference_")] = value
        else:
            data[key] = value
    return data


def latlon_lake(poke=None) -> dict:
    m = map_from_dict(LAKE_DATA)
    lat, lon = m.lat.tolist(), m.lon.tolist()
    if poke:
        poke(lat, lon)
    return lake(latlon={"lat": lat, "lon": lon})


def refused_everywhere(data, tmp_path, *fragments):
    """map info, map show and validate all refuse the map with the same sentence."""
    path = tmp_path / "bad.json"
    path.write_text(data if isinstance(data, str) else json.dumps(data))
    mission = tmp_path / "m.yaml"
    mission.write_text(yaml.safe_dump(base_mission(map=str(path))))
    for args in (["map", "info", str(path)], ["map", "show", str(path)], ["validate", str(mission)]):
        result = CliRunner().invoke(app, args)
        message = " ".join(result.output.split())
        assert result.exit_code == 2, (args, result.output)
        assert "Traceback" not in result.output
        for fragment in fragments:
            assert fragment in message, f"{args}: {fragment!r} not in {message!r}"
    assert not (tmp_path / "bad.png").exists()


CASES = {
    "reference row not a whole number": (lake(reference_row=2.5), ["reference row and col must be whole"]),
    "reference row a string": (lake(reference_row="15"), ["reference row and col must be whole"]),
    "reference col huge": (lake(reference_col=10**30), ["cols 0..48"]),
    "reference row a list": (lake(reference_row=[1]), ["reference row and col must be whole"]),
    "reference latitude 500": (lake(reference_lat=500), ["reference lat must be a number in [-90, 90]"]),
    "reference latitude true": (lake(reference_lat=True), ["reference lat must be a number"]),
    "version true": (lake(version=True), ["has version True; this guadal reads version 1"]),
    "version nested": (lake(version={"v": 1}), ["has version dict"]),
    "cell size tiny": (
        lake(cell_size_m=1e-300),
        ["'cell_size_m' must be a number of metres between 0.1 and 1000"],
    ),
    "cell size huge": (lake(cell_size_m=1e300), ["between 0.1 and 1000"]),
    "grid reaching past the pole": (
        lake(reference_lat=89.9999, cell_size_m=1000.0),
        ["latitudes in [-90, 90]", "reaches beyond"],
    ),
    "NaN in the lat grid": (
        latlon_lake(lambda lat, lon: lat[3].__setitem__(4, float("nan"))),
        ["'latlon' holds NaN or infinite coordinates"],
    ),
    "inf in the lon grid": (
        latlon_lake(lambda lat, lon: lon[0].__setitem__(0, float("inf"))),
        ["'latlon' holds NaN or infinite coordinates"],
    ),
    "latitude 500 in the grid": (
        latlon_lake(lambda lat, lon: lat[5].__setitem__(5, 500.0)),
        ["latitudes in [-90, 90]"],
    ),
    "grid collapsed to one point": (
        latlon_lake(lambda lat, lon: [row.__setitem__(slice(None), [37.4] * len(row)) for row in lat + lon]),
        ["neighbouring cells 0 m apart", "collapsed to one point"],
    ),
    "one coordinate flung away": (
        latlon_lake(lambda lat, lon: lat[10].__setitem__(10, 38.4)),
        ["neighbouring cells", "near row 9, col 10"],
    ),
    "latlon grid of the wrong shape": (
        lake(latlon={"lat": [[1.0, 2.0]], "lon": [[1.0, 2.0]]}),
        ["'latlon' grids must have the mask's shape 30x49"],
    ),
    "latlon nested deeper": (lake(latlon={"lat": [[[1.0]]], "lon": 3}), ["'latlon' grids must have"]),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_bad_map_gets_one_sentence_from_every_command(case, tmp_path):
    data, fragments = CASES[case]
    refused_everywhere(data, tmp_path, *fragments)


def test_deeply_nested_json_is_refused(tmp_path):
    refused_everywhere(
        '{"format": "guadal-map", "mask": ' + "[" * 100_000 + "]" * 100_000 + "}",
        tmp_path,
        "nests its JSON too deeply",
    )


def test_a_grid_too_large_for_memory_is_refused_before_it_is_built(tmp_path):
    data = lake(mask=["1" * 2001] * 2000, reference_row=0, reference_col=0)
    refused_everywhere(data, tmp_path, "the mask is 2000x2001; maps are at most 4,000,000 cells")


def test_the_node_limit_names_itself_and_how_to_raise_it(tmp_path, write_mission):
    data = lake(mask=["1" * 300] * 200, reference_row=0, reference_col=0)
    path = tmp_path / "big.json"
    path.write_text(json.dumps(data))
    mission = write_mission(base_mission(map=str(path)))
    proc = run_cli("validate", mission, env={"GUADAL_MAX_NODES": "50000"})
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    message = " ".join(proc.stderr.split())
    assert "60,000 water nodes; guadal builds graphs of at most 50,000" in message
    assert "set GUADAL_MAX_NODES to raise the limit" in message
    # map info still reads it (no graph is built), and the variable sets the limit
    assert load_map(path).water_nodes == 60_000


def test_the_node_limit_comes_from_the_environment(monkeypatch):
    from guadal_cli.maps.format import DEFAULT_MAX_NODES, max_nodes

    assert max_nodes() == DEFAULT_MAX_NODES
    monkeypatch.setenv("GUADAL_MAX_NODES", "70000")
    assert max_nodes() == 70_000
    monkeypatch.setenv("GUADAL_MAX_NODES", "lots")
    with pytest.raises(GuadalError, match="GUADAL_MAX_NODES must be a whole number of nodes above 0"):
        max_nodes()
