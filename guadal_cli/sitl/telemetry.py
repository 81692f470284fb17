"""What a boat reports and how often: the message builders and the per-vehicle rate table.

Rates are in simulated time, like SITL's: a 1 Hz stream at speed-up 50 is 50 messages per wall
second (the runner caps that, see ``server.py``, except for the position fixes of
``TRACK_MESSAGES``, which keep at least the track rate in simulated time so that a GPS track is
as dense at speed-up 200 as at 1).  Groups follow ArduPilot's stream groups so a
REQUEST_DATA_STREAM for EXTENDED_STATUS changes the same messages it would on a real autopilot.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from .modes import AUTOPILOT_MODES, HOLD, MANUAL_INPUT_MODES

if TYPE_CHECKING:
    from .vehicle import EmulatedBoat

HEARTBEAT = mavlink.MAVLINK_MSG_ID_HEARTBEAT
SYS_STATUS = mavlink.MAVLINK_MSG_ID_SYS_STATUS
SYSTEM_TIME = mavlink.MAVLINK_MSG_ID_SYSTEM_TIME
GPS_RAW_INT = mavlink.MAVLINK_MSG_ID_GPS_RAW_INT
ATTITUDE = mavlink.MAVLINK_MSG_ID_ATTITUDE
GLOBAL_POSITION_INT = mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT
NAV_CONTROLLER_OUTPUT = mavlink.MAVLINK_MSG_ID_NAV_CONTROLLER_OUTPUT
VFR_HUD = mavlink.MAVLINK_MSG_ID_VFR_HUD
POSITION_TARGET_GLOBAL_INT = mavlink.MAVLINK_MSG_ID_POSITION_TARGET_GLOBAL_INT
BATTERY_STATUS = mavlink.MAVLINK_MSG_ID_BATTERY_STATUS
AUTOPILOT_VERSION = mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION
HOME_POSITION = mavlink.MAVLINK_MSG_ID_HOME_POSITION

#: ArduPilot's stream groups (REQUEST_DATA_STREAM ids), restricted to what the emulator sends
STREAM_GROUPS = {
    mavlink.MAV_DATA_STREAM_EXTENDED_STATUS: (
        SYS_STATUS,
        GPS_RAW_INT,
        NAV_CONTROLLER_OUTPUT,
        POSITION_TARGET_GLOBAL_INT,
    ),
    mavlink.MAV_DATA_STREAM_POSITION: (GLOBAL_POSITION_INT,),
    mavlink.MAV_DATA_STREAM_EXTRA1: (ATTITUDE,),
    mavlink.MAV_DATA_STREAM_EXTRA2: (VFR_HUD,),
    mavlink.MAV_DATA_STREAM_EXTRA3: (SYSTEM_TIME, BATTERY_STATUS),
    mavlink.MAV_DATA_STREAM_RAW_SENSORS: (),
    mavlink.MAV_DATA_STREAM_RC_CHANNELS: (),
    mavlink.MAV_DATA_STREAM_RAW_CONTROLLER: (),
}
DEFAULT_INTERVAL_S = 1.0
#: the position fixes a GPS track is made of: the wall-rate cap never thins them below the track rate
TRACK_MESSAGES = (GLOBAL_POSITION_INT,)
#: position fixes may be sent this many times faster than the track rate (when asked), so that a
#: recorder sampling at the track rate always finds a fix younger than one interval
TRACK_OVERSAMPLING = 2.0
#: streamed from boot at 1 Hz (Rover's default rate for every group, and the heartbeat)
STREAMED_BY_DEFAULT = (HEARTBEAT,) + tuple(sorted({m for ids in STREAM_GROUPS.values() for m in ids}))
#: sent on request (REQUEST_MESSAGE) or when given an interval, never by default
ON_REQUEST = (AUTOPILOT_VERSION, HOME_POSITION)

SENSORS = (
    mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG
    | mavlink.MAV_SYS_STATUS_SENSOR_GPS
    | mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    | mavlink.MAV_SYS_STATUS_AHRS
    | mavlink.MAV_SYS_STATUS_SENSOR_BATTERY
    | mavlink.MAV_SYS_STATUS_PREARM_CHECK
)
CAPABILITIES = (
    mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
)


def stream_group(stream_id: int) -> tuple[int, ...] | None:
    """Message ids of a REQUEST_DATA_STREAM group; ALL (0) is every group; None if unknown."""
    if stream_id == mavlink.MAV_DATA_STREAM_ALL:
        return tuple(m for ids in STREAM_GROUPS.values() for m in ids)
    return STREAM_GROUPS.get(stream_id)


class StreamTable:
    """Per-vehicle message intervals in simulated seconds (None: not streamed)."""

    def __init__(self) -> None:
        self._interval: dict[int, float | None] = {m: DEFAULT_INTERVAL_S for m in STREAMED_BY_DEFAULT}
        self._interval.update({m: None for m in ON_REQUEST})
        self.listener: Callable[[int], None] | None = None

    def supports(self, msg_id: int) -> bool:
        return msg_id in self._interval

    def interval(self, msg_id: int) -> float | None:
        return self._interval.get(msg_id)

    def items(self):
        return self._interval.items()

    def set(self, msg_id: int, wanted: float | str | None) -> bool:
        """``wanted``: seconds, None to stop, or "default"; False for a message never sent."""
        if msg_id not in self._interval:
            return False
        if wanted == "default":
            wanted = DEFAULT_INTERVAL_S if msg_id in STREAMED_BY_DEFAULT else None
        self._interval[msg_id] = wanted
        if self.listener is not None:
            self.listener(msg_id)
        return True


def send_once(boat: EmulatedBoat, msg_id: int) -> bool:
    """Send message ``msg_id`` now if the boat has it to send; False for unsupported ids."""
    builder = _BUILDERS.get(msg_id)
    if builder is None:
        return False
    builder(boat)
    return True


def _heartbeat(boat: EmulatedBoat) -> None:
    base_mode = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    if boat.mode in AUTOPILOT_MODES:
        base_mode |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
    if boat.mode in MANUAL_INPUT_MODES:
        base_mode |= mavlink.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
    if boat.armed:
        base_mode |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    kind = mavlink.MAV_TYPE_SURFACE_BOAT if boat.is_boat else mavlink.MAV_TYPE_GROUND_ROVER
    status = mavlink.MAV_STATE_STANDBY if boat.mode == HOLD else mavlink.MAV_STATE_ACTIVE
    boat.mav.heartbeat_send(kind, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, base_mode, boat.mode, status, 3)


def _reported_position(boat: EmulatedBoat) -> tuple[int, int]:
    """lat/lon ×1e7 as the GPS reports them: the true position plus seeded noise."""
    east, north = boat.hull.east, boat.hull.north
    sigma = boat.config.gps_noise_m
    if sigma > 0:
        east += boat.rng.gauss(0.0, sigma)
        north += boat.rng.gauss(0.0, sigma)
    lat, lon = boat.frame.to_global(east, north)
    return int(round(lat * 1e7)), int(round(lon * 1e7))


def _course_cdeg(boat: EmulatedBoat) -> tuple[float, int]:
    ve, vn = boat.hull.ground_velocity()
    speed = math.hypot(ve, vn)
    course = (
        math.degrees(math.atan2(ve, vn)) % 360.0 if speed > 0.01 else math.degrees(boat.hull.heading) % 360.0
    )
    return speed, int(round(course * 100)) % 36000


def _heading_deg(boat: EmulatedBoat) -> float:
    return math.degrees(boat.hull.heading) % 360.0


def _global_position_int(boat: EmulatedBoat) -> None:
    lat, lon = _reported_position(boat)
    ve, vn = boat.hull.ground_velocity()
    hdg = int(round(_heading_deg(boat) * 100)) % 36000
    boat.mav.global_position_int_send(boat.time_boot_ms, lat, lon, 0, 0, int(vn * 100), int(ve * 100), 0, hdg)


def _gps_raw_int(boat: EmulatedBoat) -> None:
    lat, lon = _reported_position(boat)
    speed, cog = _course_cdeg(boat)
    h_acc = int(max(boat.config.gps_noise_m, 0.3) * 1000)
    boat.mav.gps_raw_int_send(
        int(boat.time_s * 1e6),
        mavlink.GPS_FIX_TYPE_3D_FIX,
        lat,
        lon,
        0,
        121,
        200,
        int(speed * 100),
        cog,
        10,
        0,
        h_acc,
        500,
        200,
        0,
        0,
    )


def _attitude(boat: EmulatedBoat) -> None:
    yaw = math.atan2(math.sin(boat.hull.heading), math.cos(boat.hull.heading))
    boat.mav.attitude_send(boat.time_boot_ms, 0.0, 0.0, yaw, 0.0, 0.0, boat.hull.yaw_rate)


def _vfr_hud(boat: EmulatedBoat) -> None:
    speed, _ = _course_cdeg(boat)
    limits = boat.hull.limits
    throttle = int(round(100 * boat.hull.speed / limits.max_speed)) if limits.max_speed > 0 else 0
    boat.mav.vfr_hud_send(boat.hull.speed, speed, int(_heading_deg(boat)) % 360, throttle, 0.0, 0.0)


def _nav_controller_output(boat: EmulatedBoat) -> None:
    """Only in autopilot modes, as Rover sends it."""
    if boat.mode not in AUTOPILOT_MODES:
        return
    goal = boat.goal
    if goal is None or goal.kind == "heading":
        dist, bearing = 0.0, 0.0 if goal is None else math.degrees(goal.heading)
    else:
        dist = boat.distance_to(goal.east, goal.north)
        bearing = math.degrees(boat.bearing_to(goal.east, goal.north))
    bearing = int(round(bearing)) % 360
    bearing = bearing - 360 if bearing > 180 else bearing
    boat.mav.nav_controller_output_send(
        0.0, 0.0, bearing, bearing, min(int(round(dist)), 65535), 0.0, 0.0, 0.0
    )


def _position_target_global_int(boat: EmulatedBoat) -> None:
    """Echo of the active target; nothing when the mode has no desired location."""
    goal = boat.goal
    if goal is None or goal.kind == "heading":
        return
    lat, lon = boat.frame.to_global(goal.east, goal.north)
    type_mask = 0xF000 | 0x0DF8  # Rover: position only (velocity, accel, yaw, yaw rate ignored)
    boat.mav.position_target_global_int_send(
        boat.time_boot_ms,
        mavlink.MAV_FRAME_GLOBAL,
        type_mask,
        int(round(lat * 1e7)),
        int(round(lon * 1e7)),
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
    )


def _battery(boat: EmulatedBoat) -> tuple[int, int, int]:
    """(millivolts, centiamps, percent) of a 4-cell pack sagging a little under load."""
    limits = boat.hull.limits
    load = boat.hull.speed / limits.max_speed if limits.max_speed > 0 else 0.0
    amps = boat.battery_current_a(load)
    remaining = boat.battery_remaining()
    volts = 14.0 + 2.8 * remaining / 100.0 - 0.05 * amps
    return int(volts * 1000), int(amps * 100), remaining


def _sys_status(boat: EmulatedBoat) -> None:
    mv, ca, pct = _battery(boat)
    bad = boat.counters["bad_packets"]
    # no fence is configured, and ArduPilot then reports the fence as healthy (never breached)
    health = SENSORS | mavlink.MAV_SYS_STATUS_GEOFENCE
    boat.mav.sys_status_send(SENSORS, SENSORS, health, 100, mv, ca, pct, 0, min(bad, 65535), 0, 0, 0, 0)


def _battery_status(boat: EmulatedBoat) -> None:
    mv, ca, pct = _battery(boat)
    cells = [mv // 4] * 4 + [65535] * 6
    boat.mav.battery_status_send(
        0,
        mavlink.MAV_BATTERY_FUNCTION_ALL,
        mavlink.MAV_BATTERY_TYPE_LIPO,
        32767,
        cells,
        ca,
        int(boat.consumed_mah),
        -1,
        pct,
    )


def _system_time(boat: EmulatedBoat) -> None:
    boat.mav.system_time_send(int((boat.epoch_s + boat.time_s) * 1e6), boat.time_boot_ms)


def _autopilot_version(boat: EmulatedBoat) -> None:
    boat.mav.autopilot_version_send(
        CAPABILITIES, 0, 0, 0, 0, b"\0" * 8, b"\0" * 8, b"\0" * 8, 0, 0, boat.sysid
    )


def _home_position(boat: EmulatedBoat) -> None:
    lat, lon = boat.config.home
    boat.mav.home_position_send(
        int(round(lat * 1e7)), int(round(lon * 1e7)), 0, 0.0, 0.0, 0.0, [1.0, 0, 0, 0], 0, 0, 0
    )


_BUILDERS: dict[int, Callable[[EmulatedBoat], None]] = {
    HEARTBEAT: _heartbeat,
    SYS_STATUS: _sys_status,
    SYSTEM_TIME: _system_time,
    GPS_RAW_INT: _gps_raw_int,
    ATTITUDE: _attitude,
    GLOBAL_POSITION_INT: _global_position_int,
    NAV_CONTROLLER_OUTPUT: _nav_controller_output,
    VFR_HUD: _vfr_hud,
    POSITION_TARGET_GLOBAL_INT: _position_target_global_int,
    BATTERY_STATUS: _battery_status,
    AUTOPILOT_VERSION: _autopilot_version,
    HOME_POSITION: _home_position,
}
