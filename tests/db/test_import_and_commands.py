"""``guadal db`` on runs of the shipped example missions, against both engines, as a user types it."""

from __future__ import annotations

import csv
import io
import json

import pytest
import yaml
from support import ROOT, run_cli
from support.db import assert_same_run_files

from guadal_cli.db import queries
from guadal_cli.db.export import export_run
from guadal_cli.mission import prepare
from guadal_cli.runner import MissionRunner

#: shipped sim missions of each environment, cut short (the budget) to keep the test quick
EXAMPLES = ["lake_greedy", "lake_lawnmower", "oil_spill_frontier", "trash_detection_greedy"]


@pytest.fixture(scope="module")
def example_runs(tmp_path_factory):
    """The example missions run with the database off: plain run directories, as older guadal made."""
    folder = tmp_path_factory.mktemp("examples")
    for name in EXAMPLES:
        mission = yaml.safe_load((ROOT / "missions" / f"{name}.yaml").read_text())
        mission["map"] = str(ROOT / "maps" / mission["map"].split("/")[-1])
        mission["fleet"]["max_distance"] = 60
        path = folder / f"{name}.yaml"
        path.write_text(yaml.safe_dump(mission))
        MissionRunner(prepare(path), output=folder / "runs" / name, database="none").run()
    return folder / "runs"


def test_import_is_complete_idempotent_and_queryable(example_runs, db_url, tmp_path):
    first = run_cli("db", "import", example_runs, "--db", db_url, "--json")
    assert first.returncode == 0, first.stderr
    imported = json.loads(first.stdout)
    assert len(imported) == len(EXAMPLES)
    assert all(r["new rows"] == r["rows"] > 0 for r in imported)
    again = json.loads(run_cli("db", "import", example_runs, "--db", db_url, "--json").stdout)
    assert [r["new rows"] for r in again] == [0] * len(EXAMPLES)  # nothing written twice

    runs = json.loads(run_cli("db", "runs", "--db", db_url, "--json").stdout)
    assert sorted(r["name"] for r in runs) == sorted(EXAMPLES)
    lawnmower = json.loads(run_cli("db", "runs", "--db", db_url, "--algorithm", "lawnmower", "--json").stdout)
    assert [r["name"] for r in lawnmower] == ["lake_lawnmower"]
    on_lake = json.loads(run_cli("db", "runs", "--db", db_url, "--map", "urban_lake", "--json").stdout)
    assert sorted(r["name"] for r in on_lake) == sorted(EXAMPLES)  # every example sails the urban lake
    assert json.loads(run_cli("db", "runs", "--db", db_url, "--map", "reservoir", "--json").stdout) == []
    assert json.loads(run_cli("db", "runs", "--db", db_url, "--since", "2999-01-01", "--json").stdout) == []

    done = run_cli("db", "export", "lake_greedy", "--db", db_url, "--output", tmp_path / "export")
    assert done.returncode == 0, done.stderr
    assert_same_run_files(tmp_path / "export", example_runs / "lake_greedy")
    engine = queries.open_database(db_url)
    for name in EXAMPLES[1:]:  # the others in process: the same code, without a process each
        assert_same_run_files(export_run(engine, name, tmp_path / f"export-{name}"), example_runs / name)

    check_samples(example_runs, db_url)
    from_db = run_cli("report", "--db", db_url, "--where", "algorithm=lawnmower", "--csv")
    assert from_db.returncode == 0, from_db.stderr
    from_dirs = run_cli("report", example_runs / "lake_lawnmower", "--csv")
    assert from_db.stdout == from_dirs.stdout


def check_samples(example_runs, db_url):
    """Samples by map, then in a box (GeoJSON), then in a time window that holds none."""
    all_rows = list(
        csv.DictReader(io.StringIO(run_cli("db", "samples", "--map", "urban_lake", "--db", db_url).stdout))
    )
    expected = sum(len(list(csv.DictReader(open(example_runs / n / "measurements.csv")))) for n in EXAMPLES)
    assert len(all_rows) == expected
    lats = sorted(float(r["lat"]) for r in all_rows)
    lons = sorted(float(r["lon"]) for r in all_rows)
    middle_lat = lats[len(lats) // 2]
    box = f"{lons[0]},{lats[0]},{lons[-1]},{middle_lat}"
    south = run_cli(
        "db", "samples", "--map", "urban_lake", "--db", db_url, "--bbox", box, "--format", "geojson"
    )
    features = json.loads(south.stdout)["features"]
    assert len(features) == sum(1 for lat in lats if lat <= middle_lat)
    assert all(f["geometry"]["coordinates"][1] <= middle_lat for f in features)
    engine = queries.open_database(db_url)
    assert queries.samples(engine, "urban_lake", until="2000-01-01") == []  # nothing taken before 2000


def test_bad_requests_get_one_sentence(tmp_path, example_runs):
    url = f"sqlite:///{tmp_path / 'x.db'}"
    cases = [
        (("db", "runs", "--db", url), "not a guadal database yet"),
        (("db", "runs", "--db", "mysql://h/db"), "not supported"),
        (("db", "import", tmp_path, "--db", url), "no run directories"),
        (("report", "--db", url, "--where", "colour=red"), "must be KEY=VALUE"),
        (("db", "samples", "--map", "x", "--db", url, "--bbox", "1,2,3"), "must be four numbers"),
    ]
    for args, sentence in cases:
        result = run_cli(*args)
        assert result.returncode == 2, (args, result.stderr)
        assert sentence in result.stderr and "Traceback" not in result.stderr
