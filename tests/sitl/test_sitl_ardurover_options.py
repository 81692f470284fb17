"""``guadal sitl`` takes ardurover's own options, and keeps a dense GPS track at any speed-up."""

from __future__ import annotations

import statistics
import subprocess

import pytest
from support.sitl import SITL_MODULE, command_long, connect, start_sitl, stop_sitl

from guadal_cli.errors import GuadalError
from guadal_cli.sitl.ardupilot import RoverInstance, free_instances, instance_free, plan_rover_fleet
from guadal_cli.sitl.params import read_param_files

MAV_CMD_SET_MESSAGE_INTERVAL = 511
GLOBAL_POSITION_INT, ATTITUDE = 33, 30


def test_ardurover_command_line_starts_the_emulator_on_the_instance_port(tmp_path):
    (tmp_path / "rover.parm").write_text("WP_RADIUS 3\nWP_SPEED 0.3\nSOME_ARDUPILOT_ONLY_PARAM 7\n")
    (tmp_path / "guadal.parm").write_text("# the later file wins\nWP_RADIUS,0.75\n")
    (instance,) = free_instances(1, first=60)
    rover = RoverInstance(
        binary="ardurover",
        instance=instance,
        home=(37.41795, -5.98345),
        speedup=10,
        defaults=[tmp_path / "rover.parm", tmp_path / "guadal.parm"],
        sysid=4,
    )
    # the launcher's command line for ardurover, as sim_vehicle.py builds it, with guadal behind it
    assert rover.command()[:5] == ["ardurover", "-S", "--model", "motorboat", "--speedup"]
    proc, ready = start_sitl(*rover.command()[1:], entry=SITL_MODULE)
    try:
        (vehicle,) = ready["vehicles"]
        assert vehicle["tcp"] == rover.port == 5760 + 10 * instance and vehicle["sysid"] == 4
        assert vehicle["home"] == pytest.approx([37.41795, -5.98345])
        conn = connect(f"tcp:127.0.0.1:{vehicle['tcp']}")
        hb = conn.recv_match(type="HEARTBEAT", blocking=True, timeout=10)
        assert conn.target_system == 4 and hb.type == 11  # MAV_TYPE_SURFACE_BOAT
        values = {}
        for name in ("WP_RADIUS", "WP_SPEED"):
            conn.mav.param_request_read_send(4, 1, name.encode(), -1)
            msg = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=10)
            values[msg.param_id] = msg.param_value
        assert values == {"WP_RADIUS": pytest.approx(0.75), "WP_SPEED": pytest.approx(0.3)}
        conn.close()
    finally:
        stop_sitl(proc)


