"""`guadal sitl` against MAVLINK.md: one real emulator process, pymavlink over real TCP, UDP and a
pseudo-terminal.  Every wait is a condition with a timeout; distances are short and the speed-up
high so the module runs in seconds."""

from __future__ import annotations

import math
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from support.sitl import (
    POSITION_ONLY,
    arm,
    barrier,
    collect,
    command_int,
    command_long,
    connect,
    heartbeat_of,
    metres_between,
    offset,
    set_mode,
    start_sitl,
    stop_sitl,
    wait_for,
)

MANUAL, HOLD, LOITER, AUTO, RTL, SMART_RTL, GUIDED = 0, 4, 5, 10, 11, 12, 15
ACCEPTED, DENIED, FAILED, UNSUPPORTED = 0, 2, 4, 3
CUSTOM, GUIDED_FLAG, MANUAL_FLAG, ARMED_FLAG = 1, 8, 64, 128
SPEEDUP = 50
MAX_SPEED = 0.5
VEHICLES = 3


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def fleet():
    udp_port = _free_udp_port()
    proc, info = start_sitl(
        "--vehicles",
        str(VEHICLES),
        "--base-port",
        "0",
        "--speedup",
        str(SPEEDUP),
        "--serial",
        "pty",
        "--udp-out",
        f"127.0.0.1:{udp_port}",
    )
    info["udp_port"] = udp_port
    yield info
    code, err = stop_sitl(proc)
    assert code == 0 and "Traceback" not in err, err


@pytest.fixture
def gcs(fleet):
    """``gcs(sysid)``: a fresh GCS connection to that vehicle, reset to disarmed MANUAL so tests
    do not depend on each other's leftovers (several tests share a vehicle to save start-ups)."""
    opened = []

    def open_vehicle(sysid: int):
        conn = connect(f"tcp:127.0.0.1:{fleet['vehicles'][sysid - 1]['tcp']}")
        opened.append(conn)
        assert arm(conn, sysid, on=False, force=True) == ACCEPTED
        assert set_mode(conn, sysid, MANUAL) == ACCEPTED
        return conn, sysid

    yield open_vehicle
    for conn in opened:
        conn.close()


def _position(conn, sysid):
    msg = wait_for(conn, "GLOBAL_POSITION_INT", lambda m: m.get_srcSystem() == sysid)
    return (msg.lat, msg.lon), msg.time_boot_ms


def _echo(conn):
    """The target the vehicle reports after every message sent so far has been handled."""
    msg = wait_for(conn, "POSITION_TARGET_GLOBAL_INT")
    return msg.lat_int, msg.lon_int


def _send_target(conn, sysid, latlon, mask=POSITION_ONLY, frame=6):
    conn.mav.set_position_target_global_int_send(
        0, sysid, 1, frame, mask, latlon[0], latlon[1], 0, 0, 0, 0, 0, 0, 0, 0, 0
    )


# ------------------------------------------------------------------ identity and connections
def test_each_vehicle_has_its_own_port_and_system_id(fleet):
    ports = [v["tcp"] for v in fleet["vehicles"]]
    assert len(set(ports)) == VEHICLES
    for expected, vehicle in enumerate(fleet["vehicles"], start=1):
        conn = connect(f"tcp:127.0.0.1:{vehicle['tcp']}")
        hb = wait_for(conn, "HEARTBEAT")
        assert vehicle["sysid"] == expected and hb.get_srcSystem() == expected
        assert (hb.type, hb.autopilot) == (11, 3)  # SURFACE_BOAT, ARDUPILOTMEGA
        conn.close()
    homes = [tuple(v["home"]) for v in fleet["vehicles"]]
    assert len(set(homes)) == VEHICLES  # boats do not start on top of each other


