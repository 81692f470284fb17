"""A mission writes the database as it runs; the CSVs stay exactly as they were."""

from __future__ import annotations

from pathlib import Path

import yaml
from support import base_mission
from support.db import assert_same_run_files

from guadal_cli.db import queries
from guadal_cli.db.export import export_run
from guadal_cli.mission import prepare
from guadal_cli.runner import MissionRunner


def run_mission(tmp_path: Path, name: str, database: str | None, on_step=None, **overrides):
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(base_mission(**overrides)))
    runner = MissionRunner(prepare(path), output=tmp_path / name, on_step=on_step, database=database)
    result = runner.run()
    assert result.status == "complete"
    for sink in runner.recorder.sinks:
        sink.close()  # the run returned at once; its last rows go out in the background
    return runner


def test_run_in_database_is_its_csvs_and_csvs_do_not_change(db_url, tmp_path):
    with_db = run_mission(tmp_path, "with-db", db_url)
    without = run_mission(tmp_path, "without-db", "none")
    assert_same_run_files(with_db.output, without.output)
    assert not (without.output.parent / "guadal.db").exists() or db_url.startswith("sqlite")

    engine = queries.open_database(db_url)
    run = queries.get_run(engine, with_db.output.name)
    assert run["status"] == "complete"
    assert run["algorithm"] == "greedy" and run["map"] == "urban_lake"
    assert len(queries.vehicles(engine, run["id"])) == 3
    exported = export_run(engine, run["id"], tmp_path / "exported")
    assert_same_run_files(exported, with_db.output)  # every row there, none twice, same text
