"""Bad input: one sentence naming the file and field, exit code 2, no traceback, no run directory."""

import copy

import pytest
from support import base_mission, run_cli
from typer.testing import CliRunner

from guadal_cli.app import app


def mutate(path, value):
    m = base_mission()
    node = m
    for key in path[:-1]:
        node = node[key]
    if value is DELETE:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return m


DELETE = object()

CASES = {
    "unknown top-level key": (
        lambda: {**base_mission(), "flet": {}},
        ["flet", "unknown key", "allowed:", "fleet"],
    ),
    "unknown fleet key": (
        lambda: mutate(["fleet", "speeed"], 1.0),
        ["fleet.speeed", "unknown key", "max_distance"],
    ),
    "unknown plugin param": (
        lambda: mutate(["algorithm", "temperature"], 3),
        ["algorithm.temperature", "unknown key"],
    ),
    "wrong type": (lambda: mutate(["fleet", "vehicles"], "three"), ["fleet.vehicles", "integer"]),
    "budget zero": (lambda: mutate(["fleet", "max_distance"], 0), ["fleet.max_distance", "greater than 0"]),
    "budget negative": (
        lambda: mutate(["fleet", "max_distance"], -50),
        ["fleet.max_distance", "greater than 0", "-50"],
    ),
    "zero vehicles": (
        lambda: mutate(["fleet", "vehicles"], 0),
        ["fleet.vehicles", "greater than or equal to 1"],
    ),
    "more vehicles than nodes": (
        lambda: mutate(["fleet", "vehicles"], 400),
        ["fleet.vehicles", "400 vehicles", "351 water nodes"],
    ),
    "missing map file": (lambda: mutate(["map"], "nowhere/lake.json"), ["map.path", "does not exist"]),
    "missing section": (lambda: mutate(["fleet"], DELETE), ["fleet", "required"]),
    "position on land": (
        lambda: mutate(["fleet", "initial_positions"], [{"row": 0, "col": 0}, 5, 6]),
        ["initial_positions[0]", "land"],
    ),
    "position off the grid": (
        lambda: mutate(["fleet", "initial_positions"], [{"row": 99, "col": 3}, 5, 6]),
        ["initial_positions[0]", "off the grid"],
    ),
    "node id out of range": (
        lambda: mutate(["fleet", "initial_positions"], [1, 2, 9999]),
        ["initial_positions[2]", "9999", "0..350"],
    ),
    "lat/lon off the map": (
        lambda: mutate(["fleet", "initial_positions"], [{"lat": 40.0, "lon": -3.0}, 5, 6]),
        ["initial_positions[0]", "outside the map"],
    ),
    "wrong number of positions": (
        lambda: mutate(["fleet", "initial_positions"], [1, 2]),
        ["2 positions given for 3 vehicles"],
    ),
    "two on one node": (
        lambda: mutate(["fleet", "initial_positions"], [4, 4, 6]),
        ["same node", "allow_shared_nodes"],
    ),
    "unknown algorithm": (
        lambda: mutate(["algorithm", "type"], "gredy"),
        ["algorithm.type", "unknown algorithm 'gredy'", "Did you mean 'greedy'"],
    ),
    "unknown environment": (
        lambda: mutate(["environment", "type"], "gpp"),
        ["environment.type", "known:", "Did you mean 'gp'"],
    ),
    "unknown level": (
        lambda: mutate(["backend", "level"], "simm"),
        ["backend.level", "unknown backend 'simm'"],
    ),
    "mode not supported": (
        lambda: mutate(["algorithm", "mode"], "target"),
        ["algorithm.mode", "supports sequential"],
    ),
    "bad nested ground truth": (
        lambda: mutate(["environment", "ground_truth"], {"type": "shekel", "peaks": 0}),
        ["environment.ground_truth.peaks", "greater than or equal to 1"],
    ),
    "bad kernel": (
        lambda: mutate(["environment", "kernel"], {"type": "cubic"}),
        ["environment.kernel.type", "'rbf' or 'matern'"],
    ),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_mission_gets_one_clear_sentence(case, write_mission, tmp_path):
    make, fragments = CASES[case]
    path = write_mission(copy.deepcopy(make()))
    out = tmp_path / "run"
    result = CliRunner().invoke(app, ["run", str(path), "--output", str(out)])
    assert result.exit_code == 2, result.output
    message = " ".join(result.output.split())
    assert str(path) in message
    for fragment in fragments:
        assert fragment in message, f"{fragment!r} not in {message!r}"
    assert "Traceback" not in result.output
    assert not out.exists()


def test_malformed_yaml_names_the_line(write_mission):
    path = write_mission("name: x\nfleet: [1, 2\nseed: 3\n")
    result = CliRunner().invoke(app, ["validate", str(path)])
    assert result.exit_code == 2
    assert "malformed YAML at line" in result.output and str(path) in " ".join(result.output.split())


def test_mission_file_that_is_not_a_mapping(write_mission):
    result = CliRunner().invoke(app, ["validate", str(write_mission("- just\n- a list\n"))])
    assert result.exit_code == 2 and "must be a YAML mapping" in result.output


def test_missing_mission_file_from_a_real_process(tmp_path):
    proc = run_cli("run", tmp_path / "absent.yaml")
    assert proc.returncode == 2
    assert "mission file does not exist" in proc.stderr and "Traceback" not in proc.stderr


def test_error_sentences_keep_their_square_brackets(write_mission):
    # "[red]" would be read as a colour tag and vanish from the sentence
    result = CliRunner().invoke(app, ["validate", str(write_mission({**base_mission(), "[red]speed": 1}))])
    assert result.exit_code == 2 and "[red]speed: unknown key" in result.output
