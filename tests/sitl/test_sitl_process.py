"""`guadal sitl` as a process: bad options, busy ports, water current and GPS noise, signals."""

from __future__ import annotations

import math
import signal
import socket
import subprocess
import statistics

from sitl_support import GUADAL, METRES_PER_DEG, connect, start_sitl, stop_sitl, wait_for


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([GUADAL, "sitl", *args], capture_output=True, text=True, timeout=60)


def test_bad_options_get_one_sentence_and_exit_2():
    result = _run("--home", "north-of-here", "--base-port", "0")
    assert result.returncode == 2
    assert "--home" in result.stderr and "LAT,LON" in result.stderr
    assert "Traceback" not in result.stderr and result.stdout == ""


def test_busy_port_is_reported_not_raised():
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        port = busy.getsockname()[1]
        result = _run("--base-port", str(port))
    assert result.returncode == 2
    assert f"127.0.0.1:{port}" in result.stderr and "--base-port" in result.stderr
    assert "Traceback" not in result.stderr


def test_current_drifts_the_boat_noise_scatters_reports_and_sigint_stops_cleanly():
    proc, info = start_sitl(
        "--base-port", "0", "--speedup", "100", "--current", "0.2,0", "--gps-noise", "0.5", "--seed", "7",
        "--home", "10.0,20.0",
    )
    try:
        assert info["vehicles"][0]["home"] == [10.0, 20.0]
        conn = connect(f"tcp:127.0.0.1:{info['vehicles'][0]['tcp']}")
        first = wait_for(conn, "GLOBAL_POSITION_INT")
        samples = [first]
        while samples[-1].time_boot_ms < first.time_boot_ms + 60_000:
            samples.append(wait_for(conn, "GLOBAL_POSITION_INT"))
        conn.close()
    finally:
        code, err = stop_sitl(proc, signal.SIGINT)
    assert code == 0 and "Traceback" not in err
    east = [(m.lon / 1e7 - 20.0) * METRES_PER_DEG * math.cos(math.radians(10.0)) for m in samples]
    north = [(m.lat / 1e7 - 10.0) * METRES_PER_DEG for m in samples]
    elapsed = (samples[-1].time_boot_ms - first.time_boot_ms) / 1000
    # disarmed and drifting east at 0.2 m/s: about 12 m in 60 s, give or take the GPS noise
    assert abs((east[-1] - east[0]) - 0.2 * elapsed) < 3.0
    residual = [e - 0.2 * (m.time_boot_ms - first.time_boot_ms) / 1000 - east[0] for e, m in zip(east, samples)]
    assert 0.2 < statistics.pstdev(north) < 1.0 and statistics.pstdev(residual) > 0.2
    assert all(m.vy == 20 and m.vx == 0 for m in samples)  # reported velocity is the drift, cm/s
