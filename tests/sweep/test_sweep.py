"""`guadal sweep` as users run it: real worker processes, real Dask processes, real kills."""

import json
import os
import signal
import subprocess
import sys
import time

import pytest
import yaml
from support import ROOT, base_mission, run_cli

RUN_FILES = ("metrics.csv", "trajectory.csv", "measurements.csv", "fields.csv")

#: a planner that breaks at run time (validation cannot see it coming): for failure isolation
FLAKY_PLANNER = """
from pydantic import BaseModel, ConfigDict
from guadal_cli.planners.base import SEQUENTIAL, Planner, free_neighbours


class Config(BaseModel):
    model_config = ConfigDict(extra="forbid")
    fail_at_step: int = -1


class Flaky(Planner):
    Config = Config
    modes = (SEQUENTIAL,)

    def next_targets(self, obs):
        if obs.step == self.config.fail_at_step:
            raise RuntimeError("planner broke on purpose")
        targets, claimed = {}, set(obs.positions.values())
        for v in sorted(obs.positions):
            options = free_neighbours(obs, v, claimed - {obs.positions[v]})
            if options:
                targets[v] = min(options)
                claimed.add(targets[v])
        return targets
"""


def write_sweep(folder, **fields):
    base = base_mission(fleet={"vehicles": 2, "initial_positions": "auto", "max_distance": 40.0})
    sweep = {
        "name": "t",
        "base": base,
        "grid": {"algorithm.type": ["greedy", "random"]},
        "seeds": "1..2",
        "output": "out",
        **fields,
    }
    path = folder / "sweep.yaml"
    path.write_text(yaml.safe_dump(sweep))
    return path


def manifest(sweep_dir):
    return json.loads((sweep_dir / "sweep.json").read_text())


def final_metrics(sweep_dir):
    return {e["id"]: e["final_metrics"] for e in manifest(sweep_dir)["combinations"]}


def run_bytes(run_dir):
    return {name: (run_dir / name).read_bytes() for name in RUN_FILES}


def test_local_sweep_runs_every_combination_like_guadal_run_and_skips_them_on_rerun(tmp_path):
    path = write_sweep(tmp_path)
    proc = run_cli("sweep", path, "--workers", "2")
    assert proc.returncode == 0, proc.stderr
    out = tmp_path / "out"
    data = manifest(out)
    assert data["status"] == "complete" and data["axes"] == ["algorithm.type", "seed"]
    entries = data["combinations"]
    assert [e["values"] for e in entries] == [
        {"algorithm.type": a, "seed": s} for s in (1, 2) for a in ("greedy", "random")
    ]
    assert all(e["status"] == "complete" and e["attempts"] == 1 for e in entries)
    for entry in entries:
        run = json.loads((out / entry["run_dir"] / "manifest.json").read_text())
        assert run["status"] == "complete" and run["final_metrics"] == entry["final_metrics"]

    # each mission is byte for byte what `guadal run` writes for the same mission file
    entry = entries[3]
    mission = base_mission(fleet={"vehicles": 2, "initial_positions": "auto", "max_distance": 40.0})
    mission.update(algorithm={"type": "random"}, seed=2)
    (tmp_path / "one.yaml").write_text(yaml.safe_dump(mission))
    single = run_cli("run", tmp_path / "one.yaml", "--output", tmp_path / "single", "--quiet")
    assert single.returncode == 0, single.stderr
    assert run_bytes(tmp_path / "single") == run_bytes(out / entry["run_dir"])

    # the summary groups by the swept axes, seed excluded: two algorithms, two seeds each
    summary = (out / "summary.csv").read_text().splitlines()
    assert summary[0].startswith("algorithm.type,status,runs,")
    assert [line.split(",")[:3] for line in summary[1:]] == [
        ["greedy", "complete", "2"],
        ["random", "complete", "2"],
    ]
    assert (out / "summary.md").read_text().startswith("## 2 groups by algorithm.type")
    assert len(json.loads((out / "summary.json").read_text())["groups"]) == 2

    # `guadal report SWEEP_DIR` groups by the same axes by itself
    report = run_cli("report", out, "--json")
    assert report.returncode == 0, report.stderr
    assert json.loads(report.stdout)["group_by"] == ["algorithm.type"]

    # a re-run finds everything complete and runs nothing again
    stamps = {e["id"]: (out / e["run_dir"] / "metrics.csv").stat().st_mtime_ns for e in entries}
    again = run_cli("sweep", path, "--workers", "2")
    assert again.returncode == 0, again.stderr
    assert "0 to run" in again.stdout and "4 complete (skipped)" in again.stdout
    assert stamps == {e["id"]: (out / e["run_dir"] / "metrics.csv").stat().st_mtime_ns for e in entries}


