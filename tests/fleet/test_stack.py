"""``guadal stack up/down/status`` as a user runs them: real processes, nothing left behind."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import uuid
from pathlib import Path

import yaml
from support import LAKE, ROOT, run_cli
from support.fleet import Inbox, connect_refused, processes_marked, wait_for
from typer.testing import CliRunner

from guadal_cli.app import app
from guadal_cli.channel import protocol as msg


def cli(*args):
    """The CLI in this process (quick); up and down themselves run as separate processes below."""
    return CliRunner().invoke(app, [str(a) for a in args])


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def test_stack_up_then_down_leaves_no_process(tmp_path):
    state = tmp_path / "stack"
    up = run_cli(
        "stack", "up", "--map", LAKE, "--vehicles", "2", "--speedup", "20", "--state-dir", state, "--json"
    )
    assert up.returncode == 0, up.stderr
    info = json.loads(up.stdout)
    pids = info["pids"]
    try:
        assert len(pids) == 4 and all(alive(p) for p in pids)  # broker, emulator, two bridges
        assert (state / "stack.json").is_file()
        # up returned only once every bridge was online: the retained statuses are there already
        secrets = state / "secrets"  # generated for this stack: owner-only
        assert (secrets.stat().st_mode & 0o777) == 0o700 and (state.stat().st_mode & 0o777) == 0o700
        files = [p for p in secrets.rglob("*") if p.is_file()]
        assert files and all((p.stat().st_mode & 0o777) == 0o600 for p in files)
        assert connect_refused(info["broker"]["port"]) != ""  # no anonymous client
        password = Path(info["planner"]["password_file"]).read_text().strip()
        assert password not in up.stdout + up.stderr
        inbox = Inbox(
            info["broker"]["port"],
            login=("watcher", (secrets / "users" / "watcher.password").read_text().strip()),
        )
        inbox.subscribe("guadal/vehicle/+/status")
        inbox.wait(
            lambda: len({m.topic for m in inbox.messages}) == 2, 5, "the retained statuses are missing"
        )
        assert {msg.decode(m.payload)["state"] for m in inbox.messages} <= {"online"}
        inbox.close()

        again = cli("stack", "up", "--map", LAKE, "--vehicles", "2", "--state-dir", state)
        assert (
            again.exit_code == 2 and "already up" in again.output and again.exception.__class__ is SystemExit
        )

        status = cli("stack", "status", "--state-dir", state, "--json")
        assert [row["state"] for row in json.loads(status.stdout)] == ["alive"] * 4
    finally:
        down = run_cli("stack", "down", "--state-dir", state)
    assert down.returncode == 0, down.stderr
    assert not any(alive(p) for p in pids)
    assert not (state / "stack.json").exists()
    assert not (state / "secrets").exists()
    twice = cli("stack", "down", "--state-dir", state)
    assert twice.exit_code == 0 and "nothing to stop" in twice.output


def test_stack_up_with_a_missing_map_is_one_sentence(tmp_path):
    result = cli("stack", "up", "--map", tmp_path / "nope.json", "--state-dir", tmp_path)
    assert result.exit_code == 2 and result.exception.__class__ is SystemExit
    assert "nope.json' does not exist" in result.output
    assert not (tmp_path / "stack.json").exists()


def test_a_killed_run_takes_its_launched_stack_down(tmp_path):
    """kill -9 of `guadal run` leaves no broker, emulator or bridge behind."""
    mission = yaml.safe_load((ROOT / "missions" / "lake_greedy_sitl.yaml").read_text())
    mission["map"] = str(LAKE)
    mission["fleet"]["vehicles"] = 1  # one bridge is enough, and quicker to start
    path = tmp_path / "m.yaml"
    path.write_text(yaml.safe_dump(mission))
    token = uuid.uuid4().hex  # inherited by every process the run starts
    mark = f"GUADAL_TEST_MARK={token}"
    run = subprocess.Popen(
        [sys.executable, "-m", "guadal_cli", "run", str(path), "-o", str(tmp_path / "run"), "-q"],
        env={**os.environ, "GUADAL_TEST_MARK": token},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        # mid-mission: steps are being recorded
        wait_for(
            lambda: (
                (tmp_path / "run" / "metrics.csv").is_file()
                and len((tmp_path / "run" / "metrics.csv").read_text().splitlines()) > 2
            ),
            60,
            "the mission did not start",
        )
        assert len(processes_marked(mark)) == 4  # the run, broker, emulator, bridge
    finally:
        run.send_signal(signal.SIGKILL)
        run.wait(10)
    wait_for(lambda: processes_marked(mark) == [], 20, "processes of the killed run's stack are still alive")