def test_heartbeat_reports_mode_flags_and_status(gcs):
    conn, sysid = gcs(1)
    hb = heartbeat_of(conn, sysid, lambda m: m.custom_mode == MANUAL)
    assert (hb.base_mode, hb.system_status) == (CUSTOM | MANUAL_FLAG, 4)
    assert set_mode(conn, sysid, HOLD) == ACCEPTED
    hb = heartbeat_of(conn, sysid, lambda m: m.custom_mode == HOLD)
    assert (hb.base_mode, hb.system_status) == (CUSTOM, 3)  # STANDBY in HOLD
    assert set_mode(conn, sysid, GUIDED) == ACCEPTED
    hb = heartbeat_of(conn, sysid, lambda m: m.custom_mode == GUIDED)
    assert (hb.base_mode, hb.system_status) == (CUSTOM | GUIDED_FLAG, 4)
    assert arm(conn, sysid) == ACCEPTED
    hb = heartbeat_of(conn, sysid, lambda m: m.base_mode & ARMED_FLAG)
    assert hb.base_mode == CUSTOM | GUIDED_FLAG | ARMED_FLAG and conn.motors_armed()


def test_navigation_messages_only_in_autopilot_modes(gcs):
    conn, sysid = gcs(2)
    barrier(conn, sysid)
    seen = []
    while seen.count("HEARTBEAT") < 5:  # MANUAL: no controller output, no target
        msg = wait_for(conn, ["HEARTBEAT", "NAV_CONTROLLER_OUTPUT", "POSITION_TARGET_GLOBAL_INT"])
        seen.append(msg.get_type())
    assert set(seen) == {"HEARTBEAT"}
    assert set_mode(conn, sysid, GUIDED) == ACCEPTED
    here, _ = _position(conn, sysid)
    target = offset((here[0] / 1e7, here[1] / 1e7), 30.0)
    _send_target(conn, sysid, target)
    barrier(conn, sysid)
    assert 28 <= wait_for(conn, "NAV_CONTROLLER_OUTPUT").wp_dist <= 32
    assert _echo(conn) == target


def test_mode_change_acknowledgements(gcs):
    conn, sysid = gcs(1)
    assert set_mode(conn, sysid, LOITER) == ACCEPTED
    assert command_long(conn, sysid, 176, 1, GUIDED) == ACCEPTED  # DO_SET_MODE with the custom flag
    assert command_long(conn, sysid, 176, 0, HOLD) == DENIED  # base_mode without the custom flag
    assert command_long(conn, sysid, 176, 1, AUTO) == FAILED  # no mission to run
    assert command_long(conn, sysid, 176, 1, 99) == FAILED  # no such mode
    hb = heartbeat_of(conn, sysid)
    assert hb.custom_mode == GUIDED  # the refused changes left the mode alone


def test_arming_rules(gcs):
    conn, sysid = gcs(1)
    assert set_mode(conn, sysid, RTL) == ACCEPTED
    assert arm(conn, sysid) == FAILED
    assert not heartbeat_of(conn, sysid).base_mode & ARMED_FLAG
    assert arm(conn, sysid, force=True) == ACCEPTED
    heartbeat_of(conn, sysid, lambda m: m.base_mode & ARMED_FLAG)
    assert arm(conn, sysid, on=False) == ACCEPTED
    heartbeat_of(conn, sysid, lambda m: not m.base_mode & ARMED_FLAG)
    assert set_mode(conn, sysid, SMART_RTL) == ACCEPTED
    assert arm(conn, sysid) == FAILED
    assert set_mode(conn, sysid, MANUAL) == ACCEPTED
    assert arm(conn, sysid) == ACCEPTED


# ------------------------------------------------------------------ guided targets
def test_target_ignored_outside_guided(gcs):
    conn, sysid = gcs(2)
    assert set_mode(conn, sysid, LOITER) == ACCEPTED
    assert arm(conn, sysid) == ACCEPTED
    barrier(conn, sysid)
    loiter_point = _echo(conn)
    here, _ = _position(conn, sysid)
    _send_target(conn, sysid, offset((here[0] / 1e7, here[1] / 1e7), 6.0))
    barrier(conn, sysid)
    assert _echo(conn) == loiter_point