def test_same_final_metrics_and_files_whatever_the_worker_count(tmp_path):
    path = write_sweep(tmp_path)
    one = run_cli("sweep", path, "--workers", "1", "--output", tmp_path / "w1", "--quiet")
    two = run_cli("sweep", path, "--workers", "2", "--output", tmp_path / "w2", "--quiet")
    assert one.returncode == 0 and two.returncode == 0, one.stderr + two.stderr
    assert final_metrics(tmp_path / "w1") == final_metrics(tmp_path / "w2")
    for entry in manifest(tmp_path / "w1")["combinations"]:
        assert run_bytes(tmp_path / "w1" / entry["run_dir"]) == run_bytes(tmp_path / "w2" / entry["run_dir"])


def test_two_workers_index_every_run_whole_in_one_sqlite_file(tmp_path):
    """Workers of one sweep, and the finished missions' writers inside each worker, share the
    default SQLite file: every run must reach it whole, none left spooled for 'db sync'."""
    import sqlite3

    path = write_sweep(
        tmp_path, seeds="1..8", base=base_mission(fleet={"vehicles": 3, "max_distance": 250.0})
    )
    proc = run_cli("sweep", path, "--workers", "2")
    assert proc.returncode == 0, proc.stderr
    assert "spooling" not in proc.stderr and "did not take every row" not in proc.stderr
    out = tmp_path / "out"
    databases = list(out.rglob("guadal.db"))
    assert len(databases) == 1, databases
    db = sqlite3.connect(databases[0])
    entries = manifest(out)["combinations"]
    assert len(entries) == 16
    for entry in entries:
        run_dir = out / entry["run_dir"]
        assert not list(run_dir.glob("*.spool*")), f"{run_dir.name} left rows spooled"
        uid = json.loads((run_dir / "manifest.json").read_text())["run_id"]
        run_id, status = db.execute("SELECT id, status FROM runs WHERE uid = ?", (uid,)).fetchone()
        assert status == "complete"
        for table, name in (("steps", "metrics.csv"), ("measurements", "measurements.csv")):
            rows = len((run_dir / name).read_text().splitlines()) - 1
            (stored,) = db.execute(f"SELECT count(*) FROM {table} WHERE run_id = ?", (run_id,)).fetchone()
            assert stored == rows, f"{run_dir.name}: {table} has {stored} rows, {name} {rows}"


def test_validate_counts_every_combination_and_names_the_bad_one(tmp_path):
    path = write_sweep(tmp_path, zip={"fleet.max_distance": [30, 40, 50]}, seeds="1..10")
    proc = run_cli("sweep", "validate", path, "--json")
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["missions"] == 2 * 3 * 10

    bad = write_sweep(tmp_path, grid={"algorithm.type": ["greedy", "greedyy"]})
    proc = run_cli("sweep", "validate", bad)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "combination 1 (algorithm.type=greedyy, seed=1)" in proc.stderr and "greedy" in proc.stderr
    assert not (tmp_path / "out").exists()

    uneven = write_sweep(tmp_path, zip={"fleet.max_distance": [30, 40], "fleet.speed": [1.0]})
    proc = run_cli("sweep", "validate", uneven)
    assert proc.returncode == 2 and "zip: its lists must have one length" in proc.stderr


def test_the_shipped_example_sweep_holds_the_papers_comparison(tmp_path):
    proc = run_cli("sweep", "validate", ROOT / "examples" / "lake_algorithms.sweep.yaml", "--json")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["missions"] == 4 * 2 * 10 and summary["levels"] == "sim"
    assert summary["distinct maps"] == 1


