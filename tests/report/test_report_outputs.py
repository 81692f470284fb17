"""Files a report writes: figures, animation, geo exports, ground-station plans, the HTML page."""

from __future__ import annotations

import base64
import csv
import io
import json
import re
import shutil
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from PIL import Image
from support.report import invoke

from guadal_cli.report.animate import scene
from guadal_cli.report.build import Options, build
from guadal_cli.report.geo import route
from guadal_cli.report.plots import distance_to_polyline, group_curve
from guadal_cli.report.runs import find_runs

METRICS = ("coverage", "rmse", "mean_std", "max_std")


@pytest.fixture(scope="module")
def report_dir(runs_root, gps_run, tmp_path_factory):
    out = tmp_path_factory.mktemp("report")
    result = invoke("report", runs_root, gps_run, "--output", out, "--frames", "10")
    assert result.exit_code == 0, result.stderr
    return out


def plan_rows(run_dir, vehicle):
    with open(run_dir / "trajectory.csv", newline="") as fh:
        return [r for r in csv.DictReader(fh) if r["source"] == "plan" and int(r["vehicle"]) == vehicle]


def sane_png(path):
    with Image.open(path) as im:
        assert im.format == "PNG"
        w, h = im.size
    assert 300 <= w <= 4000 and 200 <= h <= 3000, (path.name, w, h)


def test_figures_exist_as_png_and_svg_with_sane_sizes(report_dir):
    figs = report_dir / "figures"
    names = [f"metric_{m}_vs_distance" for m in METRICS]
    names += [f"map_{r}" for r in ("greedy-1", "greedy-2", "lawnmower-1", "lawnmower-2", "gps-1")]
    names += ["track_gps-1"]
    for name in names:
        sane_png(figs / f"{name}.png")
        assert ET.parse(figs / f"{name}.svg").getroot().tag.endswith("svg")
    # sim runs have no GPS, so no track figure
    assert not (figs / "track_greedy-1.png").exists()


def test_every_run_is_animated_with_bounded_changing_frames(report_dir):
    gifs = sorted((report_dir / "animations").glob("*.gif"))
    names = ["gps-1", "greedy-1", "greedy-2", "lawnmower-1", "lawnmower-2"]
    assert [g.name for g in gifs] == [f"animation_{n}.gif" for n in names]
    with Image.open(report_dir / "animations" / "animation_greedy-1.gif") as im:
        assert 2 <= im.n_frames <= 10
        assert im.size[0] >= 1200 and im.size[1] >= 350  # three panels people can read
        first = np.asarray(im.convert("RGB"))
        im.seek(im.n_frames - 1)
        last = np.asarray(im.convert("RGB"))
    assert (first != last).any()  # the vehicles moved and the model changed


def test_each_animated_field_has_a_colour_bar_on_its_scale(runs_root):
    (run,) = find_runs([runs_root / "greedy-1"])
    built, warning = scene(run)
    assert warning is None and built.panels == ["ground_truth", "mean", "std"]
    bars = [image.colorbar for image in built.images]
    assert all(bar is not None for bar in bars)
    truth = run.fields["ground_truth"]
    assert bars[0].vmin <= truth.min() and bars[0].vmax >= truth.max()
    assert bars[2].vmin == 0.0  # the std bar starts at no uncertainty


def test_animate_runs_first_or_by_name(runs_root, tmp_path):
    out = tmp_path / "first"
    result = invoke(
        "report", runs_root, "-o", out, "--frames", "3", "--animate-runs", "first", "--metrics", "rmse"
    )
    assert result.exit_code == 0, result.stderr
    assert sorted(p.name for p in (out / "animations").iterdir()) == [
        "animation_greedy-1.gif",
        "animation_lawnmower-1.gif",
    ]
    out = tmp_path / "chosen"
    result = invoke(
        "report", runs_root, "-o", out, "--frames", "3", "--animate-runs", "lawnmower-2", "--metrics", "rmse"
    )
    assert result.exit_code == 0, result.stderr
    assert [p.name for p in (out / "animations").iterdir()] == ["animation_lawnmower-2.gif"]
    result = invoke("report", runs_root, "-o", tmp_path / "bad", "--animate-runs", "nosuch")
    assert result.exit_code == 2 and "--animate-runs must be" in result.stderr and "greedy-1" in result.stderr


