"""ArduPilot's SITL as the sitl level's autopilot, through the very launch path ``ardurover`` takes.

ArduPilot's binary cannot be built here, so ``binary:`` points at a wrapper that records its
command line and execs guadal's emulator with it: the emulator accepts ardurover's options, so
the launcher, the per-instance folders, the parameter file and the bridges are all real.
"""

from __future__ import annotations

import csv
import json
import math
import shlex
import statistics
import sys
import uuid
from pathlib import Path

import yaml
from support import LAKE, base_mission, run_cli
from support.fleet import processes_marked

from guadal_cli.mission import prepare
from guadal_cli.runner import MissionRunner
from guadal_cli.sitl.params import read_param_files


def ardurover_stand_in(folder: Path) -> Path:
    """An executable named like ArduPilot's that logs its argv and working folder, then runs guadal's emulator."""
    wrapper = folder / "ardurover"
    log = folder / "ardurover-calls.txt"
    wrapper.write_text(
        "#!/bin/sh\n"
        f'echo "$(pwd) $*" >> {shlex.quote(str(log))}\n'
        # the parameter files as read, in order (a launched stack's own folder is gone after the run)
        'prev=""; for a in "$@"; do\n'
        '  if [ "$prev" = "--defaults" ]; then\n'
        f'    for f in $(echo "$a" | tr "," " "); do cat "$f" >> {shlex.quote(str(folder))}/params-$(basename "$(pwd)").parm; done\n'
        '  fi; prev="$a"\n'
        "done\n"
        f'exec {shlex.quote(sys.executable)} -m guadal_cli sitl "$@"\n'
    )
    wrapper.chmod(0o755)
    return wrapper


def calls(folder: Path) -> list[tuple[str, list[str]]]:
    lines = (folder / "ardurover-calls.txt").read_text().splitlines()
    return [(line.split(" ", 1)[0], line.split(" ", 1)[1].split()) for line in lines]


def test_a_mission_on_ardupilot_sitl_launches_one_ardurover_per_boat_as_sim_vehicle_would(
    tmp_path, monkeypatch
):
    binary = ardurover_stand_in(tmp_path)
    extra = tmp_path / "motorboat.parm"
    extra.write_text("WP_RADIUS 3\nSOME_ARDUPILOT_ONLY_PARAM 1\n")
    mission = base_mission(
        name="ardu",
        backend={
            "level": "sitl",
            "launch": True,
            "autopilot": "ardupilot",
            "binary": str(binary),
            "defaults": [str(extra)],
            "speedup": 20,
        },
    )
    mission["fleet"] = {**mission["fleet"], "vehicles": 2, "max_distance": 30.0}
    path = tmp_path / "ardu.yaml"
    path.write_text(yaml.safe_dump(mission))
    mark = uuid.uuid4().hex
    monkeypatch.setenv("GUADAL_TEST_MARK", mark)
    run = tmp_path / "run"
    result = MissionRunner(prepare(path), output=run).run()
    assert result.status == "complete"

    launched = calls(tmp_path)
    assert len(launched) == 2
    instances = []
    for v, (cwd, argv) in enumerate(launched):
        assert Path(cwd).name == f"ardupilot-{v}"  # its own folder: eeprom.bin and logs
        assert argv[:4] == ["-S", "--model", "motorboat", "--speedup"] and argv[4] == "20"
        assert argv[argv.index("--sysid") + 1] == str(v + 1)
        instance = next(int(a[2:]) for a in argv if a.startswith("-I"))
        home = argv[argv.index("--home") + 1].split(",")
        assert len(home) == 4
        files = argv[argv.index("--defaults") + 1].split(",")
        assert files[0] == str(extra.resolve()) and files[-1].endswith("guadal-rover.parm")
        params = read_param_files([str(tmp_path / f"params-ardupilot-{v}.parm")])  # all of them, in order
        assert params["WP_RADIUS"] == 1.0 and params["WP_SPEED"] == 0.5  # guadal's file comes last and wins
        instances.append(instance)
    assert instances[1] == instances[0] + 1  # consecutive instances, where every port was free
    assert processes_marked(f"GUADAL_TEST_MARK={mark}") == [], "the launched stack left processes behind"

    manifest = json.loads((run / "manifest.json").read_text())
    assert manifest["fleet"]["gps_track_rate_hz"] == 1.0 and manifest["fleet"]["problems"] == []
    with open(run / "trajectory.csv", newline="") as fh:
        gps = [r for r in csv.DictReader(fh) if r["source"] == "gps" and r["vehicle"] == "0"]
    times = [float(r["time_s"]) for r in gps]
    gaps = [b - a for a, b in zip(times, times[1:])]
    # one fix per simulated second of the boat's clock, at speed-up 20 as at any other: the track
    # keeps the first fix of each period of a fixed grid (on the boat's clock, whose origin the CSV
    # does not show), so a late fix makes its gap to the next one short, but over any span no more
    # periods, hence fixes, are touched than the span's whole seconds plus the two partial ends
    assert len(gaps) > 10 and min(gaps) > 0
    assert len(times) <= math.floor(times[-1] - times[0]) + 2
    assert statistics.median(gaps) < 1.2


def test_ardupilot_without_its_binary_is_one_sentence(tmp_path):
    mission = base_mission(backend={"level": "sitl", "launch": True, "autopilot": "ardupilot"})
    path = tmp_path / "m.yaml"
    path.write_text(yaml.safe_dump(mission))
    out = run_cli("validate", path)
    assert out.returncode == 2 and "needs binary" in out.stderr and "Traceback" not in out.stderr
    mission["backend"]["binary"] = str(tmp_path / "no-such-ardurover")
    path.write_text(yaml.safe_dump(mission))
    out = run_cli("run", path, "--run-dir", tmp_path / "r", "-q")
    assert out.returncode == 2 and "ArduPilot SITL binary" in out.stderr and "Traceback" not in out.stderr


def test_stack_up_with_ardupilot_and_bridge_options(tmp_path):
    binary = ardurover_stand_in(tmp_path)
    state = tmp_path / "stack"
    up = run_cli(
        "stack", "up", "--map", LAKE, "--vehicles", "1", "--speedup", "10", "--state-dir", state,
        "--autopilot", "ardupilot", "--binary", binary, "--bridge-arg=--arrival-radius", "--bridge-arg=1.5",
        "--track-rate", "2", "--json",
    )  # fmt: skip
    try:
        assert up.returncode == 0, up.stderr
        info = json.loads(up.stdout)
        assert info["autopilot"] == "ardupilot" and len(info["ardupilot"]["mavlink"]) == 1
        bridge_cmd = json.loads((state / "stack.json").read_text())
        bridge = next(p for p in bridge_cmd["processes"] if p["name"] == "bridge-0")
        cmd = bridge["cmd"]
        assert cmd[cmd.index("--arrival-radius") + 1] == "1.5" and cmd[cmd.index("--track-rate") + 1] == "2"
        assert cmd[cmd.index("--mavlink") + 1] == info["ardupilot"]["mavlink"][0]
        ((cwd, argv),) = calls(tmp_path)
        assert Path(cwd) == state / "ardupilot-0" and "-S" in argv
    finally:
        down = run_cli("stack", "down", "--state-dir", state)
    assert down.returncode == 0, down.stderr
