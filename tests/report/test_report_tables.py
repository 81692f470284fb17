"""Report tables against the CSVs the runs wrote, grouping, and the odd cases users meet."""

from __future__ import annotations

import csv
import json
import shutil
import statistics

import pytest
from support import ROOT, run_cli
from support.report import invoke, run_mission

from guadal_cli.errors import GuadalError
from guadal_cli.report.build import Options, build
from guadal_cli.report.runs import find_runs


def last_metrics_row(run_dir) -> dict[str, float]:
    with open(run_dir / "metrics.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    return {k: float(v) for k, v in rows[-1].items()}


def test_run_rows_are_the_last_rows_of_metrics_csv(runs_root):
    report = build(find_runs([runs_root]), Options())
    assert len(report.run_rows) == 4
    for row in report.run_rows:
        values = dict(zip(report.run_columns, row))
        expected = last_metrics_row(runs_root / values["run"])
        for column in ("total_distance", "time_s", "samples", "coverage", "rmse", "mean_std", "max_std"):
            assert values[column] == expected[column], column
        assert values["steps"] == expected["step"]
        assert values["status"] == "complete"


def test_two_seeds_of_two_algorithms_group_into_two_groups_of_two(runs_root):
    report = build(find_runs([runs_root]), Options())
    assert report.group_by == ["map", "level", "algorithm.type"]
    groups = {row[2]: dict(zip(report.group_columns, row)) for row in report.group_rows}
    assert set(groups) == {"greedy", "lawnmower"}
    assert {(g["map"], g["level"]) for g in groups.values()} == {("urban_lake", "sim")}
    for algorithm, group in groups.items():
        finals = [last_metrics_row(runs_root / f"{algorithm}-{seed}") for seed in (1, 2)]
        assert group["runs"] == 2
        assert group["status"] == "complete"
        for metric in ("rmse", "total_distance", "coverage"):
            values = [f[metric] for f in finals]
            assert group[f"{metric}_mean"] == pytest.approx(statistics.mean(values), rel=1e-12)
            assert group[f"{metric}_std"] == pytest.approx(statistics.stdev(values), rel=1e-12, abs=1e-15)


def test_group_by_several_mission_fields(runs_root):
    report = build(find_runs([runs_root]), Options(group_by=["algorithm.type", "seed"]))
    keys = sorted(tuple(row[:2]) for row in report.group_rows)
    assert keys == [("greedy", "1"), ("greedy", "2"), ("lawnmower", "1"), ("lawnmower", "2")]
    assert all(row[report.group_columns.index("runs")] == 1 for row in report.group_rows)


def test_unknown_group_field_is_one_clear_error(runs_root):
    with pytest.raises(GuadalError, match="group_by: field 'algorithm.typo' is in none"):
        build(find_runs([runs_root]), Options(group_by=["algorithm.typo"]))
    result = invoke("report", runs_root, "--group-by", "algorithm.typo")
    assert result.exit_code == 2 and "--group-by field 'algorithm.typo' is in none" in result.stderr
    result = invoke("report", runs_root, "--group-by", " ,")
    assert result.exit_code == 2 and "--group-by needs at least one mission field" in result.stderr


def test_cli_json_csv_and_markdown_agree_with_the_csvs(runs_root):
    out = invoke("report", runs_root, "--json")
    assert out.exit_code == 0, out.stderr
    data = json.loads(out.stdout)
    by_run = {r["run"]: r for r in data["runs"]}
    assert by_run["greedy-2"]["rmse"] == last_metrics_row(runs_root / "greedy-2")["rmse"]
    assert {g["algorithm.type"]: g["runs"] for g in data["groups"]} == {"greedy": 2, "lawnmower": 2}

    out = invoke("report", runs_root, "--csv")
    assert out.exit_code == 0, out.stderr
    runs_part, groups_part = out.stdout.split("\n\n")
    rows = {r["run"]: r for r in csv.DictReader(runs_part.splitlines())}
    assert (
        float(rows["lawnmower-1"]["total_distance"])
        == last_metrics_row(runs_root / "lawnmower-1")["total_distance"]
    )
    assert [r["algorithm.type"] for r in csv.DictReader(groups_part.splitlines())] == ["greedy", "lawnmower"]

    out = invoke("report", runs_root, "--markdown")
    assert out.exit_code == 0, out.stderr
    assert "| run | status |" in out.stdout and "| urban_lake | sim | greedy | complete | 2 |" in out.stdout
    assert "by map, level, algorithm.type" in out.stdout


def test_no_runs_found_exits_2_with_one_sentence(tmp_path):
    (tmp_path / "empty").mkdir()
    out = run_cli("report", tmp_path / "empty")
    assert out.returncode == 2
    assert "no run directories found" in out.stderr and "Traceback" not in out.stderr
    out = invoke("report", tmp_path / "missing")
    assert out.exit_code == 2 and "does not exist" in out.stderr


def test_unreadable_manifest_exits_2(runs_root, tmp_path):
    broken = tmp_path / "broken"
    shutil.copytree(runs_root / "greedy-1", broken)
    (broken / "manifest.json").write_text("{not json")
    out = invoke("report", broken)
    assert out.exit_code == 2
    assert "unreadable manifest.json" in out.stderr and "Traceback" not in out.stderr


def test_interrupted_and_killed_runs_are_labelled_and_left_out_of_means(runs_root, tmp_path):
    folder = tmp_path / "runs"
    for name in ("greedy-1", "greedy-2"):
        shutil.copytree(runs_root / name, folder / name)
    shutil.copytree(runs_root / "greedy-1", folder / "greedy-killed")
    manifest = json.loads((folder / "greedy-2" / "manifest.json").read_text())
    manifest["status"] = "interrupted"
    (folder / "greedy-2" / "manifest.json").write_text(json.dumps(manifest))
    manifest["status"] = "running"
    (folder / "greedy-killed" / "manifest.json").write_text(json.dumps(manifest))

    report = build(find_runs([folder]), Options())
    status = {row[0]: row[1] for row in report.run_rows}
    assert status == {"greedy-1": "complete", "greedy-2": "interrupted", "greedy-killed": "unfinished"}
    (group,) = report.group_rows
    values = dict(zip(report.group_columns, group))
    assert values["runs"] == 1  # only the complete run enters the mean
    assert values["rmse_mean"] == last_metrics_row(folder / "greedy-1")["rmse"]
    assert (
        "1 interrupted" in values["status"]
        and "1 unfinished" in values["status"]
        and "left out" in values["status"]
    )
    assert any("did not complete" in w for w in report.warnings)

    out = invoke("report", folder, "--markdown")
    assert out.exit_code == 0, out.stderr
    assert "| greedy-2 | interrupted |" in out.stdout and "| greedy-killed | unfinished |" in out.stdout


def test_runs_on_different_maps_are_not_averaged_unless_asked(runs_root, tmp_path):
    other = run_mission(tmp_path, "greedy", 1, map=str(ROOT / "maps" / "reservoir.json"))
    runs = find_runs([runs_root / "greedy-1", runs_root / "greedy-2", other])
    report = build(runs, Options())
    assert sorted((row[0], row[4]) for row in report.group_rows) == [("reservoir", 1), ("urban_lake", 2)]
    assert not report.warnings
    out = invoke("report", runs_root / "greedy-1", runs_root / "greedy-2", other)
    assert out.exit_code == 0 and out.stderr == ""
    assert "by map, level, algorithm.type" in out.stdout

    asked = build(runs, Options(group_by=["algorithm.type"]))
    ((algorithm, _, n, *_),) = asked.group_rows
    assert (algorithm, n) == ("greedy", 3)
    assert any("different maps, as --group-by asked" in w and "reservoir" in w for w in asked.warnings)


def test_sim_and_sitl_runs_of_one_algorithm_are_grouped_apart(runs_root, tmp_path):
    sitl = tmp_path / "greedy-sitl"
    shutil.copytree(runs_root / "greedy-2", sitl)
    manifest = json.loads((sitl / "manifest.json").read_text())
    manifest["level"] = "sitl"
    (sitl / "manifest.json").write_text(json.dumps(manifest))
    report = build(find_runs([runs_root / "greedy-1", sitl]), Options())
    assert [(row[1], row[2], row[4]) for row in report.group_rows] == [
        ("sim", "greedy", 1),
        ("sitl", "greedy", 1),
    ]
    assert (
        len(build(find_runs([runs_root / "greedy-1", sitl]), Options(group_by=["algorithm.type"])).groups)
        == 1
    )


def test_a_killed_run_is_reported_as_unfinished_with_what_it_wrote(tmp_path):
    """SIGKILL a real ``guadal run`` mid-mission: no fields.csv, manifest still 'running'."""
    import os
    import signal
    import subprocess
    import sys
    import time

    import yaml
    from support import base_mission

    mission = base_mission(name="killed", seed=4)
    mission["fleet"] = {**mission["fleet"], "max_distance": 925.0}
    path = tmp_path / "killed.yaml"
    path.write_text(yaml.safe_dump(mission))
    run_dir = tmp_path / "runs" / "killed"
    proc = subprocess.Popen([sys.executable, "-m", "guadal_cli", "run", str(path), "-q", "-o", str(run_dir)])
    metrics = run_dir / "metrics.csv"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and proc.poll() is None:
        if metrics.exists() and metrics.read_text().count("\n") >= 4:
            break
        time.sleep(0.005)  # polling for the condition, not waiting a fixed time
    assert proc.poll() is None, "the mission ended before it could be killed"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    assert not (run_dir / "fields.csv").exists()

    report = build(find_runs([run_dir]), Options())
    (row,) = report.run_rows
    values = dict(zip(report.run_columns, row))
    assert values["status"] == "unfinished"
    with open(metrics, newline="") as fh:
        rows = [r for r in csv.DictReader(fh)]
    assert values["steps"] == int(rows[-1]["step"]) and values["rmse"] == float(rows[-1]["rmse"])

    out_dir = tmp_path / "report"
    result = invoke("report", run_dir, "-o", out_dir, "--frames", "4", "--metrics", "rmse")
    assert result.exit_code == 0, result.stderr
    assert "did not complete" in result.stderr
    assert (out_dir / "animations" / "animation_killed.gif").exists()  # model replayed from the samples
    assert not (out_dir / "figures" / "map_killed.png").exists()  # no final fields were written
    geo = json.loads((out_dir / "geo" / "killed.geojson").read_text())
    assert geo["features"] and geo["features"][0]["properties"]["status"] == "unfinished"


def test_runs_of_different_environments_are_grouped_apart(runs_root, tmp_path):
    import yaml

    other = tmp_path / "other-env"
    shutil.copytree(runs_root / "greedy-2", other)
    mission = yaml.safe_load((other / "mission.resolved.yaml").read_text())
    mission["environment"]["type"] = "another_env"
    (other / "mission.resolved.yaml").write_text(yaml.safe_dump(mission))

    report = build(find_runs([runs_root / "greedy-1", other]), Options())
    assert report.group_by == ["environment.type", "map", "level", "algorithm.type"]
    assert sorted((r[0], r[3]) for r in report.group_rows) == [("another_env", "greedy"), ("gp", "greedy")]
    assert any("2 environments" in w for w in report.warnings)
    titles = [t for t, _, _ in report.display_tables()]
    assert (
        sum("in environment gp" in t for t in titles) == 2
        and sum("in environment another_env" in t for t in titles) == 2
    )
