"""Start ``guadal sitl`` as a real process and talk to it with pymavlink (no mocks, no sleeps)."""

from __future__ import annotations

import json
import os
import select
import subprocess
import sys
import time
from pathlib import Path

os.environ["MAVLINK20"] = "1"  # before pymavlink.mavutil is imported anywhere

from pymavlink import mavutil  # noqa: E402

GUADAL = str(Path(sys.executable).with_name("guadal"))
#: the CLI command, and the same command through the interpreter, as ``guadal stack`` launches it
SITL_CLI = [GUADAL, "sitl"]
SITL_MODULE = [sys.executable, "-m", "guadal_cli", "sitl"]
GCS_SYSID = 255
GCS_COMPID = 190
#: MAVLINK.md's mask for "go to this lat/lon": position used; velocity, accel, yaw, yaw rate ignored
POSITION_ONLY = 0x0FF8
METRES_PER_DEG = 111319.49079327357  # ArduPilot's LOCATION_SCALING_FACTOR × 1e7


def start_sitl(*args: str, entry=SITL_CLI, timeout: float = 30.0) -> tuple[subprocess.Popen, dict]:
    """Launch the emulator and return it with its parsed ready line."""
    proc = subprocess.Popen([*entry, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + timeout
    line = ""
    while not line.endswith("\n"):
        remaining = deadline - time.monotonic()
        ready, _, _ = select.select([proc.stdout], [], [], max(0.0, remaining))
        if not ready:
            proc.kill()
            raise AssertionError(f"guadal sitl printed no ready line within {timeout} s")
        chunk = proc.stdout.readline()
        if not chunk:
            err = proc.stderr.read()
            raise AssertionError(f"guadal sitl exited early ({proc.wait()}): {err}")
        line += chunk
    return proc, json.loads(line)


def stop_sitl(proc: subprocess.Popen, sig=None) -> tuple[int, str]:
    """Signal the emulator (SIGTERM by default) and return its exit code and stderr."""
    if proc.poll() is None:
        proc.send_signal(sig) if sig is not None else proc.terminate()
    try:
        _, err = proc.communicate(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate()
    return proc.returncode, err


def connect(device: str, **kwargs):
    """A GCS-like pymavlink connection that has seen the vehicle's first heartbeat."""
    conn = mavutil.mavlink_connection(device, source_system=GCS_SYSID, source_component=GCS_COMPID, **kwargs)
    hb = conn.recv_match(type="HEARTBEAT", blocking=True, timeout=10)
    assert hb is not None, f"no HEARTBEAT on {device}"
    return conn


def wait_for(conn, msg_type, condition=lambda m: True, timeout: float = 10.0):
    """The first ``msg_type`` message satisfying ``condition`` within ``timeout`` wall seconds."""
    deadline = time.monotonic() + timeout
    while True:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise AssertionError(f"no {msg_type} matching the condition within {timeout} s")
        msg = conn.recv_match(type=msg_type, blocking=True, timeout=remaining)
        if msg is not None and condition(msg):
            return msg


def collect(conn, msg_types, until, timeout: float = 10.0) -> list:
    """Every message of ``msg_types`` received until ``until(msg)`` is true for one of them."""
    deadline = time.monotonic() + timeout
    seen = []
    while True:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise AssertionError(
                f"condition not met within {timeout} s; saw {[m.get_type() for m in seen][-10:]}"
            )
        msg = conn.recv_match(type=msg_types, blocking=True, timeout=remaining)
        if msg is None:
            continue
        seen.append(msg)
        if until(msg):
            return seen


def command_long(conn, sysid: int, command: int, *params: float) -> int:
    """Send COMMAND_LONG and return the result of its COMMAND_ACK."""
    p = list(params) + [0.0] * (7 - len(params))
    conn.mav.command_long_send(sysid, 1, command, 0, *p)
    return wait_for(conn, "COMMAND_ACK", lambda m: m.command == command).result


def command_int(
    conn, sysid: int, command: int, frame: int, params=(0, 0, 0, 0), x: int = 0, y: int = 0, z: float = 0.0
) -> int:
    conn.mav.command_int_send(sysid, 1, frame, command, 0, 0, *params, x, y, z)
    return wait_for(conn, "COMMAND_ACK", lambda m: m.command == command).result


def set_mode(conn, sysid: int, mode: int) -> int:
    """SET_MODE with the custom-mode flag; returns the COMMAND_ACK result (command id 11)."""
    conn.mav.set_mode_send(sysid, 1, mode)
    return wait_for(conn, "COMMAND_ACK", lambda m: m.command == 11).result


def arm(conn, sysid: int, on: bool = True, force: bool = False) -> int:
    magic = (2989 if on else 21196) if force else 0
    return command_long(conn, sysid, 400, 1 if on else 0, magic)


def barrier(conn, sysid: int) -> None:
    """Round trip a parameter read: every message sent before it has been handled."""
    conn.mav.param_request_read_send(sysid, 1, b"WP_RADIUS", -1)
    wait_for(conn, "PARAM_VALUE", lambda m: m.param_id == "WP_RADIUS")


def heartbeat_of(conn, sysid: int, condition=lambda m: True, timeout: float = 10.0):
    return wait_for(conn, "HEARTBEAT", lambda m: m.get_srcSystem() == sysid and condition(m), timeout)


def offset(home, north_m: float, east_m: float = 0.0) -> tuple[int, int]:
    """lat/lon ×1e7 of a point ``north_m``/``east_m`` from ``home`` (flat earth)."""
    import math

    lat = home[0] + north_m / METRES_PER_DEG
    lon = home[1] + east_m / (METRES_PER_DEG * math.cos(math.radians(home[0])))
    return int(round(lat * 1e7)), int(round(lon * 1e7))


def metres_between(a: tuple[int, int], b: tuple[int, int]) -> float:
    import math

    dn = (a[0] - b[0]) / 1e7 * METRES_PER_DEG
    de = (a[1] - b[1]) / 1e7 * METRES_PER_DEG * math.cos(math.radians(a[0] / 1e7))
    return math.hypot(dn, de)
