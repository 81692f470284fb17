"""`guadal sitl` as a process: bad options, busy ports, water current and GPS noise, signals
(the last through ``python -m guadal_cli sitl``, as ``guadal stack`` launches it)."""

from __future__ import annotations

import math
import signal
import socket
import statistics
import subprocess

import pytest
from support.sitl import METRES_PER_DEG, SITL_MODULE, connect, start_sitl, stop_sitl, wait_for

BAD_RUNS = {
    "home": ["--home", "north-of-here", "--base-port", "0"],
    "homes": ["--vehicles", "3", "--homes", "10,20;10.001,20", "--base-port", "0"],
    "speedup": ["--speedup", "-5", "--base-port", "0"],
    # past 1000 the physics could not keep up: 1e16 spun at 100 % CPU, deaf to SIGTERM
    "speedup_huge": ["--speedup", "1e16", "--base-port", "0"],
    "speedup_nan": ["--speedup", "nan", "--base-port", "0"],
    "max_speed_inf": ["--max-speed", "inf", "--base-port", "0"],
    "current_nan": ["--current", "nan,0", "--base-port", "0"],
}


@pytest.fixture(scope="module")
def bad_runs():
    """Every refused command line plus one on a port already taken, started together through
    ``python -m guadal_cli sitl`` (the fleet in test_sitl_emulator.py goes through ``guadal sitl``)."""
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        port = busy.getsockname()[1]
        runs = {name: [*SITL_MODULE, *args] for name, args in BAD_RUNS.items()}
        runs["busy"] = [*SITL_MODULE, "--base-port", str(port)]
        procs = {
            name: subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            for name, cmd in runs.items()
        }
        results = {name: (p.wait(timeout=60), *p.communicate()) for name, p in procs.items()}
    results["busy_port"] = port
    return results


def _refused(result) -> str:
    code, out, err = result
    assert code == 2 and out == "" and "Traceback" not in err, (code, out, err)
    return err


def test_bad_home_is_one_sentence_and_exit_2(bad_runs):
    err = _refused(bad_runs["home"])
    assert "--home" in err and "LAT,LON" in err


def test_homes_must_match_the_number_of_vehicles(bad_runs):
    assert "one LAT,LON per vehicle" in _refused(bad_runs["homes"])


def test_speedup_must_be_positive(bad_runs):
    assert "--speedup must be positive" in _refused(bad_runs["speedup"])


def test_speeds_and_rates_must_be_finite_and_the_speedup_bounded(bad_runs):
    assert "--speedup must be positive and at most 1000 (got 1e+16)" in _refused(bad_runs["speedup_huge"])
    assert "--speedup must be a finite number (got nan)" in _refused(bad_runs["speedup_nan"])
    assert "--max-speed must be a finite number (got inf)" in _refused(bad_runs["max_speed_inf"])
    assert "--current must be finite E,N m/s" in _refused(bad_runs["current_nan"])


def test_busy_port_is_reported_not_raised(bad_runs):
    err = _refused(bad_runs["busy"])
    assert f"127.0.0.1:{bad_runs['busy_port']}" in err and "--base-port" in err


def test_current_drifts_the_boat_noise_scatters_reports_and_sigint_stops_cleanly():
    proc, info = start_sitl(
        "--base-port",
        "0",
        "--speedup",
        "100",
        "--current",
        "0.2,0",
        "--gps-noise",
        "0.5",
        "--seed",
        "7",
        "--vehicles",
        "2",
        "--homes",
        "10.0,20.0; 10.001,20.0",
        entry=SITL_MODULE,
    )
    try:
        assert [v["home"] for v in info["vehicles"]] == [[10.0, 20.0], [10.001, 20.0]]
        conn = connect(f"tcp:127.0.0.1:{info['vehicles'][0]['tcp']}")
        battery_before = wait_for(conn, "BATTERY_STATUS")
        first = wait_for(conn, "GLOBAL_POSITION_INT")
        samples = [first]
        while samples[-1].time_boot_ms < first.time_boot_ms + 60_000:
            samples.append(wait_for(conn, "GLOBAL_POSITION_INT"))
        battery_after = wait_for(conn, "BATTERY_STATUS")
        conn.close()
    finally:
        code, err = stop_sitl(proc, signal.SIGINT)
    assert code == 0 and "Traceback" not in err
    east = [(m.lon / 1e7 - 20.0) * METRES_PER_DEG * math.cos(math.radians(10.0)) for m in samples]
    north = [(m.lat / 1e7 - 10.0) * METRES_PER_DEG for m in samples]
    elapsed = (samples[-1].time_boot_ms - first.time_boot_ms) / 1000
    # disarmed and drifting east at 0.2 m/s: about 12 m in 60 s, give or take the GPS noise
    assert abs((east[-1] - east[0]) - 0.2 * elapsed) < 3.0
    residual = [
        e - 0.2 * (m.time_boot_ms - first.time_boot_ms) / 1000 - east[0] for e, m in zip(east, samples)
    ]
    assert 0.2 < statistics.pstdev(north) < 1.0 and statistics.pstdev(residual) > 0.2
    assert all(m.vy == 20 and m.vx == 0 for m in samples)  # reported velocity is the drift, cm/s
    # the electronics draw the battery down even at rest, slowly
    assert battery_after.current_consumed > battery_before.current_consumed
    assert battery_after.battery_remaining >= 99
