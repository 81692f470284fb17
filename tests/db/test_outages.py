"""The database goes away in the middle of a mission: the mission goes on, and nothing is lost.

The outage is real: an exclusive lock held on the SQLite file by another connection, or a
PostgreSQL database that refuses connections after its open ones were terminated. Each test
waits (without a clock) until the writer has met the outage, keeps it for more steps, lifts it,
and then finds every CSV row in the database exactly once.
"""

from __future__ import annotations

import sqlite3
import time
import uuid
from pathlib import Path

import yaml
from support import ROOT, base_mission
from support.db import assert_same_run_files
from support.fleet import processes_marked

from guadal_cli.db import queries
from guadal_cli.db.engine import make_engine, upgrade
from guadal_cli.db.export import export_run
from guadal_cli.mission import prepare
from guadal_cli.runner import MissionRunner


def wait_for(condition, what: str, limit_s: float = 60.0) -> None:
    """Poll until ``condition()``; the limit only turns a hang into a failure."""
    deadline = time.monotonic() + limit_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"gave up waiting for {what}")
        time.sleep(0.05)


class SqliteLock:
    """Another process's exclusive lock on the database file."""

    def __init__(self, url: str):
        self.path = url.removeprefix("sqlite:///")
        self.conn = None

    def start(self):
        self.conn = sqlite3.connect(self.path, isolation_level=None, timeout=30, check_same_thread=False)
        self.conn.execute("BEGIN EXCLUSIVE")

    def stop(self):
        self.conn.execute("COMMIT")
        self.conn.close()


class PgOutage:
    def __init__(self, db):
        self.db = db

    def start(self):
        self.db.outage()

    def stop(self):
        self.db.restore()


def outage_for(db_url, request):
    if db_url.startswith("sqlite"):
        return SqliteLock(db_url)
    return PgOutage(request.getfixturevalue("pg_database"))


def run_through_outage(mission: dict, tmp_path: Path, db_url: str, outage, begin: int, end: int):
    upgrade(make_engine(db_url))  # the database exists and is healthy when the mission starts
    path = tmp_path / "mission.yaml"
    path.write_text(yaml.safe_dump(mission))
    seen = {}

    def on_step(step, fleet):
        writer = runner.recorder.sinks[0]
        if step == begin:
            outage.start()
        elif step == begin + 1:  # the rows of step `begin` reach the writer: it meets the outage
            wait_for(lambda: writer.last_error_ is not None, "the writer to meet the outage")
        elif step == end:
            seen["spooled"] = writer.spool_path_.exists()
            outage.stop()

    runner = MissionRunner(prepare(path), output=tmp_path / "run", on_step=on_step, database=db_url)
    result = runner.run()
    assert result.status == "complete" and result.steps > end
    writer = runner.recorder.sinks[0]
    writer.close()  # the run returned at once; its last rows go out in the background
    assert seen["spooled"], "rows written during the outage went to the spool"
    assert writer.outages_ >= 1
    assert not writer.spool_path_.exists(), "the spool was delivered and removed"
    engine = queries.open_database(db_url)
    run = queries.get_run(engine, runner.output.name)
    assert run["status"] == "complete"
    assert_same_run_files(export_run(engine, run["id"], tmp_path / "exported"), runner.output)


def test_sim_mission_through_a_database_outage(db_url, tmp_path, request):
    mission = base_mission()
    run_through_outage(mission, tmp_path, db_url, outage_for(db_url, request), begin=3, end=15)


def test_sitl_mission_through_a_database_outage(db_url, tmp_path, request, monkeypatch):
    mission = yaml.safe_load((ROOT / "missions" / "lake_greedy_sitl.yaml").read_text())
    mission["map"] = str(ROOT / "maps" / "urban_lake.json")
    mission["fleet"]["max_distance"] = 45
    mission["backend"].update(speedup=200)
    mark = uuid.uuid4().hex
    monkeypatch.setenv("GUADAL_TEST_MARK", mark)
    run_through_outage(mission, tmp_path, db_url, outage_for(db_url, request), begin=1, end=4)
    with open(tmp_path / "run" / "trajectory.csv") as f:
        assert ",gps," in f.read()  # GPS fixes went through the outage too
    assert processes_marked(f"GUADAL_TEST_MARK={mark}") == []


def test_a_full_queue_spools_instead_of_waiting(tmp_path, monkeypatch):
    """With room for one item, the mission thread itself spools; the rows still all arrive once."""
    from guadal_cli.db import writer as writer_module

    monkeypatch.setattr(writer_module, "QUEUE_SIZE", 1)
    spooled = []
    original = writer_module.DatabaseWriter._spool
    monkeypatch.setattr(
        writer_module.DatabaseWriter,
        "_spool",
        lambda self, items: (spooled.append(len(items)), original(self, items)),
    )
    url = f"sqlite:///{tmp_path / 'q.db'}"
    path = tmp_path / "mission.yaml"
    path.write_text(yaml.safe_dump(base_mission()))
    runner = MissionRunner(prepare(path), output=tmp_path / "run", database=url)
    assert runner.run().status == "complete"
    runner.recorder.sinks[0].close()
    assert spooled, "the one-item queue overflowed into the spool"
    engine = queries.open_database(url)
    run = queries.get_run(engine, "run")
    assert_same_run_files(export_run(engine, run["id"], tmp_path / "exported"), runner.output)


def test_a_lock_held_past_the_missions_end_still_delivers_every_row(tmp_path):
    """Another process (a sweep's other worker, an import) holds the SQLite file for seconds
    while a mission ends: the writer keeps trying a while, so no 'db sync' is needed."""
    import threading

    url = f"sqlite:///{tmp_path / 'busy.db'}"
    upgrade(make_engine(url))
    lock = SqliteLock(url)
    path = tmp_path / "mission.yaml"
    path.write_text(yaml.safe_dump(base_mission()))

    def on_step(step, fleet):
        if step == 2:
            lock.start()

    runner = MissionRunner(prepare(path), output=tmp_path / "run", on_step=on_step, database=url)
    assert runner.run().status == "complete"
    threading.Timer(5.0, lock.stop).start()  # longer than one busy wait and one retry
    writer = runner.recorder.sinks[0]
    writer.close()
    assert not writer.spool_path_.exists(), "rows were left for 'db sync'"
    engine = queries.open_database(url)
    run = queries.get_run(engine, "run")
    assert run["status"] == "complete"
    assert_same_run_files(export_run(engine, run["id"], tmp_path / "exported"), runner.output)
