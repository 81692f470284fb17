"""The app's one boundary (``console.GuadalGroup``): bad input is one sentence and exit code 2; a
failure nobody foresaw is one sentence, a crash log holding the traceback, and exit code 70.

Faults are injected for real: a planner plugin that raises during a run, and a library function
replaced by one that raises, in a real `guadal` process each time (and once in-process, since the
boundary is part of the app, not of ``main``).
"""

import json
import os
import subprocess
import sys

import pytest
from support import base_mission, run_cli
from typer.testing import CliRunner

from guadal_cli.app import app
from guadal_cli.console import EXIT_BUG
from guadal_cli.errors import GuadalError
from guadal_cli.maps.discretize import DiscretizeOptions

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
    assert "guadal map info failed unexpectedly (KeyError: 'injected')" in message
    logged_traceback(message, "KeyError: 'injected'")


def test_bad_input_still_exits_2_not_70(tmp_path):
    proc = run_cli("validate", tmp_path / "absent.yaml")
    assert proc.returncode == 2 and "failed unexpectedly" not in proc.stderr


def test_credentials_reach_neither_the_sentence_nor_the_log(tmp_path, write_mission):
    (tmp_path / "leaky.py").write_text(
        BROKEN_PLANNER.replace('"the planner divided by zero"', '"lost mqtt://pilot:hunter2@10.0.0.7:1883"')
    )
    mission = write_mission(base_mission(algorithm={"type": "leaky:Broken"}))
    env = {"PYTHONPATH": str(tmp_path), "XDG_STATE_HOME": str(tmp_path / "state")}
    message = crash_sentence(run_cli("run", mission, "-o", tmp_path / "run", "-q", env=env))
    assert "mqtt://***@10.0.0.7:1883" in message and "hunter2" not in message
    path = logged_traceback(message, "ZeroDivisionError: lost mqtt://***@10.0.0.7:1883")
    assert "hunter2" not in open(path).read()


def test_the_boundary_is_part_of_the_app_not_of_main(tmp_path, monkeypatch):
    import guadal_cli.maps.format as map_format

    def broken(path):
        raise KeyError("injected")

    monkeypatch.setattr(map_format, "load_map", broken)
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    result = CliRunner().invoke(app, ["map", "info", "x.json"])
    assert result.exit_code == EXIT_BUG and isinstance(result.exception, SystemExit)
    assert "guadal map info failed unexpectedly (KeyError: 'injected')" in " ".join(result.stderr.split())


def test_bad_input_is_exactly_one_sentence_and_writes_no_log(tmp_path, write_mission):
    mission = write_mission(base_mission(algorithm={"type": "greedy", "colour": "red"}))
    proc = run_cli("run", mission, env={"XDG_STATE_HOME": str(tmp_path / "state")})
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        f"error: {mission}: algorithm.colour: unknown key (allowed: none)."
    ]
    assert not (tmp_path / "state").exists()  # a user's mistake is no bug


def test_library_errors_name_fields_and_the_cli_names_its_flags(tmp_path):
    with pytest.raises(GuadalError) as caught:
        DiscretizeOptions(cell_size_m=-1)
    assert caught.value.field == "cell_size_m" and "--" not in str(caught.value)
    grid = tmp_path / "grid.csv"
    grid.write_text("1,1\n1,1\n")
    proc = run_cli(
        "discretize", grid, "--cell-size", "-1", "--bounds", "1,0,1,0", "--output", tmp_path / "m.json"
    )
    assert proc.returncode == 2
    assert "--cell-size must be between 0.1 and 1000 metres (got -1)" in proc.stderr


def test_a_path_the_system_refuses_is_one_sentence_naming_it_not_a_bug(tmp_path, write_mission):
    """An output in a folder that does not exist, or a folder where a file should be: the user's
    path, said as such (it used to be a crash log, "this is a bug")."""
    db = f"sqlite:///{tmp_path / 'g.db'}"
    env = {"XDG_STATE_HOME": str(tmp_path / "state")}
    mission = write_mission(base_mission(fleet={"vehicles": 1, "max_distance": 20.0}))
    assert run_cli("run", mission, "-o", tmp_path / "run", "-q", "--db", db).returncode == 0
    for output in (tmp_path / "no-such-folder" / "samples.csv", tmp_path):
        proc = run_cli("db", "samples", "--map", "urban_lake", "--db", db, "-o", output, env=env)
        assert proc.returncode == 2, proc.stderr
        assert proc.stderr.strip().splitlines() == [
            f"error: cannot use '{output}': "
            + ("No such file or directory." if output != tmp_path else "Is a directory.")
        ]
    proc = run_cli("db", "export", "9" * 30, "-o", tmp_path / "out", "--db", db, env=env)
    assert proc.returncode == 2 and f"no run '{'9' * 30}' in the database" in proc.stderr
    assert not (tmp_path / "state").exists()


def test_files_of_the_wrong_kind_are_one_sentence(tmp_path):
    from guadal_cli.channel.credentials import fleet_key
    from guadal_cli.maps.format import load_map
    from guadal_cli.sweep.manifest import read_sweep_manifest

    binary = tmp_path / "key.bin"
    binary.write_bytes(b"\x80\xcc" * 40)
    with pytest.raises(GuadalError, match="backend.key_file: '.*' is not UTF-8 text"):
        fleet_key(file=binary, what="backend.key")
    huge = tmp_path / "huge.json"
    huge.write_text('{"format": "guadal-map", "version": ' + "9" * 5000 + "}")
    with pytest.raises(GuadalError, match="is not readable JSON"):
        load_map(huge)
    for combinations in (None, 5, [["a"]], [{"id": ["a"]}]):
        (tmp_path / "sweep.json").write_text(
            json.dumps({"format": "guadal-sweep", "combinations": combinations})
        )
        with pytest.raises(GuadalError, match="is damaged: 'combinations' must be a list of entries"):
            read_sweep_manifest(tmp_path)


def test_mission_numbers_past_4300_digits_and_in_memory_databases_are_one_sentence(tmp_path):
    huge = tmp_path / "huge.yaml"
    huge.write_text("name: x\nseed: " + "9" * 5000 + "\n")
    proc = run_cli("validate", huge)
    assert proc.returncode == 2 and "a number in it is too long to read" in proc.stderr
    from guadal_cli.db.engine import check_url

    for url in ("sqlite://", "sqlite:///:memory:"):
        with pytest.raises(GuadalError, match="is a database in memory, gone when the process ends"):
            check_url(url)