def test_target_without_acc_ignore_is_dropped_with_two_chunk_statustext(gcs):
    conn, sysid = gcs(2)
    assert set_mode(conn, sysid, GUIDED) == ACCEPTED
    barrier(conn, sysid)
    before = _echo(conn)
    here, _ = _position(conn, sysid)
    _send_target(conn, sysid, offset((here[0] / 1e7, here[1] / 1e7), 6.0), mask=POSITION_ONLY & ~0x1C0)
    first = wait_for(conn, "STATUSTEXT", lambda m: m.id != 0 and m.chunk_seq == 0)
    second = wait_for(conn, "STATUSTEXT", lambda m: m.id == first.id and m.chunk_seq == 1)
    assert first.text + second.text == "Ignoring SET_POSITION_TARGET_GLOBAL_INT; set ACC_IGNORE in mask"
    barrier(conn, sysid)
    assert _echo(conn) == before


def test_ignore_altitude_mask_moves_nothing(gcs):
    conn, sysid = gcs(2)
    assert set_mode(conn, sysid, GUIDED) == ACCEPTED
    barrier(conn, sysid)
    before = _echo(conn)
    here, _ = _position(conn, sysid)
    _send_target(conn, sysid, offset((here[0] / 1e7, here[1] / 1e7), 6.0), mask=0x0FFC)
    barrier(conn, sysid)
    assert _echo(conn) == before


def test_guided_target_is_driven_at_most_max_speed_and_reached_once(gcs):
    conn, sysid = gcs(3)
    assert set_mode(conn, sysid, GUIDED) == ACCEPTED
    assert arm(conn, sysid) == ACCEPTED
    here, t_start = _position(conn, sysid)
    target = offset((here[0] / 1e7, here[1] / 1e7), 8.0)
    _send_target(conn, sysid, target)
    seen = collect(
        conn,
        ["GLOBAL_POSITION_INT", "VFR_HUD", "MISSION_ITEM_REACHED"],
        lambda m: m.get_type() == "MISSION_ITEM_REACHED",
    )
    assert seen[-1].seq == 0
    speeds = [math.hypot(m.vx, m.vy) / 100 for m in seen if m.get_type() == "GLOBAL_POSITION_INT"]
    speeds += [m.groundspeed for m in seen if m.get_type() == "VFR_HUD"]
    assert max(speeds) <= MAX_SPEED + 0.01 and max(speeds) > 0.8 * MAX_SPEED
    pos, t_arrived = _position(conn, sysid)
    # 6 m to cover before the 2 m radius: no faster than max speed allows
    assert t_arrived - t_start >= (8.0 - 2.0) / MAX_SPEED * 1000
    assert metres_between(pos, target) <= 2.5
    # loitering afterwards: 30 simulated seconds and no second arrival
    later = collect(
        conn,
        ["GLOBAL_POSITION_INT", "MISSION_ITEM_REACHED"],
        lambda m: m.get_type() == "GLOBAL_POSITION_INT" and m.time_boot_ms > t_arrived + 30_000,
    )
    assert not [m for m in later if m.get_type() == "MISSION_ITEM_REACHED"]
    assert metres_between((later[-1].lat, later[-1].lon), target) <= 2.5
    assert command_long(conn, sysid, 178, 1, 0.3, -1) == FAILED  # arrived: loitering, not driving
    # the same target sent again is a new target, with its own arrival
    _send_target(conn, sysid, target)
    assert wait_for(conn, "MISSION_ITEM_REACHED").seq == 0