def test_a_sweep_of_real_boats_is_refused_in_one_sentence(tmp_path):
    path = write_sweep(tmp_path, grid={"backend.level": ["sim", "real"]})
    proc = run_cli("sweep", path)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "backend.level 'real' cannot be swept" in proc.stderr and "never real boats" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_a_seed_range_of_astronomical_size_is_one_sentence_not_an_out_of_memory(tmp_path):
    path = write_sweep(tmp_path, seeds="0..99999999999")
    proc = run_cli("sweep", "validate", path)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr and "this is a bug" not in proc.stderr
    assert "holds 100,000,000,000 seeds; one sweep takes at most 1,000,000" in proc.stderr


def test_one_failing_mission_does_not_stop_the_others_and_is_retried_up_to_the_limit(tmp_path):
    (tmp_path / "flaky.py").write_text(FLAKY_PLANNER)
    path = write_sweep(
        tmp_path,
        grid={"algorithm.fail_at_step": [-1, 2]},
        base={
            **base_mission(fleet={"vehicles": 2, "initial_positions": "auto", "max_distance": 40.0}),
            "algorithm": {"type": "flaky:Flaky"},
        },
        retries=1,
    )
    env = {"PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")])}
    proc = run_cli("sweep", path, "--workers", "2", env=env)
    assert proc.returncode == 1
    assert "planner broke on purpose" in proc.stderr and "Traceback" not in proc.stderr
    entries = manifest(tmp_path / "out")["combinations"]
    by_step = {(e["values"]["algorithm.fail_at_step"], e["values"]["seed"]): e for e in entries}
    assert [by_step[(-1, s)]["status"] for s in (1, 2)] == ["complete", "complete"]
    assert [by_step[(2, s)]["status"] for s in (1, 2)] == ["failed", "failed"]
    assert "RuntimeError: planner broke on purpose" in by_step[(2, 1)]["error"]
    run = json.loads((tmp_path / "out" / by_step[(2, 1)]["run_dir"] / "manifest.json").read_text())
    assert run["status"] == "failed"

    # a re-run retries the failed ones (retries: 1), keeping the earlier attempt beside it
    again = run_cli("sweep", path, "--workers", "2", env=env)
    assert again.returncode == 1 and "2 to run" in again.stdout
    entries = manifest(tmp_path / "out")["combinations"]
    assert sorted(e["attempts"] for e in entries) == [1, 1, 2, 2]
    assert (tmp_path / "out" / (by_step[(2, 1)]["run_dir"] + ".attempt1") / "manifest.json").is_file()
    # then the limit is reached: nothing left to try
    last = run_cli("sweep", path, "--workers", "2", env=env)
    words = " ".join(last.stdout.split())  # the progress text wraps at the terminal's width
    assert last.returncode == 1 and "0 to run" in words and "2 failed with no attempt left" in words


