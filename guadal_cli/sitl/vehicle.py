"""One emulated boat: the autopilot's modes, arming, guided targets, commands and parameters,
answering MAVLink the way ArduPilot Rover does for the subset in MAVLINK.md.

The vehicle never touches a socket: replies go out through ``mav`` (a pymavlink encoder whose
file is the vehicle's link), and time only moves when the runner calls :meth:`advance` with the
simulated clock.  That keeps every rule here testable and the timing in one place.
"""

from __future__ import annotations

import math
import random
import time
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from .modes import AUTO, ENTERABLE_MODES, GUIDED, LOITER, MANUAL, RTL, SMART_RTL, UNARMABLE_MODES
from .params import Param, apply_defaults, default_params
from .physics import MAX_SUBSTEP_S, GeoFrame, Hull, HullLimits
from .telemetry import StreamTable, send_once, stream_group

FORCE_ARM = 2989
POS_IGNORE = 0b111
VEL_IGNORE = 0b111 << 3
ACC_IGNORE = 0b111 << 6
YAW_IGNORE = 1 << 10
YAW_RATE_IGNORE = 1 << 11
GLOBAL_FRAMES = {
    mavlink.MAV_FRAME_GLOBAL,
    mavlink.MAV_FRAME_GLOBAL_INT,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
    mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT,
    mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
}
#: seconds without a new heading/speed target before guided gives up on it, as Rover does
ATTITUDE_TARGET_TIMEOUT_S = 3.0
BATTERY_CAPACITY_MAH = 10000.0


@dataclass
class VehicleConfig:
    sysid: int
    home: tuple[float, float]
    limits: HullLimits = field(default_factory=HullLimits)
    gps_noise_m: float = 0.0
    current_en: tuple[float, float] = (0.0, 0.0)
    seed: int = 0
    param_defaults: dict[str, float] = field(default_factory=dict)  # from --defaults and --model


@dataclass
class Goal:
    """Where the autopilot is steering: ``kind`` is wp (guided target), rtl, loiter or heading."""

    kind: str
    east: float = 0.0
    north: float = 0.0
    heading: float = 0.0
    speed: float = 0.0
    stamp: float = 0.0  # simulated time the goal was last set
    notify: bool = False  # send MISSION_ITEM_REACHED once on arrival (guided targets only)