def test_group_mean_curve_stops_where_the_shortest_run_ends(runs_root, tmp_path):
    folder = tmp_path / "runs"
    shutil.copytree(runs_root / "greedy-1", folder / "long")
    shutil.copytree(runs_root / "greedy-2", folder / "short")
    metrics = folder / "short" / "metrics.csv"
    lines = metrics.read_text().splitlines(keepends=True)
    metrics.write_text("".join(lines[: len(lines) // 2]))  # as if it had stopped halfway
    report = build(find_runs([folder]), Options())
    (group,) = report.groups
    grid, mean, std, n = group_curve(group, "total_distance", "rmse")
    short_end = float(lines[len(lines) // 2 - 1].split(",")[lines[0].split(",").index("total_distance")])
    assert n == 2 and grid[-1] == pytest.approx(short_end)
    assert not np.isnan(mean).any() and not np.isnan(std).any()


def test_html_links_the_tables_and_exports(report_dir):
    page = (report_dir / "report.html").read_text()
    links = re.findall(r'href="([^"]*)"', page)
    for expected in (
        "tables/runs.csv",
        "tables/report.json",
        "geo/gps-1.geojson",
        "geo/greedy-1.kml",
        "geo/greedy-1_v0.plan",
    ):
        assert expected in links
    assert all((report_dir / link).is_file() for link in links)


def test_html_is_one_self_contained_page(report_dir):
    page = (report_dir / "report.html").read_text()
    sources = re.findall(r'src="([^"]*)"', page)
    assert sources and all(s.startswith("data:") for s in sources)
    assert "<table>" in page and "greedy-1" in page and "lawnmower" in page
    png = next(s for s in sources if s.startswith("data:image/png;base64,"))
    with Image.open(io.BytesIO(base64.b64decode(png.split(",", 1)[1]))) as im:
        assert im.size[0] >= 300
    assert any(s.startswith("data:image/gif;base64,") for s in sources)


def test_tables_written_to_the_report_folder(report_dir, runs_root):
    with open(report_dir / "tables" / "runs.csv", newline="") as fh:
        rows = {r["run"]: r for r in csv.DictReader(fh)}
    with open(runs_root / "greedy-1" / "metrics.csv", newline="") as fh:
        last = list(csv.DictReader(fh))[-1]
    assert float(rows["greedy-1"]["rmse"]) == float(last["rmse"])
    data = json.loads((report_dir / "tables" / "report.json").read_text())
    assert sorted((g["level"], g["algorithm.type"], g["runs"]) for g in data["groups"]) == [
        ("sim", "greedy", 2),
        ("sim", "lawnmower", 2),
        ("support.report:GpsTrackBackend", "greedy", 1),
    ]


def test_geojson_is_a_feature_collection_in_lon_lat_order(report_dir, runs_root):
    data = json.loads((report_dir / "geo" / "greedy-1.geojson").read_text())
    assert data["type"] == "FeatureCollection"
    tracks = [f for f in data["features"] if f["properties"]["kind"] == "track"]
    samples = [f for f in data["features"] if f["properties"]["kind"] == "sample"]
    line = next(f for f in tracks if f["properties"]["vehicle"] == 0 and f["properties"]["source"] == "plan")
    assert line["geometry"]["type"] == "LineString"
    rows = plan_rows(runs_root / "greedy-1", 0)
    assert line["geometry"]["coordinates"] == [[float(r["lon"]), float(r["lat"])] for r in rows]
    with open(runs_root / "greedy-1" / "measurements.csv", newline="") as fh:
        measured = list(csv.DictReader(fh))
    assert len(samples) == len(measured)
    assert samples[5]["geometry"]["coordinates"] == [float(measured[5]["lon"]), float(measured[5]["lat"])]
    assert samples[5]["properties"]["value"] == float(measured[5]["value"])


def test_kml_holds_paths_and_samples(report_dir, runs_root):
    ns = {"k": "http://www.opengis.net/kml/2.2"}
    root = ET.parse(report_dir / "geo" / "greedy-1.kml").getroot()
    lines = root.findall(".//k:LineString/k:coordinates", ns)
    assert len(lines) == 2  # two vehicles, planned paths only at sim level
    first = [tuple(map(float, c.split(","))) for c in lines[0].text.split()]
    rows = plan_rows(runs_root / "greedy-1", 0)
    got = [v for lo, la, _ in first for v in (lo, la)]
    assert got == pytest.approx([v for r in rows for v in (float(r["lon"]), float(r["lat"]))], abs=1e-8)
    with open(runs_root / "greedy-1" / "measurements.csv", newline="") as fh:
        assert len(root.findall(".//k:Point", ns)) == len(list(csv.DictReader(fh)))


def test_qgc_plan_has_the_structure_qgroundcontrol_reads(report_dir, runs_root):
    plan = json.loads((report_dir / "geo" / "greedy-1_v1.plan").read_text())
    assert plan["fileType"] == "Plan" and plan["version"] == 1 and plan["groundStation"] == "QGroundControl"
    assert plan["geoFence"] == {"version": 2, "circles": [], "polygons": []}
    assert plan["rallyPoints"] == {"version": 2, "points": []}
    mission = plan["mission"]
    assert mission["version"] == 2 and mission["firmwareType"] == 3 and mission["vehicleType"] == 11
    assert mission["cruiseSpeed"] == 0.5 and len(mission["plannedHomePosition"]) == 3
    items = mission["items"]
    assert [i["doJumpId"] for i in items] == list(range(1, len(items) + 1))
    for item in items:
        assert item["type"] == "SimpleItem" and item["command"] == 16 and item["frame"] == 3
        assert item["autoContinue"] is True and len(item["params"]) == 7
        assert {"AMSLAltAboveTerrain", "Altitude", "AltitudeMode"} <= set(item)
    rows = plan_rows(runs_root / "greedy-1", 1)
    start, end = rows[0], rows[-1]
    assert items[0]["params"][4:6] == [float(start["lat"]), float(start["lon"])]
    assert mission["plannedHomePosition"][:2] == [float(start["lat"]), float(start["lon"])]
    assert items[-1]["params"][4:6] == [float(end["lat"]), float(end["lon"])]


def test_route_keeps_turns_and_every_node_lies_on_it(runs_root):
    (run,) = find_runs([runs_root / "lawnmower-1"])
    rows = run.track("plan")[0]
    points = route(rows)
    assert 2 <= len(points) < len(rows["lat"])  # straight legs were merged
    line = np.array(points)
    visited = np.column_stack([rows["lat"], rows["lon"]])
    assert distance_to_polyline(visited, line).max() < 1e-9
    assert points[0] == (rows["lat"][0], rows["lon"][0]) and points[-1] == (rows["lat"][-1], rows["lon"][-1])


def test_mission_planner_waypoints_file(report_dir):
    text = (report_dir / "geo" / "greedy-1_v1.waypoints").read_text().splitlines()
    plan = json.loads((report_dir / "geo" / "greedy-1_v1.plan").read_text())["mission"]["items"]
    assert text[0] == "QGC WPL 110"
    rows = [line.split("\t") for line in text[1:]]
    assert all(len(r) == 12 for r in rows)
    assert rows[0][:4] == ["0", "1", "0", "16"]  # home, absolute frame
    assert [int(r[0]) for r in rows] == list(range(len(rows)))
    assert len(rows) == len(plan) + 1
    for row, item in zip(rows[1:], plan):
        assert row[1:4] == ["0", "3", "16"] and row[11] == "1"
        assert float(row[8]) == pytest.approx(item["params"][4], abs=1e-8)
        assert float(row[9]) == pytest.approx(item["params"][5], abs=1e-8)


def test_gps_runs_get_offtrack_columns(report_dir):
    with open(report_dir / "tables" / "runs.csv", newline="") as fh:
        rows = {r["run"]: r for r in csv.DictReader(fh)}
    # the test fleet reports fixes on its path (hop midpoints and nodes)
    assert float(rows["gps-1"]["gps_offtrack_max_m"]) < 0.01
    assert rows["greedy-1"]["gps_offtrack_max_m"] == ""


def test_distance_to_polyline_known_geometry():
    line = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]])
    points = np.array([[5.0, 3.0], [12.0, 5.0], [-4.0, 3.0], [10.0, 0.0]])
    assert distance_to_polyline(points, line) == pytest.approx([3.0, 2.0, 5.0, 0.0])


def test_time_axis_and_chosen_metrics(runs_root, tmp_path):
    result = invoke(
        "report",
        runs_root / "greedy-1",
        "-o",
        tmp_path,
        "--x",
        "time",
        "--metrics",
        "rmse",
        "--animate",
        "none",
    )
    assert result.exit_code == 0, result.stderr
    assert sorted(p.name for p in (tmp_path / "figures").glob("metric_*.png")) == ["metric_rmse_vs_time.png"]
    assert not (tmp_path / "animations").exists()
    bad = invoke("report", runs_root / "greedy-1", "-o", tmp_path, "--metrics", "rmse,nope")
    assert bad.exit_code == 2 and "no run recorded 'nope'" in bad.stderr


def test_mp4_needs_ffmpeg(runs_root, tmp_path):
    result = invoke("report", runs_root / "greedy-1", "-o", tmp_path, "--animate", "mp4", "--frames", "4")
    if shutil.which("ffmpeg") is None:
        assert result.exit_code == 2 and "needs an ffmpeg program" in result.stderr
        assert not (tmp_path / "report.html").exists()
    else:
        assert result.exit_code == 0, result.stderr
        assert (tmp_path / "animations" / "animation_greedy-1.mp4").stat().st_size > 1000


def test_replayed_model_ends_where_the_run_ended(runs_root):
    """The animation's model, rebuilt from measurements.csv, matches the run's final fields."""
    from guadal_cli.report.animate import Replay

    (run,) = find_runs([runs_root / "greedy-1"])
    replay = Replay(run)
    for step in (0, 3, run.steps):  # batches differ from the run's; the posterior must not
        fields = replay.fields_at(step)
    np.testing.assert_allclose(fields["mean"], run.fields["mean"], atol=1e-6)
    np.testing.assert_allclose(fields["std"], run.fields["std"], atol=1e-6)
    np.testing.assert_allclose(
        replay.env.ground_truth, run.fields["ground_truth"], rtol=1e-9
    )  # CSV keeps 10 digits