def _start_sweep(path, *args):
    return subprocess.Popen(
        [sys.executable, "-m", "guadal_cli", "sweep", str(path), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # the sweep and its workers in a group of their own, as in a terminal
    )


def _wait_for_complete(sweep_dir, n, proc, timeout=120):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()
        try:
            done = [e for e in manifest(sweep_dir)["combinations"] if e["status"] == "complete"]
        except (FileNotFoundError, json.JSONDecodeError):
            done = []
        if len(done) >= n:
            return done
        time.sleep(0.05)
    raise AssertionError("the sweep made no progress")


def _long_sweep(tmp_path):
    # 24 missions of ~0.5 s each on a quiet machine: long enough to be caught mid-way
    return write_sweep(
        tmp_path, seeds="1..12", base=base_mission(fleet={"vehicles": 3, "max_distance": 600.0})
    )


def test_resume_after_kill_skips_completed_missions(tmp_path):
    path = _long_sweep(tmp_path)
    proc = _start_sweep(path, "--workers", "1")
    done = _wait_for_complete(tmp_path / "out", 2, proc)
    proc.kill()  # kill -9 of the sweep: no chance to clean up, its worker left behind
    proc.communicate()
    out = tmp_path / "out"
    assert any(e["status"] != "complete" for e in manifest(out)["combinations"])
    # the orphaned worker notices, stops its mission as Ctrl-C would, and leaves no run 'running'
    deadline = time.monotonic() + 60
    while any(
        json.loads(m.read_text())["status"] == "running" for m in (out / "runs").glob("*/manifest.json")
    ):
        assert time.monotonic() < deadline, "a worker of the killed sweep went on running"
        time.sleep(0.2)
    stamps = {e["id"]: (out / e["run_dir"] / "metrics.csv").stat().st_mtime_ns for e in done}

    again = run_cli("sweep", path, "--workers", "2")
    assert again.returncode == 0, again.stderr
    skipped = int(again.stdout.split(" complete (skipped)")[0].rsplit(" ", 1)[-1])
    assert skipped >= len(done) and f"{24 - skipped} to run" in again.stdout
    entries = manifest(out)["combinations"]
    assert all(e["status"] == "complete" for e in entries)
    assert stamps == {i: (out / f"runs/{i}" / "metrics.csv").stat().st_mtime_ns for i in stamps}


def test_ctrl_c_stops_cleanly_and_the_same_command_continues(tmp_path):
    path = _long_sweep(tmp_path)
    proc = _start_sweep(path, "--workers", "2")
    _wait_for_complete(tmp_path / "out", 2, proc)
    os.killpg(proc.pid, signal.SIGINT)  # what a terminal sends on Ctrl-C
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    assert "interrupted" in stderr and "Traceback" not in stderr
    data = manifest(tmp_path / "out")
    assert data["status"] == "interrupted"
    statuses = {e["status"] for e in data["combinations"]}
    assert statuses <= {"complete", "interrupted", "pending"} and "running" not in statuses
    for entry in data["combinations"]:
        run = tmp_path / "out" / entry["run_dir"] / "manifest.json"
        if entry["status"] == "interrupted" and run.is_file():
            assert json.loads(run.read_text())["status"] == "interrupted"
    # however early in its mission the stop reached a worker, no run directory is left 'running'
    for run in (tmp_path / "out" / "runs").glob("*/manifest.json"):
        assert json.loads(run.read_text())["status"] in ("complete", "interrupted"), run.parent.name
    again = run_cli("sweep", path, "--workers", "2", "--quiet")
    assert again.returncode == 0, again.stderr
    assert all(e["status"] == "complete" for e in manifest(tmp_path / "out")["combinations"])


@pytest.fixture
def dask_cluster(tmp_path):
    """A real `dask scheduler` and two `dask worker` processes on loopback, free ports only."""
    pytest.importorskip("distributed")
    dask = [sys.executable, "-m", "distributed.cli.dask_scheduler"]
    scheduler_file = tmp_path / "scheduler.json"
    procs = [
        subprocess.Popen(
            [
                *dask,
                "--host",
                "127.0.0.1",
                "--port",
                "0",
                "--no-dashboard",
                "--scheduler-file",
                scheduler_file,
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
    ]
    try:
        deadline = time.monotonic() + 60
        while not scheduler_file.is_file() and time.monotonic() < deadline:
            time.sleep(0.1)
        address = json.loads(scheduler_file.read_text())["address"]
        for _ in range(2):
            procs.append(
                subprocess.Popen(
                    [
                        sys.executable,
                        "-m",
                        "distributed.cli.dask_worker",
                        address,
                        "--nthreads",
                        "1",
                        "--host",
                        "127.0.0.1",
                        "--no-dashboard",
                        "--local-directory",
                        tmp_path / "dask-worker-space",
                    ],
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL,
                )
            )
        from distributed import Client

        with Client(address, timeout=30) as client:
            client.wait_for_workers(2, timeout=60)
        yield address
    finally:
        for proc in reversed(procs):
            proc.terminate()
        for proc in procs:
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def test_sweep_on_a_dask_cluster_gives_the_local_results(tmp_path, dask_cluster):
    path = write_sweep(tmp_path)
    proc = run_cli("sweep", path, "--scheduler", dask_cluster, "--output", tmp_path / "dask")
    assert proc.returncode == 0, proc.stderr
    entries = manifest(tmp_path / "dask")["combinations"]
    assert all(e["status"] == "complete" for e in entries)
    assert len({e["worker"] for e in entries}) == 2  # both workers took missions
    local = run_cli("sweep", path, "--workers", "1", "--output", tmp_path / "local", "--quiet")
    assert local.returncode == 0, local.stderr
    assert final_metrics(tmp_path / "dask") == final_metrics(tmp_path / "local")
    for entry in entries:
        assert run_bytes(tmp_path / "dask" / entry["run_dir"]) == run_bytes(
            tmp_path / "local" / entry["run_dir"]
        )