class EmulatedBoat:
    """The autopilot state machine plus the hull it drives."""

    def __init__(self, config: VehicleConfig, mav: mavlink.MAVLink):
        self.config = config
        self.sysid = config.sysid
        self.mav = mav
        self.frame = GeoFrame(*config.home)
        self.hull = Hull(config.limits, config.current_en)
        self.params: dict[str, Param] = default_params(config.limits.max_speed)
        apply_defaults(self.params, config.param_defaults)
        self.rng = random.Random(config.seed * 1_000_003 + config.sysid)
        self.time_s = 0.0
        self.mode = MANUAL  # ArduPilot Rover's INITIAL_MODE default
        self.armed = False
        self.goal: Goal | None = None
        self.nav_speed = self.param("WP_SPEED")
        self.consumed_mah = 0.0
        self.counters = {"bad_packets": 0, "ignored": 0, "received": 0}
        self._statustext_id = 0
        self.streams = StreamTable()
        self.epoch_s = time.time()  # SYSTEM_TIME: Unix time when the simulated clock read 0

    # ---------------------------------------------------------------- helpers
    def param(self, name: str) -> float:
        return self.params[name].value

    @property
    def is_boat(self) -> bool:
        return int(self.param("FRAME_CLASS")) == 2

    @property
    def time_boot_ms(self) -> int:
        return int(self.time_s * 1000.0) & 0xFFFFFFFF

    def distance_to(self, east: float, north: float) -> float:
        return math.hypot(east - self.hull.east, north - self.hull.north)

    def bearing_to(self, east: float, north: float) -> float:
        return math.atan2(east - self.hull.east, north - self.hull.north)

    def statustext(self, text: str, severity: int = mavlink.MAV_SEVERITY_INFO) -> None:
        """Send text the way ArduPilot does: over 50 characters it goes in numbered chunks."""
        raw = text.encode("ascii", errors="replace")
        if len(raw) <= 50:
            self.mav.statustext_send(severity, raw, 0, 0)
            return
        self._statustext_id = self._statustext_id % 0xFFFF + 1
        for seq, start in enumerate(range(0, len(raw), 50)):
            self.mav.statustext_send(severity, raw[start : start + 50], self._statustext_id, seq)

    def _default_speed(self) -> float:
        wp_speed = self.param("WP_SPEED")
        return wp_speed if wp_speed > 0 else self.param("CRUISE_SPEED")

    def _hold_here(self) -> Goal | None:
        """What a vehicle does when it has nowhere to go: boats loiter, rovers stop."""
        if self.is_boat:
            return Goal("loiter", self.hull.east, self.hull.north, stamp=self.time_s)
        return None

    # ---------------------------------------------------------------- time
    def advance(self, t: float) -> None:
        """Integrate the boat and its autopilot up to simulated time ``t``."""
        while self.time_s < t:
            if self.hull.at_rest and not (self.armed and self.goal is not None):
                self._drain_battery(t - self.time_s)  # nothing moves: skip the integration
                self.time_s = t
                return
            dt = min(MAX_SUBSTEP_S, t - self.time_s)
            want_speed, want_heading = self._steer()
            self.hull.step(dt, want_speed, want_heading)
            self.time_s += dt
            self._drain_battery(dt)
            self._check_goal()

    def _steer(self) -> tuple[float, float | None]:
        goal = self.goal
        if not self.armed or goal is None:
            return 0.0, None
        if goal.kind == "heading":
            return goal.speed, goal.heading
        dist = self.distance_to(goal.east, goal.north)
        bearing = self.bearing_to(goal.east, goal.north)
        if goal.kind == "loiter":
            radius = self.param("LOIT_RADIUS")
            if dist <= radius:
                return 0.0, None
            return min(self.nav_speed, 0.5 * (dist - radius)), bearing
        # wp / rtl: full speed, slowing only as much as stopping at the point needs
        return min(self.nav_speed, math.sqrt(2.0 * self.hull.limits.max_decel * dist)), bearing

    def _check_goal(self) -> None:
        goal = self.goal
        if goal is None or not self.armed:
            return
        if goal.kind == "heading":
            if self.time_s - goal.stamp > ATTITUDE_TARGET_TIMEOUT_S:
                self.statustext("target not received last 3secs, stopping", mavlink.MAV_SEVERITY_WARNING)
                self.goal = self._hold_here()
            return
        if goal.kind in ("wp", "rtl") and self.distance_to(goal.east, goal.north) <= self.param("WP_RADIUS"):
            if goal.notify:
                self.mav.mission_item_reached_send(0)
            elif goal.kind == "rtl":
                self.statustext("Reached destination")
            self.goal = self._hold_here()

    def _drain_battery(self, dt: float) -> None:
        load = self.hull.speed / self.hull.limits.max_speed if self.hull.limits.max_speed > 0 else 0.0
        self.consumed_mah += self.battery_current_a(load) * dt / 3.6

    @staticmethod
    def battery_current_a(load: float) -> float:
        """Electronics draw plus a thruster current growing with the cube of speed."""
        return 0.3 + 6.0 * load**3

    def battery_remaining(self) -> int:
        return max(0, int(round(100.0 * (1.0 - self.consumed_mah / BATTERY_CAPACITY_MAH))))

    # ---------------------------------------------------------------- modes and arming
    def set_mode(self, number: int) -> bool:
        """Rover::set_mode: re-selecting the current mode is a no-op that succeeds."""
        if number == self.mode:
            return True
        if number not in ENTERABLE_MODES:
            self.statustext("Flight mode change failed", mavlink.MAV_SEVERITY_WARNING)
            return False
        self.mode = number
        if number == LOITER:
            self.nav_speed = self._default_speed()
            self.goal = Goal("loiter", self.hull.east, self.hull.north, stamp=self.time_s)
        elif number == GUIDED:
            self.nav_speed = self._default_speed()
            self.goal = self._hold_here()
        elif number in (RTL, SMART_RTL):
            rtl_speed = self.param("RTL_SPEED")
            self.nav_speed = rtl_speed if rtl_speed > 0 else self._default_speed()
            self.goal = Goal("rtl", 0.0, 0.0, stamp=self.time_s)
        else:
            self.goal = None
        return True

    def _set_mode_common(self, base_mode: int, custom_mode: int) -> int:
        if not base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return mavlink.MAV_RESULT_DENIED
        return mavlink.MAV_RESULT_ACCEPTED if self.set_mode(custom_mode) else mavlink.MAV_RESULT_FAILED

    def _arm_disarm(self, param1: float, param2: float) -> int:
        if param1 == 1.0:
            if self.armed:
                return mavlink.MAV_RESULT_ACCEPTED
            if self.mode in UNARMABLE_MODES and param2 != FORCE_ARM:
                self.statustext("PreArm: Mode not armable", mavlink.MAV_SEVERITY_CRITICAL)
                return mavlink.MAV_RESULT_FAILED
            self.armed = True
            self.statustext("Throttle armed")
            return mavlink.MAV_RESULT_ACCEPTED
        if param1 == 0.0:
            if self.armed:
                self.armed = False
                self.statustext("Throttle disarmed")
            return mavlink.MAV_RESULT_ACCEPTED
        return mavlink.MAV_RESULT_UNSUPPORTED

    def _change_speed(self, speed: float) -> int:
        """Rover takes a new speed only while GUIDED drives to a target, or in RTL/SMART_RTL
        (even after arriving home): loitering and stopped submodes have no speed to change."""
        goal = self.goal
        driving = self.mode in (RTL, SMART_RTL) or (
            self.mode == GUIDED and goal is not None and goal.kind == "wp"
        )
        if not driving or not math.isfinite(speed) or speed <= 0:
            return mavlink.MAV_RESULT_FAILED
        self.nav_speed = speed
        return mavlink.MAV_RESULT_ACCEPTED

    def set_guided_target(self, lat: float, lon: float) -> bool:
        """ModeGuided::set_desired_location: a new target replaces the old, arrival unsent."""
        if self.mode != GUIDED or not _valid_latlon(lat, lon):
            return False
        east, north = self.frame.to_local(lat, lon)
        self.goal = Goal("wp", east, north, stamp=self.time_s, notify=True)
        return True

    # ---------------------------------------------------------------- incoming MAVLink
    def handle(self, msg) -> None:
        """Act on one decoded message; anything not understood is counted and ignored."""
        self.counters["received"] += 1
        kind = msg.get_type()
        target = getattr(msg, "target_system", 0)
        if target not in (0, self.sysid):
            self.counters["ignored"] += 1
            return
        handler = getattr(self, f"_on_{kind.lower()}", None)
        if handler is None:
            self.counters["ignored"] += 1
            return
        handler(msg)

    def _ack(self, msg, command: int, result: int) -> None:
        self.mav.command_ack_send(command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())

    def _on_heartbeat(self, msg) -> None:
        """GCS heartbeats only keep the link alive."""

    def _on_timesync(self, msg) -> None:
        """Answer a time-sync request with the simulated clock, so the peer learns *its* offset."""
        if msg.tc1 == 0:
            self.mav.timesync_send(int(self.time_s * 1e9), msg.ts1)

    def _on_set_mode(self, msg) -> None:
        result = self._set_mode_common(msg.base_mode, msg.custom_mode)
        self._ack(msg, mavlink.MAVLINK_MSG_ID_SET_MODE, result)

    def _on_command_long(self, msg) -> None:
        if msg.command == mavlink.MAV_CMD_DO_REPOSITION:
            result = mavlink.MAV_RESULT_UNSUPPORTED  # needs COMMAND_INT: lat/lon do not fit floats
        else:
            result = self._command(msg, msg.command, (msg.param1, msg.param2, msg.param3, msg.param4))
        if result is not None:
            self._ack(msg, msg.command, result)

    def _on_command_int(self, msg) -> None:
        if msg.command == mavlink.MAV_CMD_DO_REPOSITION:
            result = self._reposition(msg)
        else:
            result = self._command(msg, msg.command, (msg.param1, msg.param2, msg.param3, msg.param4))
        if result is not None:
            self._ack(msg, msg.command, result)

    def _command(self, msg, command: int, p: tuple[float, float, float, float]) -> int | None:
        if command == mavlink.MAV_CMD_DO_SET_MODE:
            return self._set_mode_common(_as_int(p[0]), _as_int(p[1]))
        if command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            return self._arm_disarm(p[0], p[1])
        if command == mavlink.MAV_CMD_DO_CHANGE_SPEED:
            return self._change_speed(p[1])
        if command == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return mavlink.MAV_RESULT_ACCEPTED if self.set_mode(RTL) else mavlink.MAV_RESULT_FAILED
        if command == mavlink.MAV_CMD_MISSION_START:
            return mavlink.MAV_RESULT_ACCEPTED if self.set_mode(AUTO) else mavlink.MAV_RESULT_FAILED
        if command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            interval_us = p[1]
            if not math.isfinite(interval_us):
                return mavlink.MAV_RESULT_DENIED
            if interval_us < 0:
                wanted = None
            elif interval_us == 0:
                wanted = "default"
            else:
                wanted = interval_us / 1e6
            ok = self.streams.set(_as_int(p[0]), wanted)
            if not ok:
                self.statustext(f"No ap_message for mavlink id ({_as_int(p[0])})")
            return mavlink.MAV_RESULT_ACCEPTED if ok else mavlink.MAV_RESULT_DENIED
        if command == mavlink.MAV_CMD_GET_MESSAGE_INTERVAL:
            return self._send_message_interval(_as_int(p[0]))
        if command == mavlink.MAV_CMD_REQUEST_MESSAGE:
            return (
                mavlink.MAV_RESULT_ACCEPTED if send_once(self, _as_int(p[0])) else mavlink.MAV_RESULT_DENIED
            )
        if command == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            send_once(self, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
            return mavlink.MAV_RESULT_ACCEPTED
        return mavlink.MAV_RESULT_UNSUPPORTED

    def _send_message_interval(self, msg_id: int) -> int:
        if not self.streams.supports(msg_id):
            return mavlink.MAV_RESULT_DENIED
        seconds = self.streams.interval(msg_id)
        self.mav.message_interval_send(msg_id, -1 if seconds is None else int(seconds * 1e6))
        return mavlink.MAV_RESULT_ACCEPTED

    def _reposition(self, msg) -> int:
        """GCS_MAVLINK_Rover::handle_command_int_do_reposition, step for step."""
        change_mode = _as_int(msg.param2) & mavlink.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE
        if self.mode != GUIDED and not change_mode:
            return mavlink.MAV_RESULT_DENIED
        lat, lon = msg.x / 1e7, msg.y / 1e7
        if not _valid_latlon(lat, lon) or (msg.x == 0 and msg.y == 0) or msg.frame not in GLOBAL_FRAMES:
            return mavlink.MAV_RESULT_DENIED
        if self.mode != GUIDED and not self.set_mode(GUIDED):
            return mavlink.MAV_RESULT_FAILED
        if msg.param1 > 0 and self._change_speed(msg.param1) != mavlink.MAV_RESULT_ACCEPTED:
            return mavlink.MAV_RESULT_FAILED
        return mavlink.MAV_RESULT_ACCEPTED if self.set_guided_target(lat, lon) else mavlink.MAV_RESULT_FAILED

    def _on_set_position_target_global_int(self, msg) -> None:
        """No ACK either way: a GCS learns the outcome from POSITION_TARGET_GLOBAL_INT."""
        if self.mode != GUIDED or msg.coordinate_frame not in GLOBAL_FRAMES:
            return
        mask = msg.type_mask
        lat, lon = msg.lat_int / 1e7, msg.lon_int / 1e7
        if not mask & POS_IGNORE and not _valid_latlon(lat, lon):
            return
        if not mask & ACC_IGNORE:
            self.statustext("Ignoring SET_POSITION_TARGET_GLOBAL_INT; set ACC_IGNORE in mask")
            return
        if not mask & POS_IGNORE:
            self.set_guided_target(lat, lon)
            return
        if not all(math.isfinite(v) for v in (msg.vx, msg.vy, msg.yaw)):
            return
        if not mask & VEL_IGNORE and mask & YAW_RATE_IGNORE:
            speed = min(math.hypot(msg.vx, msg.vy), self._default_speed())
            heading = math.atan2(msg.vy, msg.vx) if mask & YAW_IGNORE else msg.yaw
            self.goal = Goal("heading", heading=heading, speed=speed, stamp=self.time_s)
        elif mask & VEL_IGNORE and not mask & YAW_IGNORE and mask & YAW_RATE_IGNORE:
            self.goal = Goal("heading", heading=msg.yaw, speed=0.0, stamp=self.time_s)

    def _on_mission_item_int(self, msg) -> None:
        if msg.mission_type != mavlink.MAV_MISSION_TYPE_MISSION or msg.current != 2:
            # mission upload is not emulated; a stray item is refused rather than ignored
            result = mavlink.MAV_MISSION_UNSUPPORTED
        elif msg.command != mavlink.MAV_CMD_NAV_WAYPOINT or msg.frame not in GLOBAL_FRAMES:
            result = mavlink.MAV_MISSION_UNSUPPORTED
        elif self.set_guided_target(msg.x / 1e7, msg.y / 1e7):
            result = mavlink.MAV_MISSION_ACCEPTED
        else:
            result = mavlink.MAV_MISSION_ERROR
        self.mav.mission_ack_send(msg.get_srcSystem(), msg.get_srcComponent(), result, msg.mission_type)

    def _on_mission_request_list(self, msg) -> None:
        """An empty mission (only home, as item 0) so ground stations finish their sync."""
        count = 1 if msg.mission_type == mavlink.MAV_MISSION_TYPE_MISSION else 0
        self.mav.mission_count_send(msg.get_srcSystem(), msg.get_srcComponent(), count, msg.mission_type)

    def _on_mission_request_int(self, msg) -> None:
        if msg.mission_type != mavlink.MAV_MISSION_TYPE_MISSION or msg.seq != 0:
            self.mav.mission_ack_send(
                msg.get_srcSystem(),
                msg.get_srcComponent(),
                mavlink.MAV_MISSION_INVALID_SEQUENCE,
                msg.mission_type,
            )
            return
        lat, lon = self.config.home
        self.mav.mission_item_int_send(
            msg.get_srcSystem(),
            msg.get_srcComponent(),
            0,
            mavlink.MAV_FRAME_GLOBAL,
            mavlink.MAV_CMD_NAV_WAYPOINT,
            0,
            1,
            0,
            0,
            0,
            0,
            int(round(lat * 1e7)),
            int(round(lon * 1e7)),
            0.0,
            msg.mission_type,
        )

    def _on_mission_ack(self, msg) -> None:
        """End of a mission download."""

    def _on_request_data_stream(self, msg) -> None:
        ids = stream_group(msg.req_stream_id)
        if ids is None:
            self.counters["ignored"] += 1
            return
        off = msg.start_stop == 0 or msg.req_message_rate == 0
        for msg_id in ids:
            self.streams.set(msg_id, None if off else 1.0 / msg.req_message_rate)

    # ---------------------------------------------------------------- parameters
    def _send_param(self, name: str) -> None:
        names = list(self.params)
        p = self.params[name]
        self.mav.param_value_send(name.encode(), p.value, p.kind, len(names), names.index(name))

    def _on_param_request_read(self, msg) -> None:
        name = _param_name(msg.param_id)
        if msg.param_index >= 0:
            names = list(self.params)
            if msg.param_index >= len(names):
                return
            name = names[msg.param_index]
        if name in self.params:
            self._send_param(name)

    def _on_param_request_list(self, msg) -> None:
        for name in self.params:
            self._send_param(name)

    def _on_param_set(self, msg) -> None:
        """Unknown names and non-finite values are dropped without a reply, as ArduPilot does."""
        name = _param_name(msg.param_id)
        if name not in self.params or not math.isfinite(msg.param_value):
            return
        p = self.params[name]
        p.value = p.coerce(msg.param_value)
        self._send_param(name)


def _as_int(value: float) -> int:
    """A float command parameter as an integer; NaN or infinity become -1 (never valid)."""
    return int(value) if math.isfinite(value) else -1


def _param_name(raw) -> str:
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", errors="replace")
    return raw.split("\x00", 1)[0]


def _valid_latlon(lat: float, lon: float) -> bool:
    return -90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0