def test_rover_model_and_bad_ardurover_options_are_one_sentence(tmp_path):
    (tmp_path / "bad.parm").write_text("WP_RADIUS\n")
    runs = {
        "model": ["--model", "quadplane", "--base-port", "0"],
        "file": ["--defaults", str(tmp_path / "missing.parm"), "--base-port", "0"],
        "line": ["--defaults", str(tmp_path / "bad.parm"), "--base-port", "0"],
        "home": ["--home", "37.4,-5.9,10", "--base-port", "0"],
    }
    procs = {
        k: subprocess.Popen([*SITL_MODULE, *a], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for k, a in runs.items()
    }
    results = {k: (p.wait(timeout=60), p.communicate()[1]) for k, p in procs.items()}
    expected = {
        "model": "--model 'quadplane' is not one of motorboat",
        "file": "cannot read parameter file",
        "line": "line 1 must be NAME VALUE",
        "home": "LAT,LON,ALT,HEADING",
    }
    for name, (code, err) in results.items():
        assert code == 2 and expected[name] in err and "Traceback" not in err, (name, err)
    proc, ready = start_sitl("--model", "rover", "--base-port", "0", entry=SITL_MODULE)
    try:
        conn = connect(f"tcp:127.0.0.1:{ready['vehicles'][0]['tcp']}")
        assert conn.recv_match(type="HEARTBEAT", blocking=True, timeout=10).type == 10  # GROUND_ROVER
        conn.close()
    finally:
        stop_sitl(proc)


def _median_gaps(track_rate: str) -> dict[str, float]:
    """Median simulated seconds between GLOBAL_POSITION_INTs and between ATTITUDEs, both asked at 5 Hz."""
    proc, ready = start_sitl(
        "--speedup",
        "50",
        "--max-rate",
        "20",
        "--track-rate",
        track_rate,
        "--base-port",
        "0",
        entry=SITL_MODULE,
    )
    try:
        conn = connect(f"tcp:127.0.0.1:{ready['vehicles'][0]['tcp']}")
        for msg_id in (GLOBAL_POSITION_INT, ATTITUDE):
            assert command_long(conn, 1, MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, 200_000) == 0
        stamps = {"GLOBAL_POSITION_INT": [], "ATTITUDE": []}
        while len(stamps["ATTITUDE"]) < 12:
            msg = conn.recv_match(type=list(stamps), blocking=True, timeout=10)
            assert msg is not None, "telemetry stopped"
            stamps[msg.get_type()].append(msg.time_boot_ms / 1000)
        conn.close()
    finally:
        stop_sitl(proc)
    # the first few messages predate the interval requests
    return {k: statistics.median(b - a for a, b in zip(v[4:], v[5:])) for k, v in stamps.items()}, stamps


@pytest.mark.parametrize("track_rate", ["1", "2"])
def test_position_fixes_keep_the_track_rate_in_simulated_time_whatever_the_speedup(track_rate):
    gaps, stamps = _median_gaps(track_rate)
    # ATTITUDE is capped at 20 wall messages a second: at speed-up 50 one per 2.5 simulated seconds
    assert gaps["ATTITUDE"] >= 2.0
    # the position fixes are not thinned below the track rate: at least that many per simulated
    # second (up to twice as many, so that a recorder sampling at the track rate finds a fresh one)
    fixes = stamps["GLOBAL_POSITION_INT"][4:]
    assert (len(fixes) - 1) / (fixes[-1] - fixes[0]) >= float(track_rate)
    assert gaps["GLOBAL_POSITION_INT"] <= 1.0 / float(track_rate)


def test_rover_fleet_plan_writes_guided_defaults_and_one_folder_per_instance(tmp_path):
    binary = tmp_path / "ardurover"
    binary.write_text("#!/bin/sh\n")
    extra = tmp_path / "motorboat.parm"
    extra.write_text("FRAME_CLASS 2\n")
    homes = [(37.41795, -5.98345), (37.4180, -5.9834)]
    plan = plan_rover_fleet(
        binary=binary,
        homes=homes,
        speedup=20,
        speed=0.7,
        state_dir=tmp_path / "state",
        extra_defaults=[extra],
    )
    params = read_param_files([str(plan.defaults_file)])
    assert params["WP_SPEED"] == params["CRUISE_SPEED"] == 0.7 and params["WP_RADIUS"] == 1.0
    assert params["FS_ACTION"] == 2 and params["FS_GCS_ENABLE"] == 1 and params["FRAME_CLASS"] == 2
    first, second = plan.instances
    assert second.instance == first.instance + 1 and first.sysid == 1 and second.sysid == 2
    assert all(instance_free(i.instance) for i in plan.instances)
    assert [p.name for p in plan.workdirs] == ["ardupilot-0", "ardupilot-1"] and all(
        p.is_dir() for p in plan.workdirs
    )
    cmd = second.command()
    assert cmd[cmd.index("--defaults") + 1] == f"{extra.resolve()},{plan.defaults_file.resolve()}"
    assert f"-I{second.instance}" in cmd and cmd[cmd.index("--home") + 1].startswith(
        "37.41800000,-5.98340000,"
    )
    assert plan.mavproxy_command(1)[1:5] == [
        "--master",
        f"tcp:127.0.0.1:{5762 + 10 * second.instance}",
        "--out",
        f"udp:127.0.0.1:{14550 + 10 * second.instance}",
    ]
    with pytest.raises(GuadalError, match="ArduPilot SITL binary .* does not exist"):
        plan_rover_fleet(binary=tmp_path / "nope", homes=homes, speedup=1, speed=1, state_dir=tmp_path)
