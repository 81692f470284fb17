"""`guadal resume`: an interrupted mission continues where it stopped, as if never stopped.

A run killed at step k leaves exactly this on disk: the CSVs up to step k (perhaps a torn line of
step k+1), a manifest saying "running", no fields.csv. ``killed_copy`` builds that state from an
uninterrupted run, so the property can be tried at any step; the real signals are tried too.
"""

from __future__ import annotations

import json
import shutil
import signal
import sys

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from support import ROOT, base_mission, run_cli, stop_after_steps
from support.fuzz import examples

from guadal_cli.errors import GuadalError
from guadal_cli.mission import prepare
from guadal_cli.resume import prepare_resume
from guadal_cli.runner import MissionRunner

CSVS = ("metrics.csv", "trajectory.csv", "measurements.csv", "vehicles.csv", "targets.csv", "fields.csv")

PLANNERS = {
    "greedy": {"type": "greedy"},
    "expected_improvement": {"type": "expected_improvement"},
    "lawnmower": {"type": "lawnmower"},
}


def run_in_process(mission_path, out):
    return MissionRunner(prepare(mission_path), output=out).run()


def resume_in_process(run_dir):
    """``guadal resume`` in this process, returning once its database writer is done too (a
    process waits for it as it exits; here the next example reuses the directory at once)."""
    runner = MissionRunner(prepare_resume(run_dir), output=run_dir, resume=True)
    try:
        return runner.run()
    finally:
        recorder = getattr(runner, "recorder", None)  # None: refused before the run began
        for sink in recorder.sinks if recorder is not None else []:
            sink.close()


def killed_copy(full, out, step: int, torn: bytes = b"") -> None:
    """What a `kill -9` after step ``step`` leaves: CSVs cut there, a torn line, status running."""
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    shutil.copy(full / "mission.resolved.yaml", out)
    manifest = json.loads((full / "manifest.json").read_text())
    manifest.update(status="running", ended_at=None, steps=0, final_metrics=None, stop_reason="")
    (out / "manifest.json").write_text(json.dumps(manifest))
    for name in CSVS[:-1]:
        lines = (full / name).read_bytes().splitlines(keepends=True)
        # the decision after step k (labelled k+1, its first hop) may be on disk already
        last = step + 1 if name == "targets.csv" else step
        kept = [lines[0]] + [line for line in lines[1:] if int(line.split(b",")[0]) <= last]
        (out / name).write_bytes(b"".join(kept) + (torn if name == "trajectory.csv" else b""))


def same_csvs(a, b) -> None:
    for name in CSVS:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name


@pytest.fixture(scope="module")
def full_runs(tmp_path_factory):
    """One uninterrupted run per planner: the reference every resumed run must equal."""
    root = tmp_path_factory.mktemp("full")
    runs = {}
    for name, algorithm in PLANNERS.items():
        mission = root / f"{name}.yaml"
        data = base_mission(
            algorithm=algorithm,
            environment={"type": "gp", "noise_std": 0.05, "kernel": {"type": "rbf", "length_scale": 20.0}},
            fleet={"vehicles": 2, "max_distance": 90.0},
        )
        mission.write_text(yaml.safe_dump(data))
        result = run_in_process(mission, root / name)
        runs[name] = (root / name, result.steps)
    return runs


@pytest.mark.parametrize("planner", list(PLANNERS))
def test_a_run_killed_at_any_step_resumes_byte_identical(planner, full_runs, tmp_path_factory):
    full, steps = full_runs[planner]
    out = tmp_path_factory.mktemp("killed") / "run"

    @settings(
        max_examples=examples(15),
        deadline=None,
        database=None,
        suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
    )
    @given(
        step=st.integers(min_value=-1, max_value=steps),
        torn=st.sampled_from([b"", b"1", b"12,0,3", b"\xff\xfe", b"5,1,2,3,4,5,6,7,plan,9"]),
    )
    def killed_then_resumed(step, torn):
        killed_copy(full, out, step, torn)
        result = resume_in_process(out)
        assert result.status == "complete" and result.steps == steps
        same_csvs(full, out)
        manifest = json.loads((out / "manifest.json").read_text())
        assert manifest["status"] == "complete" and manifest["steps"] == steps
        assert [r["after_step"] for r in manifest["resumes"]] == [step]

    killed_then_resumed()


@pytest.mark.parametrize(
    "how", [signal.SIGKILL, signal.SIGTERM, signal.SIGINT], ids=["kill-9", "term", "int"]
)
def test_a_real_process_stopped_mid_run_resumes_to_the_uninterrupted_result(how, tmp_path, write_mission):
    mission = write_mission(
        base_mission(
            algorithm={"type": "expected_improvement"},
            environment={"type": "gp", "noise_std": 0.02},
            fleet={"vehicles": 3, "max_distance": 250.0},
        )
    )
    run_in_process(mission, tmp_path / "full")
    out = tmp_path / "stopped"
    stop_after_steps(mission, out, 10, how, timeout=120)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["status"] == ("running" if how == signal.SIGKILL else "interrupted")
    assert not (out / "fields.csv").exists() or how != signal.SIGKILL
    done = run_cli("resume", out, "--json")
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["status"] == "complete"
    same_csvs(tmp_path / "full", out)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["status"] == "complete" and len(manifest["resumes"]) == 1
    assert manifest["resumes"][0]["previous_status"] == (
        "running" if how == signal.SIGKILL else "interrupted"
    )


