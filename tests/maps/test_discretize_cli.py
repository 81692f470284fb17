"""``guadal discretize`` and ``guadal map show`` as a user types them: real processes, real files."""

import json

import numpy as np
import pytest
import yaml
from PIL import Image
from support import ROOT, run_cli
from support.maps import bounds_text, disc, draw_grid, draw_image, write_latlon_grid

EXAMPLE = ROOT / "examples" / "lake_satellite.png"
EXAMPLE_BOUNDS = "37.4200,37.4164,-5.9780,-5.9830"


def test_readme_path_from_satellite_picture_to_a_mission_run(tmp_path):
    out = tmp_path / "example_satellite.json"
    # the README's command, with --json for this test to read
    made = run_cli(
        "discretize",
        EXAMPLE,
        "--bounds",
        EXAMPLE_BOUNDS,
        "--cell-size",
        "10",
        "--largest-body",
        "--output",
        out,
        "--json",
    )
    assert made.returncode == 0, made.stderr
    summary = json.loads(made.stdout)
    assert summary["bodies"] == 1 and summary["water_nodes"] > 300
    assert (
        abs(summary["area_m2"] - summary["source_water_m2"]) < 0.05 * summary["source_water_m2"] + 1000
    )  # pond dropped
    preview = Image.open(tmp_path / "example_satellite.png")
    assert preview.size[0] > 400 and preview.size[1] > 400

    # the shipped map is exactly what the README command makes
    assert json.loads(out.read_text()) == json.loads((ROOT / "maps" / "example_satellite.json").read_text())

    info = run_cli("map", "info", out, "--json")
    assert info.returncode == 0 and json.loads(info.stdout)["water_nodes"] == summary["water_nodes"]

    mission = yaml.safe_load((ROOT / "examples" / "lake_satellite.yaml").read_text())
    mission["map"] = str(out)
    mission["fleet"]["max_distance"] = 80
    mission_path = tmp_path / "mission.yaml"
    mission_path.write_text(yaml.safe_dump(mission))
    run = run_cli("run", mission_path, "--output", tmp_path / "run", "--quiet")
    assert run.returncode == 0, run.stderr
    assert len((tmp_path / "run" / "trajectory.csv").read_text().splitlines()) > 3


def test_shipped_example_mission_validates():
    result = run_cli("validate", ROOT / "examples" / "lake_satellite.yaml", "--json")
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["water_nodes"] > 300


def test_csv_with_centre_grid_defaults_to_its_own_cell_size(tmp_path):
    clat, clon, *_ = draw_grid(
        tmp_path / "lake.csv", disc(30.0), dx=4.0, dy=4.0, half_w=40, half_h=40, water_value=0
    )
    write_latlon_grid(tmp_path / "grid.txt", clat, clon)
    result = run_cli(
        "discretize",
        tmp_path / "lake.csv",
        "--latlon-grid",
        tmp_path / "grid.txt",
        "--water-value",
        "0",
        "--output",
        tmp_path / "lake.json",
        "--no-preview",
        "--json",
    )
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary["cell_size_m"] == pytest.approx(4.0, rel=1e-4)
    assert summary["area_m2"] == pytest.approx(summary["source_water_m2"], rel=0.05)
    assert not (tmp_path / "lake.png").exists()


def bad_inputs(tmp_path):
    """(arguments, words the error must contain) for each kind of bad input in the issue."""
    lake = tmp_path / "lake.png"
    bounds = bounds_text(draw_image(lake, disc(30.0), half=50.0, pixel=1.0))
    (tmp_path / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n not really")
    black = tmp_path / "black.png"
    Image.new("L", (50, 50)).save(black)
    mask, grid = tmp_path / "mask.csv", tmp_path / "grid.txt"
    clat, clon, *_ = draw_grid(mask, disc(20.0), dx=5.0, dy=5.0, half_w=30, half_h=30)
    write_latlon_grid(grid, clat[:, :-1], clon[:, :-1])
    shifted = tmp_path / "shifted"
    shifted.mkdir()
    draw_image(shifted / "lake.png", disc(30.0), half=50.0, pixel=1.0)
    (shifted / "lake.pgw").write_text("0.0000113\n0\n0\n-0.000009\n-5.9811\n37.4185\n")
    return {
        "unreadable file": (
            [tmp_path / "broken.png", "--bounds", bounds, "--cell-size", "5"],
            "cannot read image 'broken.png'",
        ),
        "missing file": ([tmp_path / "nope.png", "--bounds", bounds, "--cell-size", "5"], "no such file"),
        "no water": ([black, "--bounds", bounds, "--cell-size", "5"], "no water found in 'black.png'"),
        "contradicting bounds": (
            [lake, "--bounds", "37.41,37.42,-5.97,-5.98", "--cell-size", "5"],
            "bounds contradict each other",
        ),
        "cell larger than lake": ([lake, "--bounds", bounds, "--cell-size", "80"], "larger than the lake"),
        "grid shape": (
            [mask, "--latlon-grid", grid, "--cell-size", "5"],
            "is 12x11 but the mask 'mask.csv' is 12x12",
        ),
        "world file vs bounds": ([shifted / "lake.png", "--bounds", bounds, "--cell-size", "5"], "disagree"),
    }


@pytest.mark.parametrize(
    "case",
    [
        "unreadable file",
        "missing file",
        "no water",
        "contradicting bounds",
        "cell larger than lake",
        "grid shape",
        "world file vs bounds",
    ],
)
def test_bad_input_one_sentence_exit_2_nothing_written(tmp_path, case):
    args, words = bad_inputs(tmp_path)[case]
    out = tmp_path / "out" / "map.json"
    out.parent.mkdir()
    result = run_cli("discretize", *args, "--output", out)
    assert result.returncode == 2
    assert words in result.stderr.replace("\n", " ")
    assert "Traceback" not in result.stderr and result.stderr.count("error:") == 1
    assert list(out.parent.iterdir()) == []


def test_existing_map_survives_a_failed_discretize(tmp_path):
    out = tmp_path / "map.json"
    out.write_text("previous map\n")
    result = run_cli("discretize", tmp_path / "nope.png", "--cell-size", "5", "--output", out)
    assert result.returncode == 2 and out.read_text() == "previous map\n"


def test_map_show_writes_a_preview_of_any_map(tmp_path):
    out = tmp_path / "lake.png"
    result = run_cli("map", "show", ROOT / "maps" / "urban_lake.json", "--output", out)
    assert result.returncode == 0, result.stderr
    image = Image.open(out)
    assert image.format == "PNG" and min(image.size) > 300
    # water cells are drawn in the water colour: plenty of blue pixels
    rgb = np.asarray(image.convert("RGB")).astype(int)
    assert ((rgb[..., 2] > 150) & (rgb[..., 0] < 100)).sum() > 5000
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    failed = run_cli("map", "show", bad, "--output", tmp_path / "bad.png")
    assert failed.returncode == 2 and "not a guadal map" in failed.stderr
    assert not (tmp_path / "bad.png").exists()
