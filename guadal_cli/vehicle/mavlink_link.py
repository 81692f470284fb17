"""The MAVLink side of the bridge: one autopilot, its latest state, and the commands it takes.

A reader thread keeps :class:`VehicleState` current and hands every message the bridge acts on
(acks, arrivals, status texts) to a callback; sends happen on the caller's thread under a lock.
Everything here follows what ArduPilot Rover actually accepts (``MAVLINK.md`` in the design
notes): guided targets only in GUIDED with ``type_mask`` 0x0FF8, modes by number, commands
addressed to the vehicle's own system id.
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

os.environ["MAVLINK20"] = "1"  # before pymavlink is imported: ArduPilot speaks MAVLink 2

from pymavlink import mavutil  # noqa: E402

from ..errors import GuadalError  # noqa: E402
from ..fleet.track import TrackSampler  # noqa: E402

log = logging.getLogger("guadal.bridge")
mavlink = mavutil.mavlink

MODE_HOLD = 4
MODE_GUIDED = 15
MODE_NAMES = dict(mavutil.mode_mapping_rover)
#: SET_POSITION_TARGET_GLOBAL_INT mask: use position only, with the acceleration-ignore bits set
POSITION_TARGET_MASK = 0x0FF8
RESULT_NAMES = {k: v.name.replace("MAV_RESULT_", "") for k, v in mavlink.enums["MAV_RESULT"].items()}
COMMAND_NAMES = {k: v.name.replace("MAV_CMD_", "") for k, v in mavlink.enums["MAV_CMD"].items()}
#: messages whose arrival the bridge reacts to, beyond keeping the state current
EVENT_TYPES = {"COMMAND_ACK", "MISSION_ACK", "MISSION_ITEM_REACHED", "STATUSTEXT", "PARAM_VALUE"}


class _WriteGuard:
    """The write lock of a link, which also keeps a dead link from raising into the bridge.

    When the autopilot (or the router before it) goes away, pymavlink's writes raise
    (``BrokenPipeError``, or ``AttributeError`` while it reconnects). Such a write is dropped
    with one warning per outage: the bridge pursues modes and targets until the autopilot
    confirms them, so nothing is lost once the link is back.
    """

    def __init__(self, connection: str):
        self.connection = connection
        self._lock = threading.Lock()
        self.down = False

    def __enter__(self):
        self._lock.acquire()
        return self

    def __exit__(self, kind, exc, tb) -> bool:
        try:
            if exc is None:
                if self.down:
                    log.info("MAVLink writes to '%s' go through again", self.connection)
                self.down = False
                return False
            if isinstance(exc, (OSError, AttributeError)):
                if not self.down:
                    log.warning(
                        "MAVLink link '%s' is down (%s); writes dropped until it is back",
                        self.connection,
                        exc,
                    )
                self.down = True
                return True
            return False
        finally:
            self._lock.release()


def mode_name(number: int | None) -> str:
    if number is None:
        return "UNKNOWN"
    return MODE_NAMES.get(int(number), f"MODE{int(number)}")


@dataclass
class VehicleState:
    """The newest facts from the autopilot; ``None`` until first heard."""

    lat: float | None = None
    lon: float | None = None
    time_boot_s: float | None = None
    heading: float | None = None
    speed: float | None = None
    custom_mode: int | None = None
    armed: bool = False
    battery: float | None = None
    battery_voltage: float | None = None
    wp_dist: float | None = None
    position_count: int = 0
    last_heartbeat: float = field(default=0.0)  # monotonic

    @property
    def mode(self) -> str:
        return mode_name(self.custom_mode)


class AutopilotLink:
    """A pymavlink connection to one vehicle."""

    def __init__(
        self, connection: str, baud: int = 115200, source_system: int = 255, source_component: int = 191
    ):
        self.connection = connection
        try:
            self.master = mavutil.mavlink_connection(
                connection,
                baud=baud,
                source_system=source_system,
                source_component=source_component,
                autoreconnect=True,
            )
        except Exception as exc:  # pymavlink raises OSError, serial errors, ValueError...
            raise GuadalError(f"cannot open MAVLink connection '{connection}' ({exc}).") from exc
        self.state = VehicleState()
        self.target_system = 0
        self.target_component = 1
        self.on_event: Callable[[object], None] = lambda msg: None
        self._lock = _WriteGuard(connection)
        self._state_lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._start = time.monotonic()
        self.sent_commands: set[int] = set()  # command ids this bridge has sent (their acks are ours)
        # position fixes it picks become events (one per period of the autopilot's clock): the GPS track
        self.track_sampler: TrackSampler | None = None

    # --- connection ----------------------------------------------------------------------
    @staticmethod
    def _is_vehicle_heartbeat(msg) -> bool:
        return (
            msg.get_type() == "HEARTBEAT"
            and msg.type != mavlink.MAV_TYPE_GCS
            and msg.autopilot != mavlink.MAV_AUTOPILOT_INVALID
        )

    def wait_vehicle(self, timeout: float) -> None:
        """Block until a vehicle's heartbeat arrives; our own heartbeats open the route."""
        deadline = time.monotonic() + timeout
        next_beat = 0.0
        while time.monotonic() < deadline:
            if time.monotonic() >= next_beat:
                self.send_heartbeat()
                next_beat = time.monotonic() + 1.0
            try:
                msg = self.master.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5)
            except Exception as exc:
                raise GuadalError(f"MAVLink connection '{self.connection}' failed ({exc}).") from exc
            if msg is not None and self._is_vehicle_heartbeat(msg):
                self.target_system = msg.get_srcSystem()
                self.target_component = msg.get_srcComponent()
                self._update(msg)
                return
        raise GuadalError(
            f"no autopilot heartbeat on '{self.connection}' within {timeout:g} s; check the connection string, "
            "cable and baud rate."
        )

    def start(self) -> None:
        self._thread = threading.Thread(target=self._read_loop, name="mavlink-reader", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        try:
            self.master.close()
        except Exception:  # closing a dead link must not stop a clean exit
            pass

    def _read_loop(self) -> None:
        last_error = None
        while not self._stop.is_set():
            try:
                msg = self.master.recv_match(blocking=True, timeout=0.2)
            except Exception as exc:  # a garbled frame or a dropped link: keep listening
                if str(exc) != last_error:  # once per kind of error, not twice a second
                    log.warning("MAVLink read error on '%s': %s", self.connection, exc)
                    last_error = str(exc)
                self._stop.wait(0.5)
                continue
            last_error = None
            if msg is None:
                continue
            kind = msg.get_type()
            if kind == "BAD_DATA" or msg.get_srcSystem() != self.target_system:
                continue
            if kind == "HEARTBEAT" and not self._is_vehicle_heartbeat(msg):
                continue
            if kind in ("COMMAND_ACK", "MISSION_ACK") and not self._addressed_to_us(msg):
                continue  # behind a router, the answers to a ground station's commands pass by too
            self._update(msg)
            if kind in EVENT_TYPES:
                self.on_event(msg)
            elif (
                kind == "GLOBAL_POSITION_INT"
                and self.track_sampler is not None
                and self.track_sampler.take(msg.time_boot_ms / 1000.0)
            ):
                self.on_event(msg)

    def _addressed_to_us(self, msg) -> bool:
        system = getattr(msg, "target_system", 0) or 0
        component = getattr(msg, "target_component", 0) or 0
        me = self.master.mav
        return system in (0, me.srcSystem) and component in (0, me.srcComponent)

    def _update(self, msg) -> None:
        kind = msg.get_type()
        s = self.state
        with self._state_lock:
            if kind == "HEARTBEAT":
                s.custom_mode = int(msg.custom_mode)
                s.armed = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
                s.last_heartbeat = time.monotonic()
            elif kind == "GLOBAL_POSITION_INT":
                s.lat, s.lon = msg.lat / 1e7, msg.lon / 1e7
                s.time_boot_s = msg.time_boot_ms / 1000.0
                s.speed = math.hypot(msg.vx, msg.vy) / 100.0
                if msg.hdg != 65535:
                    s.heading = msg.hdg / 100.0
                s.position_count += 1
            elif kind == "VFR_HUD":
                s.speed = float(msg.groundspeed)
                s.heading = float(msg.heading)
            elif kind == "SYS_STATUS":
                s.battery = None if msg.battery_remaining < 0 else float(msg.battery_remaining)
                s.battery_voltage = (
                    None if msg.voltage_battery in (0, 65535) else msg.voltage_battery / 1000.0
                )
            elif kind == "NAV_CONTROLLER_OUTPUT":
                s.wp_dist = float(msg.wp_dist)

    def snapshot(self) -> VehicleState:
        with self._state_lock:
            return VehicleState(**self.state.__dict__)

    # --- commands ------------------------------------------------------------------------
    def _boot_ms(self) -> int:
        return int((time.monotonic() - self._start) * 1000) & 0xFFFFFFFF

    def send_heartbeat(self) -> None:
        with self._lock:
            self.master.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)

    def command_long(self, command: int, *params: float) -> None:
        p = list(params) + [0.0] * (7 - len(params))
        self.sent_commands.add(int(command))
        with self._lock:
            self.master.mav.command_long_send(self.target_system, self.target_component, command, 0, *p)

    def set_mode(self, custom_mode: int) -> None:
        self.command_long(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, custom_mode)

    def arm(self) -> None:
        self.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)

    def request_param(self, name: str) -> None:
        """PARAM_REQUEST_READ by name; the autopilot answers with PARAM_VALUE."""
        with self._lock:
            self.master.mav.param_request_read_send(
                self.target_system, self.target_component, name.encode(), -1
            )

    def request_interval(self, message_id: int, hz: float) -> None:
        self.command_long(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, message_id, 1e6 / hz)

    def position_target(self, lat: float, lon: float) -> None:
        with self._lock:
            self.master.mav.set_position_target_global_int_send(
                self._boot_ms(),
                self.target_system,
                self.target_component,
                mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                POSITION_TARGET_MASK,
                int(round(lat * 1e7)),
                int(round(lon * 1e7)),
                0.0,
                0,
                0,
                0,
                0,
                0,
                0,
                0,
                0,
            )

    def guided_mission_item(self, lat: float, lon: float) -> None:
        """A guided target that is acknowledged (MISSION_ACK), for links where that matters."""
        with self._lock:
            self.master.mav.mission_item_int_send(
                self.target_system,
                self.target_component,
                0,
                mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                mavlink.MAV_CMD_NAV_WAYPOINT,
                2,
                1,
                0,
                0,
                0,
                0,
                int(round(lat * 1e7)),
                int(round(lon * 1e7)),
                0.0,
                mavlink.MAV_MISSION_TYPE_MISSION,
            )