def test_replaced_target_gets_no_arrival_and_disarmed_boat_none_at_all(gcs):
    conn, sysid = gcs(3)
    assert set_mode(conn, sysid, GUIDED) == ACCEPTED
    here, t0 = _position(conn, sysid)
    home = (here[0] / 1e7, here[1] / 1e7)
    _send_target(conn, sysid, here)  # disarmed, already within the radius
    later = collect(
        conn,
        ["GLOBAL_POSITION_INT", "MISSION_ITEM_REACHED"],
        lambda m: m.get_type() == "GLOBAL_POSITION_INT" and m.time_boot_ms > t0 + 20_000,
    )
    assert not [m for m in later if m.get_type() == "MISSION_ITEM_REACHED"]
    assert arm(conn, sysid) == ACCEPTED
    wait_for(conn, "MISSION_ITEM_REACHED")
    north, south = offset(home, 6.0), offset(home, -6.0)
    _send_target(conn, sysid, north)
    wait_for(conn, "GLOBAL_POSITION_INT", lambda m: metres_between((m.lat, m.lon), here) > 0.5)
    _send_target(conn, sysid, south)
    seen = collect(
        conn,
        ["GLOBAL_POSITION_INT", "MISSION_ITEM_REACHED"],
        lambda m: m.get_type() == "MISSION_ITEM_REACHED",
    )
    pos, t_arrived = _position(conn, sysid)
    assert metres_between(pos, south) <= 2.5
    later = collect(
        conn,
        ["GLOBAL_POSITION_INT", "MISSION_ITEM_REACHED"],
        lambda m: m.get_type() == "GLOBAL_POSITION_INT" and m.time_boot_ms > t_arrived + 20_000,
    )
    reached = [m for m in seen + later if m.get_type() == "MISSION_ITEM_REACHED"]
    assert len(reached) == 1


def test_velocity_target_steers_then_times_out_after_three_seconds(gcs):
    conn, sysid = gcs(1)
    assert set_mode(conn, sysid, GUIDED) == ACCEPTED
    assert arm(conn, sysid) == ACCEPTED
    velocity_only = 0x0DC7  # position, accel, yaw, yaw rate ignored; vx/vy (north/east) used

    def keep_streaming(msg) -> bool:
        """Like a GCS: re-send the velocity on every position report until the boat runs east."""
        if msg.vy > 25:  # cm/s eastwards
            return True
        conn.mav.set_position_target_global_int_send(
            0, sysid, 1, 6, velocity_only, 0, 0, 0, 0.0, 0.3, 0, 0, 0, 0, 0, 0
        )
        return False

    moving = wait_for(conn, "GLOBAL_POSITION_INT", keep_streaming)
    assert abs(moving.vx) < 10 and moving.vy <= 31
    wait_for(conn, "STATUSTEXT", lambda m: m.text == "target not received last 3secs, stopping")
    wait_for(conn, "VFR_HUD", lambda m: m.groundspeed == 0)


def test_mission_item_int_guided_waypoint_is_acknowledged(gcs):
    conn, sysid = gcs(2)
    here, _ = _position(conn, sysid)
    target = offset((here[0] / 1e7, here[1] / 1e7), 5.0)

    def send():
        conn.mav.mission_item_int_send(sysid, 1, 0, 6, 16, 2, 1, 0, 0, 0, 0, target[0], target[1], 0, 0)
        return wait_for(conn, "MISSION_ACK").type

    assert send() == 1  # MAV_MISSION_ERROR outside GUIDED
    assert set_mode(conn, sysid, GUIDED) == ACCEPTED
    assert send() == 0  # MAV_MISSION_ACCEPTED
    barrier(conn, sysid)
    assert _echo(conn) == target


def test_do_reposition_needs_command_int(gcs):
    conn, sysid = gcs(2)
    assert set_mode(conn, sysid, HOLD) == ACCEPTED
    here, _ = _position(conn, sysid)
    target = offset((here[0] / 1e7, here[1] / 1e7), 4.0, 3.0)
    assert command_long(conn, sysid, 192, -1, 1, 0, 0, target[0] / 1e7, target[1] / 1e7, 0) == UNSUPPORTED
    assert (
        command_int(conn, sysid, 192, 6, (-1, 0, 0, 0), target[0], target[1]) == DENIED
    )  # HOLD, no mode flag
    assert heartbeat_of(conn, sysid).custom_mode == HOLD
    assert command_int(conn, sysid, 192, 6, (-1, 1, 0, 0), target[0], target[1]) == ACCEPTED
    assert heartbeat_of(conn, sysid).custom_mode == GUIDED
    assert _echo(conn) == target


