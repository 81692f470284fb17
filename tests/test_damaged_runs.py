"""A damaged run directory is refused in one sentence by every command that reads one.

A hand-edited manifest, or a CSV replaced by a folder, used to be met as a wrong type deep inside
``db sync``, ``report`` or ``resume`` (a crash log and "this is a bug"). The manifest is checked
once, where it is read (``records.ManifestContract``); resume checks the files it goes on from.
"""

from __future__ import annotations

import json
import shutil

import pytest
import yaml
from support import base_mission, run_cli

from guadal_cli.db.engine import make_engine
from guadal_cli.db.ingest import import_run
from guadal_cli.errors import GuadalError
from guadal_cli.mission import prepare
from guadal_cli.report.runs import find_runs
from guadal_cli.resume import prepare_resume
from guadal_cli.runner import MissionRunner

#: (key, value) written over a manifest's own: each a wrong type or a wrong value for that key
DAMAGE = [
    ("vehicles", "x"),
    ("vehicles", -2),
    ("steps", "x"),
    ("map", 5),
    ("map", None),
    ("map", {"sha256": 7}),
    ("plugins", "x"),
    ("plugins", {"algorithm": 3}),
    ("metric_columns", 5),
    ("resumes", 5),
    ("resumes", ["x"]),
    ("resumes", [{"after_step": "3"}]),
    ("fleet", "x"),
    ("final_metrics", 3),
    ("mission_dir", 5),
    ("seed", True),
]


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    root = tmp_path_factory.mktemp("finished")
    mission = root / "mission.yaml"
    mission.write_text(yaml.safe_dump(base_mission(fleet={"vehicles": 2, "max_distance": 40.0})))
    MissionRunner(prepare(mission), output=root / "run").run()
    return root / "run"


def damaged_copy(finished, where, key, value):
    """The finished run as an interrupted one (so resume would go on), with one key damaged."""
    shutil.copytree(finished, where)
    manifest = json.loads((where / "manifest.json").read_text())
    manifest.update({"status": "interrupted", key: value})
    (where / "manifest.json").write_text(json.dumps(manifest))
    return where


@pytest.mark.parametrize("key, value", DAMAGE, ids=[f"{k}={json.dumps(v)}" for k, v in DAMAGE])
def test_a_damaged_manifest_is_one_sentence_to_db_sync_report_and_resume(finished, tmp_path, key, value):
    run = damaged_copy(finished, tmp_path / "run", key, value)
    engine = make_engine(f"sqlite:///{tmp_path / 'g.db'}")
    for read in (lambda: import_run(engine, run), lambda: find_runs([run]), lambda: prepare_resume(run)):
        with pytest.raises(GuadalError) as refused:
            read()
        sentence = str(refused.value)
        assert f"manifest.{key}" in sentence and "is damaged" in sentence and "\n" not in sentence


def test_the_commands_say_it_without_a_crash_log(finished, tmp_path):
    run = damaged_copy(finished, tmp_path / "run", "vehicles", "x")
    for args in (
        ("db", "sync", run, "--db", f"sqlite:///{tmp_path / 'g.db'}"),
        ("report", run),
        ("resume", run),
    ):
        out = run_cli(*args)
        assert out.returncode == 2, (args, out.stderr)
        assert "manifest.vehicles" in out.stderr and "Traceback" not in out.stderr
        assert "this is a bug" not in out.stderr


@pytest.mark.parametrize("name", ["trajectory.csv", "metrics.csv", "vehicles.csv", "run.lock"])
def test_resume_refuses_a_run_whose_file_became_a_folder(finished, tmp_path, name):
    run = damaged_copy(finished, tmp_path / "run", "status", "interrupted")
    (run / name).unlink(missing_ok=True)
    (run / name).mkdir()
    with pytest.raises(GuadalError, match=f"'{name}' is not a file; it cannot be resumed"):
        prepare_resume(run)


def test_resume_refuses_a_run_that_lost_its_trajectory(finished, tmp_path):
    run = damaged_copy(finished, tmp_path / "run", "status", "interrupted")
    (run / "trajectory.csv").unlink()
    with pytest.raises(GuadalError, match="has no trajectory.csv, which every run writes first"):
        prepare_resume(run)
