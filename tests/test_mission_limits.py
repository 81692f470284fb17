"""Mission files a careless or hostile user writes: refused at ``validate`` in one sentence.

Each case once escaped as a traceback, a hang or a run without end; ``validate`` must refuse it,
since a mission that validates must not fail at ``run`` for anything its file contains.
"""

import pytest
import yaml
from support import ROOT, base_mission
from typer.testing import CliRunner

from guadal_cli.app import app


def refused(path, *fragments, command="validate"):
    result = CliRunner().invoke(app, [command, str(path)])
    message = " ".join(result.output.split())
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    for fragment in fragments:
        assert fragment in message, f"{fragment!r} not in {message!r}"
    return message


def with_fields(**sections) -> dict:
    mission = base_mission()
    for dotted, value in sections.items():
        node = mission
        *parents, last = dotted.split("__")
        for key in parents:
            node = node.setdefault(key, {})
        node[last] = value
    return mission


def test_thousands_of_nesting_levels_are_refused_before_python_runs_out_of_stack(write_mission):
    path = write_mission("name: deep\nmap: " + "[" * 5000 + "]" * 5000 + "\n")
    refused(path, str(path), "nested more than 32 levels deep at line 2")
    path = write_mission("name: deep\nmap:\n" + "".join("  " * i + f"k{i}:\n" for i in range(200)) + "x: 1\n")
    refused(path, "nested more than 32 levels")


def test_anchors_that_expand_to_millions_of_values_are_refused(write_mission):
    lines = ["a0: &a0 [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]"]
    lines += [f"a{i}: &a{i} [*a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}]" for i in range(1, 12)]
    mission = yaml.safe_dump(base_mission()) + "\n".join(lines) + "\n"
    refused(write_mission(mission), "more than 100,000 values once its anchors")


def test_a_mission_file_of_megabytes_is_refused_unread(write_mission):
    path = write_mission(yaml.safe_dump(base_mission()) + "# " + "x" * 1_100_000 + "\n")
    refused(path, "a mission file is at most 1,000,000 bytes")


def test_a_map_path_too_long_for_any_filesystem(write_mission):
    refused(write_mission(base_mission(map="m" * 5000 + ".json")), "map.path", "too long for a file name")


@pytest.mark.parametrize(
    "directory, fragment",
    [
        ("/dev/null/x", "is a file, so no run directory can be made under it"),
        ("/proc/x", "cannot create run directories under '/proc/x'"),
        ("runs\x00x", "holds a NUL character"),
        ("/", "is the filesystem root"),
        ("d" * 300, "too long for a file name"),
    ],
    ids=["under-a-file", "proc", "nul", "root", "long"],
)
def test_an_output_directory_run_could_not_create_fails_validate(directory, fragment, write_mission):
    path = write_mission(with_fields(output__directory=directory))
    refused(path, "output.directory", fragment)


def test_a_valid_output_directory_is_checked_without_leaving_a_trace(write_mission, tmp_path):
    path = write_mission(with_fields(output__directory="runs/deeper"))
    result = CliRunner().invoke(app, ["validate", str(path)])
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mission.yaml"]


@pytest.mark.parametrize(
    "field, value, fragment",
    [
        ("fleet__max_distance", ".inf", "fleet.max_distance: must be a finite number"),
        ("fleet__max_distance", "1e308", "fleet.max_distance: must be less than or equal to 1000000"),
        ("fleet__speed", ".inf", "fleet.speed: must be a finite number"),
        ("fleet__speed", "1e-300", "fleet.speed: must be greater than or equal to 0.001"),
        ("fleet__speed", "0.001", None),  # a slow drift is still a speed
        ("environment__kernel__variance", ".nan", "environment.kernel.variance: must be a finite number"),
        ("environment__noise_std", ".inf", "environment.noise_std: must be a finite number"),
        ("output__coverage_radius", "-.inf", "output.coverage_radius: must be a finite number"),
        ("seed", "18446744073709551616", "seed: must be less than 9223372036854775808"),
    ],
)
def test_non_finite_and_unphysical_numbers_are_refused_with_their_field(
    field, value, fragment, write_mission
):
    text = yaml.safe_dump(with_fields(**{field: "PLACEHOLDER"})).replace("PLACEHOLDER", value)
    path = write_mission(text)
    if fragment is None:
        assert CliRunner().invoke(app, ["validate", str(path)]).exit_code == 0
    else:
        refused(path, fragment)


def test_a_name_too_long_for_a_run_directory_is_refused(write_mission):
    refused(write_mission(base_mission(name="n" * 300)), "name: string should have at most 100 characters")


def test_a_drift_faster_than_any_water_is_refused_not_integrated_forever(write_mission):
    """Found by the fuzz suite: a wind of 2**63 m/s made the trash world's sub-steps endless."""
    mission = yaml.safe_load((ROOT / "missions" / "trash_detection_greedy.yaml").read_text())
    mission["map"] = str(ROOT / "maps" / "urban_lake.json")
    mission["environment"]["drift"] = {"wind": [2**63, 0.0]}
    refused(write_mission(mission), "environment.drift.wind[0]", "less than or equal to 100")


@pytest.mark.parametrize("field", ["map", "name"])
def test_a_value_with_a_newline_stays_inside_one_sentence(field, write_mission):
    """Found by the fuzz suite: a newline in a value split the sentence that quoted it."""
    from guadal_cli.errors import GuadalError
    from guadal_cli.mission import prepare

    with pytest.raises(GuadalError) as caught:
        prepare(write_mission(base_mission(**{field: "lake\n\x1b[2J.json"})))
    assert "\n" not in str(caught.value) and "\x1b" not in str(caught.value)
    assert "lake\\n\\x1b[2J.json" in str(caught.value)