def test_change_speed_only_while_driving(gcs):
    conn, sysid = gcs(1)

    def change_speed(mps):
        return command_long(conn, sysid, 178, 1, mps, -1)

    assert set_mode(conn, sysid, HOLD) == ACCEPTED
    assert change_speed(0.3) == FAILED
    assert set_mode(conn, sysid, GUIDED) == ACCEPTED
    assert change_speed(0.3) == FAILED  # freshly entered GUIDED: loitering, not driving
    assert arm(conn, sysid) == ACCEPTED
    here, _ = _position(conn, sysid)
    _send_target(conn, sysid, offset((here[0] / 1e7, here[1] / 1e7), 40.0))
    assert change_speed(0.2) == ACCEPTED
    wait_for(conn, "VFR_HUD", lambda m: abs(m.groundspeed - 0.2) < 0.01)
    assert all(wait_for(conn, "VFR_HUD").groundspeed <= 0.21 for _ in range(5))
    assert set_mode(conn, sysid, HOLD) == ACCEPTED  # HOLD stops the boat
    wait_for(conn, "VFR_HUD", lambda m: m.groundspeed == 0)
    assert set_mode(conn, sysid, GUIDED) == ACCEPTED  # entering GUIDED restores WP_SPEED
    here, _ = _position(conn, sysid)
    _send_target(conn, sysid, offset((here[0] / 1e7, here[1] / 1e7), -40.0))
    wait_for(conn, "VFR_HUD", lambda m: m.groundspeed > 0.45)
    assert set_mode(conn, sysid, LOITER) == ACCEPTED
    assert change_speed(0.3) == FAILED
    assert set_mode(conn, sysid, RTL) == ACCEPTED
    assert change_speed(0.3) == ACCEPTED


def test_rtl_drives_home_and_loiters(gcs, fleet):
    conn, sysid = gcs(1)
    home = tuple(fleet["vehicles"][sysid - 1]["home"])
    assert set_mode(conn, sysid, GUIDED) == ACCEPTED
    assert arm(conn, sysid) == ACCEPTED
    here, _ = _position(conn, sysid)
    if metres_between(here, offset(home, 0)) < 6:
        _send_target(conn, sysid, offset(home, 8.0))
        wait_for(conn, "MISSION_ITEM_REACHED")
    assert set_mode(conn, sysid, RTL) == ACCEPTED
    nav = wait_for(conn, "NAV_CONTROLLER_OUTPUT")
    assert nav.wp_dist >= 5
    wait_for(conn, "STATUSTEXT", lambda m: m.text == "Reached destination")
    pos, _ = _position(conn, sysid)
    assert metres_between(pos, offset(home, 0)) <= 2.5
    assert heartbeat_of(conn, sysid).custom_mode == RTL


# ------------------------------------------------------------------ telemetry and parameters
def test_set_message_interval_changes_the_simulated_rate(gcs):
    conn, sysid = gcs(3)

    def mean_interval_ms(n=4):
        stamps = [wait_for(conn, "GLOBAL_POSITION_INT").time_boot_ms for _ in range(n + 1)]
        return (stamps[-1] - stamps[0]) / n

    # Below the wall-rate cap (1 Hz at speed-up 50 would exceed it) the interval is the requested
    # one in simulated time; the tolerance absorbs a busy machine's scheduling jitter, which the
    # speed-up multiplies.
    assert command_long(conn, sysid, 511, 33, 5_000_000) == ACCEPTED
    wait_for(conn, "GLOBAL_POSITION_INT")
    assert mean_interval_ms() == pytest.approx(5000, rel=0.15)
    assert command_long(conn, sysid, 511, 33, 10_000_000) == ACCEPTED
    wait_for(conn, "GLOBAL_POSITION_INT")
    assert mean_interval_ms(3) == pytest.approx(10000, rel=0.15)
    assert command_long(conn, sysid, 511, 33, 0) == ACCEPTED  # back to the default
    assert command_long(conn, sysid, 511, 9999, 1_000_000) == DENIED  # not a message it sends
    # REQUEST_DATA_STREAM (no ACK): stop the POSITION group, then bring it back
    conn.mav.request_data_stream_send(sysid, 1, 6, 0, 0)
    barrier(conn, sysid)
    seen = []
    while seen.count("HEARTBEAT") < 10:
        seen.append(wait_for(conn, ["HEARTBEAT", "GLOBAL_POSITION_INT"]).get_type())
    assert "GLOBAL_POSITION_INT" not in seen
    conn.mav.request_data_stream_send(sysid, 1, 6, 1, 1)
    assert wait_for(conn, "GLOBAL_POSITION_INT") is not None


