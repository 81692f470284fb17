"""The app's boundary: a failure nobody foresaw is one sentence, a crash log and exit code 70.

Faults are injected for real: a planner plugin that raises during a run, and a library function
replaced by one that raises, in a real `guadal` process each time.
"""

import json
import os
import subprocess
import sys

import pytest
from support import base_mission, run_cli

from guadal_cli.app import EXIT_BUG

BROKEN_PLANNER = """
from guadal_cli.planners.greedy import GreedyStd

class Broken(GreedyStd):
    def next_targets(self, observation):
        if observation.step == 3:
            raise ZeroDivisionError("the planner divided by zero")
        return super().next_targets(observation)
"""


def crash_sentence(proc) -> str:
    assert proc.returncode == EXIT_BUG, proc.stderr
    assert "Traceback" not in proc.stderr and "Traceback" not in proc.stdout
    message = " ".join(proc.stderr.split())
    assert "failed unexpectedly" in message and "this is a bug, please report it" in message
    return message


def logged_traceback(message: str, *fragments) -> str:
    path = message.split("the details are in ", 1)[1].rstrip(".")
    text = open(path).read()
    assert "Traceback (most recent call last)" in text
    for fragment in fragments:
        assert fragment in text
    return path


def test_a_crashing_planner_gives_one_sentence_a_log_and_a_resumable_run(tmp_path, write_mission):
    (tmp_path / "broken.py").write_text(BROKEN_PLANNER)
    mission = write_mission(base_mission(algorithm={"type": "broken:Broken"}))
    env = {"PYTHONPATH": str(tmp_path), "XDG_STATE_HOME": str(tmp_path / "state")}
    proc = run_cli("run", mission, "-o", tmp_path / "run", "-q", env=env)
    message = crash_sentence(proc)
    assert "guadal run failed unexpectedly (ZeroDivisionError: the planner divided by zero)" in message
    path = logged_traceback(message, "ZeroDivisionError", "broken.py")
    assert path.startswith(str(tmp_path / "state" / "guadal" / "crashes"))
    manifest = json.loads((tmp_path / "run" / "manifest.json").read_text())
    assert manifest["status"] == "failed" and "ZeroDivisionError" in manifest["error"]


@pytest.mark.parametrize("state", ["writable", "unwritable"])
def test_an_injected_fault_in_any_command_is_caught_at_the_boundary(state, tmp_path):
    inject = (
        "import sys, guadal_cli.maps.format as f\n"
        "def broken(path):\n    raise KeyError('injected')\n"
        "f.load_map = broken\n"
        "from guadal_cli.app import main\n"
        "sys.argv = ['guadal', 'map', 'info', 'x.json']\n"
        "main()\n"
    )
    home = tmp_path / "state" if state == "writable" else "/proc/no-such-place"
    proc = subprocess.run(
        [sys.executable, "-c", inject],
        capture_output=True,
        text=True,
        env={**os.environ, "XDG_STATE_HOME": str(home)},
        timeout=120,
    )
    message = crash_sentence(proc)
    assert "guadal map failed unexpectedly (KeyError: 'injected')" in message
    logged_traceback(message, "KeyError: 'injected'")


def test_bad_input_still_exits_2_not_70(tmp_path):
    proc = run_cli("validate", tmp_path / "absent.yaml")
    assert proc.returncode == 2 and "failed unexpectedly" not in proc.stderr