def test_a_terminate_signal_while_the_run_directory_is_made_is_recorded(tmp_path, write_mission, monkeypatch):
    """The signal lands in the moment after the directory's manifest says "running" and before
    the mission loop: the run must still end "interrupted", not stay "running" for good."""
    import os

    from guadal_cli import runner

    class SignalledRecorder(runner.RunRecorder):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            os.kill(os.getpid(), signal.SIGTERM)

    monkeypatch.setattr(runner, "RunRecorder", SignalledRecorder)
    previous = signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)
    with pytest.raises(KeyboardInterrupt):
        run_in_process(write_mission(base_mission()), tmp_path / "r")
    manifest = json.loads((tmp_path / "r" / "manifest.json").read_text())
    assert manifest["status"] == "interrupted" and manifest["ended_at"]
    assert "terminate" in manifest["error"]
    # the process's own handlers are back
    assert (signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)) == previous


CRASHING_PLANNER = """
import os
from guadal_cli.planners.greedy import GreedyStd

class Crashy(GreedyStd):
    '''Greedy, but crashes at its 8th decision while CRASH is set: a bug fixed between runs.'''

    def next_targets(self, observation):
        if os.environ.get("CRASH") and observation.step == 8:
            raise RuntimeError("planner bug")
        return super().next_targets(observation)
"""


def test_a_run_whose_planner_crashed_resumes_once_the_bug_is_fixed(tmp_path, write_mission):
    (tmp_path / "crashy.py").write_text(CRASHING_PLANNER)
    env = {"PYTHONPATH": str(tmp_path)}
    mission = write_mission(base_mission(algorithm={"type": "crashy:Crashy"}))
    sys.path.insert(0, str(tmp_path))
    try:
        run_in_process(mission, tmp_path / "full")
    finally:
        sys.path.remove(str(tmp_path))
    crashed = run_cli("run", mission, "-o", tmp_path / "r", "-q", env={**env, "CRASH": "1"})
    assert crashed.returncode != 0
    assert json.loads((tmp_path / "r" / "manifest.json").read_text())["status"] == "failed"
    done = run_cli("resume", tmp_path / "r", "-q", env=env)
    assert done.returncode == 0, done.stderr
    same_csvs(tmp_path / "full", tmp_path / "r")
    resumes = json.loads((tmp_path / "r" / "manifest.json").read_text())["resumes"]
    assert resumes[0]["previous_status"] == "failed" and "planner bug" in resumes[0]["previous_error"]


def test_resuming_twice_records_both_resumes(full_runs, tmp_path):
    full, steps = full_runs["greedy"]
    out = tmp_path / "run"
    killed_copy(full, out, 3)
    # interrupted again during the first resume, after step 7
    prep = prepare_resume(out)

    def stop_at_7(step, fleet):
        if step == 7:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        MissionRunner(prep, output=out, on_step=stop_at_7, resume=True).run()
    assert json.loads((out / "manifest.json").read_text())["status"] == "interrupted"
    resume_in_process(out)
    same_csvs(full, out)
    resumes = json.loads((out / "manifest.json").read_text())["resumes"]
    assert [(r["after_step"], r["previous_status"]) for r in resumes] == [(3, "running"), (7, "interrupted")]


def test_a_run_that_does_not_match_its_record_is_refused(full_runs, tmp_path):
    full, _ = full_runs["greedy"]
    out = tmp_path / "run"
    killed_copy(full, out, 5)
    lines = (out / "measurements.csv").read_text().splitlines(keepends=True)
    cells = lines[4].split(",")
    cells[5] = "0.123456789"  # a measurement the world of this seed never gave
    lines[4] = ",".join(cells)
    (out / "measurements.csv").write_text("".join(lines))
    with pytest.raises(GuadalError, match="replays differently from the record"):
        resume_in_process(out)


def test_resume_refuses_complete_running_and_foreign_directories(full_runs, tmp_path):
    full, _ = full_runs["greedy"]
    proc = run_cli("resume", full)
    assert proc.returncode == 2 and "is complete; there is nothing to resume" in proc.stderr
    assert "Traceback" not in proc.stderr
    with pytest.raises(GuadalError, match="holds no manifest.json"):
        prepare_resume(tmp_path)
    # a run still being written (its writer holds the lock) is left alone
    out = tmp_path / "run"
    killed_copy(full, out, 2)
    import fcntl

    with open(out / "run.lock", "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        with pytest.raises(GuadalError, match="being written by another guadal process"):
            resume_in_process(out)
    assert resume_in_process(out).status == "complete"
    same_csvs(full, out)


def test_resume_example_mission_at_sim(tmp_path):
    """The shipped trash mission (an evolving world: items drift with time) resumes exactly."""
    mission = ROOT / "missions" / "trash_lawnmower.yaml"
    run_in_process(mission, tmp_path / "full")
    killed_copy(tmp_path / "full", tmp_path / "run", 40)
    resume_in_process(tmp_path / "run")
    same_csvs(tmp_path / "full", tmp_path / "run")