def test_parameters_read_set_and_list(gcs):
    conn, sysid = gcs(2)
    conn.mav.param_request_read_send(sysid, 1, b"WP_SPEED", -1)
    wp_speed = wait_for(conn, "PARAM_VALUE", lambda m: m.param_id == "WP_SPEED")
    assert wp_speed.param_value == pytest.approx(MAX_SPEED)  # consistent with the hull's top speed
    conn.mav.param_set_send(sysid, 1, b"WP_RADIUS", 3.0, 9)
    assert wait_for(conn, "PARAM_VALUE", lambda m: m.param_id == "WP_RADIUS").param_value == pytest.approx(
        3.0
    )
    conn.mav.param_set_send(sysid, 1, b"WP_RADIUS", 2.0, 9)
    wait_for(conn, "PARAM_VALUE", lambda m: m.param_id == "WP_RADIUS" and m.param_value == 2.0)
    conn.mav.param_request_list_send(sysid, 1)
    first = wait_for(conn, "PARAM_VALUE")
    values = {first.param_id: first}
    while len(values) < first.param_count:
        msg = wait_for(conn, "PARAM_VALUE")
        values[msg.param_id] = msg
    assert {"WP_SPEED", "WP_RADIUS", "CRUISE_SPEED", "FRAME_CLASS"} <= set(values)
    assert values["FRAME_CLASS"].param_value == 2 and values["FRAME_CLASS"].param_type == 2
    assert sorted(m.param_index for m in values.values()) == list(range(first.param_count))
    # FRAME_CLASS decides what the heartbeat says the vehicle is
    conn.mav.param_set_send(sysid, 1, b"FRAME_CLASS", 1, 2)
    assert heartbeat_of(conn, sysid, lambda m: m.type != 11).type == 10  # GROUND_ROVER
    conn.mav.param_set_send(sysid, 1, b"FRAME_CLASS", 2, 2)
    heartbeat_of(conn, sysid, lambda m: m.type == 11)


def test_garbage_is_counted_and_a_dropped_client_is_replaced(gcs, fleet):
    conn, sysid = gcs(2)
    port = fleet["vehicles"][sysid - 1]["tcp"]
    errors_before = wait_for(conn, "SYS_STATUS").errors_comm
    raw = socket.create_connection(("127.0.0.1", port), timeout=5)
    good = conn.mav.param_request_read_encode(sysid, 1, b"WP_SPEED", -1).pack(conn.mav)
    corrupt = bytearray(good)
    corrupt[-1] ^= 0xFF  # bad checksum
    raw.sendall(b"\x00garbage\xfd\xff\xff" + bytes(range(256)) + bytes(corrupt) + b"\xfe\x05junk")
    raw.close()  # and vanish mid-conversation
    wait_for(conn, "SYS_STATUS", lambda m: m.errors_comm > errors_before)
    # well-formed messages with nonsense values are refused, not fatal
    assert command_long(conn, sysid, 176, math.nan, math.nan) in (DENIED, FAILED)
    assert command_long(conn, sysid, 511, 33, math.inf) == DENIED
    assert command_long(conn, sysid, 178, 1, math.nan) == FAILED
    assert set_mode(conn, sysid, GUIDED) == ACCEPTED
    conn.mav.set_position_target_global_int_send(
        0, sysid, 1, 6, 0x0DC7, 0, 0, 0, math.nan, math.nan, 0, 0, 0, 0, 0, 0
    )
    wait_for(conn, "GLOBAL_POSITION_INT")
    barrier(conn, sysid)  # the original client is still served
    again = connect(f"tcp:127.0.0.1:{port}")
    again.mav.param_request_read_send(sysid, 1, b"WP_SPEED", -1)
    assert wait_for(again, "PARAM_VALUE", lambda m: m.param_id == "WP_SPEED").param_value == pytest.approx(
        MAX_SPEED
    )
    again.close()


