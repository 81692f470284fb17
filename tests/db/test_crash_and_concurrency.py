"""Real processes: two missions writing one database at once, a mission killed with SIGKILL and then
``guadal db sync``, and a PostgreSQL password that must never reach a file or a log."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
import sqlalchemy
import yaml
from support import base_mission, run_cli
from support.db import RUN_FILES, assert_same_run_files

from guadal_cli.db import queries
from guadal_cli.db.export import export_run
from guadal_cli.db.models import Measurement
from guadal_cli.errors import GuadalError

# slow_planner:SlowGreedy, a greedy that waits: a sim mission long enough to be killed part-way
WITH_SLOW_PLANNER = {
    "PYTHONPATH": os.pathsep.join(
        [str(Path(__file__).resolve().parents[1] / "web"), os.environ.get("PYTHONPATH", "")]
    )
}


def start_run(mission: dict, folder: Path, name: str, db_url: str) -> tuple[subprocess.Popen, Path]:
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump(mission))
    out = folder / name
    proc = subprocess.Popen(
        [sys.executable, "-m", "guadal_cli", "run", str(path), "-o", str(out), "--db", db_url, "--quiet"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, **WITH_SLOW_PLANNER},
    )
    return proc, out


def test_two_missions_write_one_database_at_once(db_url, tmp_path):
    procs = [start_run(base_mission(seed=seed), tmp_path, f"m{seed}", db_url) for seed in (1, 2)]
    for proc, _ in procs:
        _, err = proc.communicate(timeout=600)
        assert proc.returncode == 0, err
    engine = queries.open_database(db_url)
    assert sorted(r["status"] for r in queries.list_runs(engine)) == ["complete", "complete"]
    for _, out in procs:
        run = queries.get_run(engine, out.name)
        assert_same_run_files(export_run(engine, run["id"], tmp_path / f"export-{out.name}"), out)


def _steps_in_database(db_url: str) -> int:
    try:
        engine = queries.open_database(db_url)
        runs = queries.list_runs(engine)
    except GuadalError:
        return 0  # the writer has not created the schema yet
    return len(queries.steps(engine, runs[0]["id"])) if runs else 0


def _killed_after_five_steps(folder: Path, name: str, db_url: str) -> Path:
    """A slow sim mission, ``kill -9``-ed once the database has five of its steps; its run directory."""
    proc, out = start_run(
        base_mission(algorithm={"type": "slow_planner:SlowGreedy", "delay_s": 0.2}), folder, name, db_url
    )
    deadline = time.monotonic() + 300
    while _steps_in_database(db_url) < 5:
        assert proc.poll() is None, "the mission ended before it could be killed"
        assert time.monotonic() < deadline, "the mission wrote no steps to the database"
        time.sleep(0.1)
    proc.kill()
    proc.wait()
    return out


def test_a_killed_mission_is_made_whole_by_db_sync(db_url, tmp_path):
    out = _killed_after_five_steps(tmp_path, "killed", db_url)
    engine = queries.open_database(db_url)
    run = queries.get_run(engine, "killed")
    assert run["status"] == "running"  # what the manifest says: the process never finished it

    synced = run_cli("db", "sync", out, "--db", db_url, "--json")
    assert synced.returncode == 0, synced.stderr
    exported = export_run(engine, run["id"], tmp_path / "exported")
    for name in RUN_FILES[:-1]:  # fields.csv is written at the end, which a killed run never reached
        data = (out / name).read_bytes()
        assert (exported / name).read_bytes() == data[: data.rfind(b"\n") + 1], name
    again = json.loads(run_cli("db", "sync", out, "--db", db_url, "--json").stdout)
    assert again[0]["new rows"] == 0


def test_a_postgresql_password_stays_out_of_files_and_logs(pg_database, tmp_path):
    secret = "Sekr3t-Pw-4711"
    with_password = pg_database.url.replace("postgresql://postgres@", f"postgresql://postgres:{secret}@")
    mission = base_mission(output={"database": with_password})  # trust auth: the server ignores it
    path = tmp_path / "mission.yaml"
    path.write_text(yaml.safe_dump(mission))
    done = run_cli("run", path, "-o", tmp_path / "run", "--json")
    assert done.returncode == 0, done.stderr
    # a database that is not there: the writer complains, and must not print the password
    gone = with_password.rsplit("/", 1)[0] + "/no_such_database_here"
    failed = run_cli("run", path, "-o", tmp_path / "run2", "--db", gone, "--json")
    assert failed.returncode == 0, failed.stderr  # the mission does not depend on its database
    assert "no_such_database_here" in failed.stderr  # it did say which database is missing
    for text in (done.stdout, done.stderr, failed.stdout, failed.stderr):
        assert secret not in text
    for file in [*(tmp_path / "run").iterdir(), *(tmp_path / "run2").iterdir()]:
        assert secret not in file.read_text(), file.name
    resolved = yaml.safe_load((tmp_path / "run" / "mission.resolved.yaml").read_text())
    assert resolved["output"]["database"].startswith("postgresql://postgres:***@")
    engine = queries.open_database(pg_database.url)
    run = queries.get_run(engine, "run")
    assert secret not in json.dumps(run["manifest"]) + json.dumps(run["mission"])
    assert_same_run_files(export_run(engine, run["id"], tmp_path / "exported"), tmp_path / "run")


@pytest.mark.parametrize("during_resume", ["live", "offline, then db sync"])
def test_a_resumed_mission_leaves_the_database_equal_to_its_files(db_url, tmp_path, during_resume):
    """kill -9, then what the killed process delivered past the last complete step differs from
    what the resumed one writes (at sitl the boats are elsewhere: here the database row is
    altered to stand for that), then 'guadal resume' writing live to the database, or with the
    database off and 'guadal db sync' after: either way the database equals the files."""
    out = _killed_after_five_steps(tmp_path, "resumed", db_url)
    engine = queries.open_database(db_url)
    run = queries.get_run(engine, "resumed")
    # the last step the database has samples of: its metrics row (and what follows) never reached
    # the file, as when the kill came between the two, so the resume cuts that step away
    cut_step = max(m["step"] for m in queries.measurements(engine, run["id"]))
    header, *lines = (out / "metrics.csv").read_bytes().splitlines(keepends=True)
    whole = [line for line in lines if line.endswith(b"\n") and int(line.split(b",")[0]) < cut_step]
    (out / "metrics.csv").write_bytes(header + b"".join(whole))
    with engine.begin() as conn:
        conn.execute(
            sqlalchemy.update(Measurement)
            .where(Measurement.run_id == run["id"], Measurement.step == cut_step)
            .values(value=999.0)
        )
    assert any(m["value"] == 999.0 for m in queries.measurements(engine, run["id"]))
    kept = {(m["seq"], m["id"]) for m in queries.measurements(engine, run["id"]) if m["step"] < cut_step}

    live = during_resume == "live"
    resumed = run_cli("resume", out, "--db", db_url if live else "none", "--json", env=WITH_SLOW_PLANNER)
    assert resumed.returncode == 0, resumed.stderr
    assert json.loads((out / "manifest.json").read_text())["status"] == "complete"
    if not live:
        assert queries.get_run(engine, run["id"])["status"] == "running"
        synced = run_cli("db", "sync", out, "--db", db_url, "--json")
        assert synced.returncode == 0, synced.stderr
    assert queries.get_run(engine, run["id"])["status"] == "complete"  # delivered as the process exited
    assert_same_run_files(export_run(engine, run["id"], tmp_path / "exported"), out)
    # rows before the cut were left alone: a console following the run gets only what is new
    assert kept <= {(m["seq"], m["id"]) for m in queries.measurements(engine, run["id"])}
    assert not (out / "database.spool.jsonl").exists()
    again = json.loads(run_cli("db", "sync", out, "--db", db_url, "--json").stdout)
    assert again[0]["new rows"] == 0