def test_pseudo_terminal_serial_endpoint(fleet):
    vehicle = fleet["vehicles"][1]
    assert vehicle["serial"].startswith("/dev/")
    conn = connect(vehicle["serial"], baud=115200)
    hb = wait_for(conn, "HEARTBEAT")
    assert hb.get_srcSystem() == 2 and hb.type == 11
    # parameters round-trip over the serial link; a value no other test sets, since the boat's
    # earlier PARAM_VALUE broadcasts may still wait unread in the terminal's buffer
    conn.mav.param_set_send(2, 1, b"WP_RADIUS", 2.25, 9)
    wait_for(conn, "PARAM_VALUE", lambda m: m.param_id == "WP_RADIUS" and m.param_value == 2.25)
    conn.mav.param_set_send(2, 1, b"WP_RADIUS", 2.0, 9)
    conn.mav.param_request_read_send(2, 1, b"WP_RADIUS", -1)
    wait_for(conn, "PARAM_VALUE", lambda m: m.param_id == "WP_RADIUS" and m.param_value == 2.0)
    # TIMESYNC answers with the vehicle's (simulated) clock
    conn.mav.timesync_send(0, 123456789)
    reply = wait_for(conn, "TIMESYNC", lambda m: m.ts1 == 123456789)
    boot_ms = wait_for(conn, "GLOBAL_POSITION_INT").time_boot_ms
    assert 0 < reply.tc1 // 1_000_000 <= boot_ms  # ns against ms: compare whole milliseconds
    conn.close()


def test_udp_out_streams_and_takes_commands(fleet):
    conn = connect(f"udpin:127.0.0.1:{fleet['udp_port']}")  # vehicle 1 streams to the base port
    assert wait_for(conn, "HEARTBEAT").get_srcSystem() == 1
    conn.mav.param_request_read_send(1, 1, b"WP_SPEED", -1)
    assert wait_for(conn, "PARAM_VALUE", lambda m: m.param_id == "WP_SPEED").get_srcSystem() == 1
    conn.close()


def test_works_through_mavproxy(fleet, tmp_path):
    """A real MAVLink router between a GCS and the boat, as MAVLINK.md suggests testing against."""
    mavproxy = Path(sys.executable).with_name("mavproxy.py")
    if not mavproxy.exists():
        pytest.skip("MAVProxy is not installed in this environment")
    udp_port = _free_udp_port()
    router = subprocess.Popen(
        [
            sys.executable,
            str(mavproxy),
            "--master",
            f"tcp:127.0.0.1:{fleet['vehicles'][2]['tcp']}",
            "--out",
            f"udp:127.0.0.1:{udp_port}",
            "--daemon",
            "--non-interactive",
            "--state-basedir",
            str(tmp_path),
        ],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        conn = connect(f"udpin:127.0.0.1:{udp_port}")
        assert arm(conn, 3, on=False, force=True) == ACCEPTED
        assert set_mode(conn, 3, GUIDED) == ACCEPTED
        assert arm(conn, 3) == ACCEPTED
        hb = heartbeat_of(conn, 3, lambda m: m.base_mode & ARMED_FLAG)
        assert hb.custom_mode == GUIDED
        conn.close()
    finally:
        router.terminate()
        output = router.communicate(timeout=20)[0]
    assert "fence breach" not in output  # SYS_STATUS reads as a healthy autopilot to MAVProxy
