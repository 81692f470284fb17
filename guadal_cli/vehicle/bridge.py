"""The vehicle bridge: guadal's MQTT protocol on one side, one MAVLink autopilot on the other.

Three threads feed one queue: the MQTT channel (commands, planner status, already checked
and authenticated), the MAVLink reader (acks, arrivals) and the sensor worker (readings).
The main loop alone changes the bridge's state, so the protocol rules below are plain
sequential code. Which commands count is decided by :class:`~guadal_cli.channel.session.Follower`
(one planner session at a time, taken only from a signed ``start``; seq rules):

- ``goto``: geofence, plan a water-only path on the high-resolution graph, drive it waypoint by
  waypoint in GUIDED, ack ``accepted`` then ``reached`` (with the boat's position). A newer goto
  replaces the current one; a duplicate ``seq`` re-sends the ack of the state it is in; an
  older one is ignored and counted.
- ``measure``: read the sensor at the boat's position, publish a ``measurement``.
- ``hold``: HOLD mode. ``ping``: contact only (it never changes the last seq).
- No planner message for ``failsafe_timeout`` s, or the planner's last will: HOLD, status
  ``failsafe``. The next goto resumes.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from dataclasses import dataclass, field

from ..channel import protocol as messages
from ..channel.client import Channel
from ..channel.session import Follower
from ..errors import GuadalError
from ..fleet.track import TrackSampler
from ..maps.format import haversine_m
from .config import BridgeConfig
from .lowlevel import LowLevelPlanner, Waypoint
from .mavlink_link import (
    COMMAND_NAMES,
    MODE_GUIDED,
    MODE_HOLD,
    RESULT_NAMES,
    AutopilotLink,
    mavlink,
    mode_name,
)
from .sensors import SensorError

log = logging.getLogger("guadal.bridge")

MODE_RETRY_S = 1.5
WP_RADIUS_RETRY_S = 5.0  # PARAM_REQUEST_READ again until the autopilot answers  # re-ask for a mode that the heartbeat does not show yet
MODE_GIVE_UP = 8  # requests before a mode change is reported as failed
TARGET_RESEND_S = 2.0  # guided targets are not acknowledged: repeat them (idempotent)
STATUS_REFRESH_S = 15.0
LINK_LOST_S = 3.0  # autopilot heartbeats are 1 Hz: three missed ones mean the link is down
LOUD_DROPS = 5  # refused messages of one kind logged at WARNING; the rest at DEBUG (all are counted)
ARRIVAL_GATE_FACTOR = 4.0  # MISSION_ITEM_REACHED counts only this close (× radius) to the target

COUNTERS = (
    "bad_payload",
    "unsigned",
    "bad_signature",
    "foreign_session",
    "seq_ahead",
    "wrong_vehicle",
    "stale_seq",
    "duplicate_seq",
    "command_failed",
    "arm_failed",
    "mission_ack_error",
    "sensor_error",
    "rejected_goto",
    "failsafe",
)


@dataclass
class Goal:
    """One goto: its path, how far along it the boat is, and the last ack sent for it."""

    seq: int
    node: int
    lat: float
    lon: float
    session: str | None = None
    waypoints: list[Waypoint] = field(default_factory=list)
    index: int = 0
    status: str = "accepted"  # accepted | reached | rejected | failed
    reason: str | None = None
    reached_at: tuple[float, float] | None = None
    sent_at: float = 0.0  # monotonic time the current waypoint was last sent
    sent_position_count: int = -1  # position fixes seen when the current waypoint was first sent
    seen_guided: bool = False
    autopilot_reached: bool = False  # MISSION_ITEM_REACHED came for the current waypoint

    @property
    def active(self) -> bool:
        return self.status == "accepted"

    @property
    def waypoint(self) -> Waypoint:
        return self.waypoints[self.index]

    @property
    def final(self) -> bool:
        return self.index == len(self.waypoints) - 1


class Bridge:
    """One vehicle's bridge; :meth:`run` until ``stop`` is set."""

    def __init__(self, config: BridgeConfig, planner: LowLevelPlanner, link: AutopilotLink, sensor=None):
        self.config = config
        self.planner = planner
        self.link = link
        self.sensor = sensor
        self.vid = config.vehicle_id
        self.fleet = config.fleet
        self.events: queue.Queue = queue.Queue()
        self.stop = threading.Event()
        self.counters = {name: 0 for name in COUNTERS}
        self.state = "online"  # online | hold | failsafe
        self.failsafe_reason: str | None = None
        self.arm_error: str | None = None
        self.autopilot_text: str | None = None
        self.follower = Follower()
        self.last_kind: str | None = None
        self.goal: Goal | None = None  # the goto being driven, or the last one driven
        self.rejected: Goal | None = None  # the newest goto, when it was refused (for duplicates)
        self.last_reply: tuple[str, bytes] | None = None  # (channel, payload) answering the newest non-goto
        self.last_contact: float | None = None  # monotonic; None until the planner is first heard
        self.want_mode: int | None = None
        self.mode_requests = 0
        self.mode_requested_at = 0.0
        # A heartbeat confirms a wanted mode only if it left the autopilot after the last mode
        # command was handled (its COMMAND_ACK came first on the ordered link), or long enough after
        # it for a lost ack: an older one may show the mode from before a HOLD still on its way.
        self.mode_sent_at = float("-inf")
        self.mode_acked_at = float("-inf")
        self.want_armed = config.arm
        self.arm_requested_at = -1e9
        self._next_beat = 0.0
        self._next_telemetry = 0.0
        self._status_sent: dict | None = None
        self._status_at = 0.0
        self._sensor_jobs: queue.Queue = queue.Queue()
        self.link_lost = False
        self.wp_radius: float | None = None  # the autopilot's WP_RADIUS, once it has told us
        self._published_t: float | None = None  # autopilot clock of the last telemetry sent
        link.track_sampler = TrackSampler(config.track_rate)  # the GPS track, in the autopilot's time
        self._wp_radius_asked = -1e9
        self.topic_command = messages.topic(self.fleet, self.vid, "command")
        self.topic_planner = messages.topic(self.fleet, None, "status")
        self.mqtt = self._make_channel()

    # --- MQTT --------------------------------------------------------------------------------
    def _make_channel(self) -> Channel:
        """A clean session each time: commands queued for an earlier run are never replayed to
        the boat. What is published while the link is down is not lost either way: the planner
        re-sends anything unanswered (duplicates are harmless), and the channel re-subscribes
        on every reconnect, when this bridge re-publishes its status."""
        return Channel(
            self.config.endpoint(),
            fleet=self.fleet,
            client_id=f"guadal-bridge-{self.fleet.replace('/', '-')}-{self.vid}",
            inbox=self.events,
            subscriptions=[(self.topic_command, 1), (self.topic_planner, 1)],
            codec=messages.Codec(self.config.fleet_key()),
            will=(self._topic("status"), "status", {"state": "offline", "vehicle": self.vid}),
            max_reconnect_delay=5.0,
        )

    def _topic(self, channel: str) -> str:
        return messages.topic(self.fleet, self.vid, channel)

    def _publish(self, channel: str, payload: bytes, qos: int = 1, retain: bool = False):
        return self.mqtt.publish_payload(self._topic(channel), payload, qos=qos, retain=retain)

    def _encode(self, channel: str, kind: str, **fields) -> bytes:
        """A signed payload for one of this vehicle's topics, in the session it follows."""
        return self.mqtt.codec.encode(self._topic(channel), kind, **fields)

    # --- status --------------------------------------------------------------------------------
    def status_fields(self) -> dict:
        s = self.link.snapshot()
        return {
            "state": self.state,
            "vehicle": self.vid,
            "mode": s.mode,
            "armed": s.armed,
            "autopilot_link": "lost" if self.link_lost else "ok",
            "failsafe_reason": self.failsafe_reason,
            "arm_error": self.arm_error,
            "autopilot_text": self.autopilot_text,
            "goal": None
            if self.goal is None
            else {"seq": self.goal.seq, "node": self.goal.node, "status": self.goal.status},
            "session": self.follower.session,
            "last_seq": self.follower.last_seq,
            "counters": dict(self.counters),
        }

    def publish_status(self, force: bool = False) -> None:
        fields = self.status_fields()
        now = time.monotonic()
        if not force and fields == self._status_sent and now - self._status_at < STATUS_REFRESH_S:
            return
        self._status_sent, self._status_at = fields, now
        self._publish("status", self._encode("status", "status", **fields), retain=True)

    def count(self, name: str) -> None:
        self.counters[name] += 1

    # --- acks ------------------------------------------------------------------------------------
    def _ack_goal(self, goal: Goal) -> None:
        fields = {
            "session": goal.session,
            "seq": goal.seq,
            "status": goal.status,
            "command": "goto",
            "node": goal.node,
        }
        if goal.reason:
            fields["reason"] = goal.reason
        if goal.reached_at is not None:
            fields["lat"], fields["lon"] = goal.reached_at
        t = self.link.snapshot().time_boot_s
        if t is not None:
            fields["t"] = t
        self._publish("ack", self._encode("ack", "ack", **fields))

    def _ack(self, seq: int, kind: str, status: str, reason: str | None = None) -> bytes:
        fields = {"session": self.follower.session, "seq": seq, "status": status, "command": kind}
        if reason:
            fields["reason"] = reason
        payload = self._encode("ack", "ack", **fields)
        self._publish("ack", payload)
        return payload

    # --- commands ----------------------------------------------------------------------------------
    def drop(self, kind: str, sentence: str) -> None:
        """An unusable message, counted; the first few of each kind are logged at WARNING."""
        counter = {"malformed": "bad_payload", "topic": "bad_payload"}.get(kind, kind)
        self.count(counter)
        level = logging.WARNING if self.counters[counter] <= LOUD_DROPS else logging.DEBUG
        log.log(level, "ignored a message (%s, %d so far): %s", counter, self.counters[counter], sentence)
        self.publish_status()

    def _idle(self) -> bool:
        """In HOLD after a failsafe or a hold, nothing to drive: a new session may take the boat."""
        return self.state in ("failsafe", "hold") and not (self.goal is not None and self.goal.active)

    def handle_command(self, data: dict) -> None:
        if "vehicle" in data and data["vehicle"] != self.vid:
            self.count("wrong_vehicle")
            log.warning(
                "ignored a command: it names vehicle %r but came on the topic of vehicle %d.",
                data["vehicle"],
                self.vid,
            )
            self.publish_status()
            return
        seq, kind = data["seq"], data["type"]
        verdict, why = self.follower.judge(data, signed=self.mqtt.codec.signing, idle=self._idle())
        if verdict in ("stale", "ahead", "foreign"):
            counter = {"stale": "stale_seq", "ahead": "seq_ahead", "foreign": "foreign_session"}[verdict]
            self.count(counter)
            level = logging.WARNING if self.counters[counter] <= LOUD_DROPS else logging.DEBUG
            log.log(level, "ignored %s seq %d: %s.", kind, seq, why)
            self.publish_status()
            return
        self.last_contact = time.monotonic()
        if verdict == "contact":
            return
        if verdict == "duplicate":
            self.count("duplicate_seq")
            log.info("duplicate %s seq %d: repeating its answer", kind, seq)
            self._repeat_answer(kind, seq)
            self.publish_status()
            return
        if kind == "goto" and verdict == "new" and self.link.snapshot().lat is None:
            # just started: the autopilot's first position is on its way, and the planner sends
            # unanswered commands again; refusing now would end the boat's mission for nothing
            log.info("goto seq %d waits for the autopilot's first position", seq)
            return
        previous = self.follower.session
        self.follower.take(data)
        self.last_kind = kind
        if verdict == "adopt":
            if previous != data["session"]:
                log.info("following planner session %s (%s)", data["session"], why)
                if self.goal is not None and self.goal.active:
                    self.enter_hold()  # the old session's goal is nobody's now
            self.last_reply = ("ack", self._ack(seq, "start", "accepted"))
        elif kind == "goto":
            self.start_goto(data)
        elif kind == "measure":
            self.start_measure(data)
        elif kind == "hold":
            self.enter_hold()
            self.last_reply = ("ack", self._ack(seq, "hold", "accepted"))
        self.publish_status()

    def _repeat_answer(self, kind: str, seq: int) -> None:
        if kind != self.last_kind:
            log.warning(
                "seq %d was a %s, now it comes as a %s; answering nothing.", seq, self.last_kind, kind
            )
        elif kind == "goto":
            for goal in (self.goal, self.rejected):
                if goal is not None and goal.seq == seq:
                    self._ack_goal(goal)
        elif kind in ("start", "measure", "hold") and self.last_reply is not None:
            self._publish(*self.last_reply)

    def start_goto(self, data: dict) -> None:
        goal = Goal(
            seq=data["seq"],
            node=data["node"],
            lat=float(data["lat"]),
            lon=float(data["lon"]),
            session=data["session"],
        )
        s = self.link.snapshot()
        reason = self.planner.check_target(goal.node, goal.lat, goal.lon)
        if reason is None and not s.armed and not self.config.arm:
            reason = "the vehicle is disarmed (arm it, or start the bridge with --arm)."
        if reason is None:
            try:
                goal.waypoints = self.planner.plan(s.lat, s.lon, goal.lat, goal.lon)
            except GuadalError as exc:
                reason = str(exc)
        if reason is not None:
            # a refused goto changes nothing: a goto under way goes on
            goal.status, goal.reason = "rejected", reason
            self.rejected = goal
            self.count("rejected_goto")
            log.warning("rejected goto seq %d to node %d: %s", goal.seq, goal.node, reason)
            self._ack_goal(goal)
            return
        if self.goal is not None and self.goal.active:
            log.info("goto seq %d replaces seq %d", goal.seq, self.goal.seq)
        self.goal, self.rejected = goal, None
        log.info("goto seq %d to node %d: %d waypoint(s)", goal.seq, goal.node, len(goal.waypoints))
        self._ack_goal(goal)
        if self.state != "online":
            log.info("resuming from %s", self.state)
        self.state, self.failsafe_reason = "online", None
        if not s.armed and self.config.arm:
            self.want_armed, self.arm_requested_at = True, -1e9
        self.request_mode(MODE_GUIDED)
        self.drive()

    def start_measure(self, data: dict) -> None:
        s = self.link.snapshot()
        if self.sensor is None:
            self.last_reply = (
                "ack",
                self._ack(
                    data["seq"], "measure", "failed", "this bridge has no sensor (start it with --sensor)."
                ),
            )
            return
        if s.lat is None:
            self.last_reply = (
                "ack",
                self._ack(data["seq"], "measure", "failed", "the autopilot has not reported a position yet."),
            )
            return
        self.last_reply = None
        self._sensor_jobs.put((data["session"], data["seq"], data["node"], s.lat, s.lon, s.time_boot_s))

    def _sensor_worker(self) -> None:
        """Readings can block (a serial probe): they run here, not in the main loop."""
        while True:
            job = self._sensor_jobs.get()
            if job is None:
                return
            session, seq, node, lat, lon, t = job
            try:
                result = ("value", self.sensor.read(lat, lon))
            except SensorError as exc:
                result = ("error", str(exc))
            except Exception as exc:  # a third-party probe's bug must not stop the bridge
                result = ("error", f"sensor failed: {exc.__class__.__name__}: {exc}")
            self.events.put(("sensor", session, seq, node, lat, lon, t, result))

    def finish_measure(self, session, seq, node, lat, lon, t, result) -> None:
        kind, value = result
        if kind == "error":
            self.count("sensor_error")
            log.warning("measure seq %d failed: %s", seq, value)
            reply = ("ack", self._ack(seq, "measure", "failed", value))
        else:
            payload = self._encode(
                "measurement",
                "measurement",
                session=session,
                seq=seq,
                node=node,
                value=value,
                lat=lat,
                lon=lon,
                t=t,
                vehicle=self.vid,
            )
            self._publish("measurement", payload)
            reply = ("measurement", payload)
        if seq == self.follower.last_seq and session == self.follower.session:
            self.last_reply = reply

    # --- modes, arming, failsafe -------------------------------------------------------------------
    def request_mode(self, mode: int) -> None:
        self.want_mode = mode
        self.mode_requests = 0
        self.mode_requested_at = 0.0
        self._pursue_mode()

    def _pursue_mode(self) -> None:
        if self.want_mode is None:
            return
        s = self.link.snapshot()
        if s.custom_mode == self.want_mode and self._heartbeat_is_fresh(s):
            self.want_mode = None
            return
        now = time.monotonic()
        if now - self.mode_requested_at < MODE_RETRY_S:
            return
        if self.mode_requests >= MODE_GIVE_UP:
            reason = f"the autopilot did not enter {mode_name(self.want_mode)} after {self.mode_requests} requests (still {s.mode})."
            log.error(reason)
            if self.want_mode == MODE_GUIDED and self.goal is not None and self.goal.active:
                self.goal.status, self.goal.reason = "failed", reason
                self._ack_goal(self.goal)
            self.want_mode = None
            return
        self.link.set_mode(self.want_mode)
        self.mode_requests += 1
        self.mode_requested_at = self.mode_sent_at = now

    def _heartbeat_is_fresh(self, s) -> bool:
        acked = self.mode_acked_at >= self.mode_sent_at and s.last_heartbeat > self.mode_acked_at
        return acked or s.last_heartbeat > self.mode_sent_at + MODE_RETRY_S

    def enter_hold(self, state: str = "hold") -> None:
        if self.goal is not None and self.goal.active:
            why = f"the failsafe ({self.failsafe_reason})" if state == "failsafe" else "a hold command"
            self.goal.status, self.goal.reason = "failed", f"interrupted by {why}; vehicle in HOLD."
            self._ack_goal(self.goal)
        self.state = state
        self.request_mode(MODE_HOLD)

    def trigger_failsafe(self, reason: str) -> None:
        if self.state == "failsafe":
            return
        self.count("failsafe")
        self.failsafe_reason = reason
        mode = self.link.snapshot().custom_mode
        if mode in (MODE_GUIDED, MODE_HOLD) or (self.goal is not None and self.goal.active):
            log.warning("FAILSAFE: %s; vehicle to HOLD", reason)
            self.enter_hold("failsafe")
        else:
            # a pilot (MANUAL, ...) or another autopilot mode has the boat: not ours to stop
            log.warning(
                "FAILSAFE: %s; vehicle left in %s, which the bridge does not command", reason, mode_name(mode)
            )
            self.state = "failsafe"
        self.publish_status(force=True)

    def handle_planner_status(self, data: dict) -> None:
        if data.get("session") != self.follower.session:
            if self.follower.session is not None and data.get("session") is not None:
                log.debug(
                    "planner status of session %s, not %s: ignored",
                    data.get("session"),
                    self.follower.session,
                )
            return  # another run's planner (or a retained status from before): not ours to obey
        if data["state"] == "offline":
            if self.state == "hold":
                # a planner that ends cleanly holds every boat, then says goodbye: not a comms loss
                log.info("the planner went offline; vehicle already in HOLD")
                self.last_contact = None
            elif self.last_contact is not None:
                self.trigger_failsafe("the planner went offline")
        else:
            self.last_contact = time.monotonic()

    def _pursue_arming(self, now: float) -> None:
        s = self.link.snapshot()
        if s.armed:
            if self.arm_error:
                log.info("vehicle armed")
            self.arm_error = None
            # armed once is enough: whoever disarms later (a pilot, for safety) is not overruled;
            # a new goto asks again
            self.want_armed = False
            return
        if not self.want_armed or now - self.arm_requested_at < self.config.arm_retry_interval:
            return
        self.arm_requested_at = now
        self.link.arm()

    # --- MAVLink events ------------------------------------------------------------------------------
    def handle_mavlink(self, msg) -> None:
        kind = msg.get_type()
        if kind == "COMMAND_ACK":
            if msg.command == mavlink.MAV_CMD_DO_SET_MODE:
                self.mode_acked_at = time.monotonic()
            if msg.result in (mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_IN_PROGRESS):
                return
            if msg.command not in self.link.sent_commands:
                return  # another ground station's command, seen through a shared link
            name = COMMAND_NAMES.get(msg.command, str(msg.command))
            result = RESULT_NAMES.get(msg.result, str(msg.result))
            self.count("command_failed")
            log.warning("autopilot answered %s to %s", result, name)
            if msg.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
                self.count("arm_failed")
                detail = f" ({self.autopilot_text})" if self.autopilot_text else ""
                self.arm_error = f"the autopilot refused to arm: {result}{detail}; retrying every {self.config.arm_retry_interval:g} s."
                log.warning(self.arm_error)
        elif kind == "MISSION_ACK":
            if msg.type != mavlink.MAV_MISSION_ACCEPTED:
                self.count("mission_ack_error")
                log.warning("autopilot rejected the guided waypoint (MISSION_ACK %d)", msg.type)
                if self.goal is not None and self.goal.active:
                    self.goal.sent_at = 0.0  # resend at the next tick (GUIDED may not be on yet)
        elif kind == "MISSION_ITEM_REACHED":
            self._on_reached_message()
        elif kind == "GLOBAL_POSITION_INT":  # a fix the track sampler picked
            self.publish_telemetry(fix=msg)
        elif kind == "PARAM_VALUE":
            self._on_param(msg)
        elif kind == "STATUSTEXT":
            text = msg.text.strip() if isinstance(msg.text, str) else str(msg.text)
            if msg.severity <= mavlink.MAV_SEVERITY_WARNING:
                self.autopilot_text = text
                log.warning("autopilot: %s", text)
            else:
                log.info("autopilot: %s", text)

    def _on_param(self, msg) -> None:
        name = (
            msg.param_id.rstrip("\x00")
            if isinstance(msg.param_id, str)
            else msg.param_id.decode().rstrip("\x00")
        )
        if name != "WP_RADIUS" or not 0 < float(msg.param_value) < 1000:
            return
        radius, before = float(msg.param_value), self.wp_radius
        self.wp_radius = radius
        if radius != before and radius > self.config.arrival_radius:
            log.warning(
                "the autopilot's WP_RADIUS is %.1f m, larger than the bridge's arrival radius %.1f m: it stops "
                "up to %.1f m short, so its MISSION_ITEM_REACHED is accepted within %.1f m",
                radius,
                self.config.arrival_radius,
                radius,
                radius,
            )

    def _ask_wp_radius(self, now: float) -> None:
        """WP_RADIUS decides where the autopilot stops: ask until it answers (and after a reboot)."""
        if self.wp_radius is None and now - self._wp_radius_asked >= WP_RADIUS_RETRY_S:
            self._wp_radius_asked = now
            self.link.request_param("WP_RADIUS")

    def _on_reached_message(self) -> None:
        goal = self.goal
        if goal is None or not goal.active or goal.sent_position_count < 0:
            return
        s = self.link.snapshot()
        d = self._distance(s, goal.waypoint)
        gate = max(ARRIVAL_GATE_FACTOR * self.config.arrival_radius, 5.0)
        if d is None or d > gate:
            log.debug(
                "MISSION_ITEM_REACHED %.1f m from waypoint %d: taken as late, for an earlier target",
                d or -1,
                goal.index,
            )
            return
        goal.autopilot_reached = True
        if goal.final:
            self._check_arrival(s, reached_message=True)
        else:
            self._advance()

    # --- driving ---------------------------------------------------------------------------------------
    @staticmethod
    def _distance(s, wp: Waypoint) -> float | None:
        if s.lat is None:
            return None
        return float(haversine_m(s.lat, s.lon, wp.lat, wp.lon))

    def _send_waypoint(self) -> None:
        goal = self.goal
        wp = goal.waypoint
        if self.config.waypoint_command == "mission_item":
            self.link.guided_mission_item(wp.lat, wp.lon)
        else:
            self.link.position_target(wp.lat, wp.lon)
        if goal.sent_position_count < 0:
            goal.sent_position_count = self.link.snapshot().position_count
        goal.sent_at = time.monotonic()

    def _advance(self) -> None:
        goal = self.goal
        goal.index += 1
        goal.autopilot_reached = False
        goal.sent_position_count = -1
        goal.sent_at = 0.0
        log.debug("waypoint %d/%d", goal.index + 1, len(goal.waypoints))
        self.drive()

    def _check_arrival(self, s, reached_message: bool = False) -> None:
        goal = self.goal
        # only positions reported after the target went out count (no stale fix)
        if s.position_count <= goal.sent_position_count:
            return
        d = self._distance(s, goal.waypoint)
        if d is None:
            return
        # the autopilot says it arrived: within its own WP_RADIUS, which may be the larger one
        radius = self.config.arrival_radius
        if (reached_message or goal.autopilot_reached) and self.wp_radius is not None:
            radius = max(radius, self.wp_radius)
        if d <= radius:
            if not goal.final:
                self._advance()
                return
            goal.status, goal.reached_at = "reached", (s.lat, s.lon)
            log.info("goto seq %d reached node %d (%.2f m from the target)", goal.seq, goal.node, d)
            self.publish_telemetry()  # the fix the planner checks the ack against, sent first
            self._ack_goal(goal)
            self.publish_status()
        elif reached_message:
            log.info(
                "autopilot reports arrival %.1f m from the target; waiting to be within %.1f m", d, radius
            )

    def drive(self) -> None:
        """Advance the active goal: mode, target (re)sends, arrival."""
        goal = self.goal
        if goal is None or not goal.active:
            return
        s = self.link.snapshot()
        if s.custom_mode == MODE_GUIDED and self.want_mode is None:
            goal.seen_guided = True
        elif goal.seen_guided and self.want_mode is None:
            goal.status, goal.reason = (
                "failed",
                f"the vehicle left GUIDED (now {s.mode}); someone else has control.",
            )
            log.warning("goto seq %d: %s", goal.seq, goal.reason)
            self._ack_goal(goal)
            self.publish_status()
            return
        if s.custom_mode != MODE_GUIDED or not s.armed:
            return
        now = time.monotonic()
        if goal.sent_position_count < 0 or now - goal.sent_at >= TARGET_RESEND_S:
            self._send_waypoint()
        self._check_arrival(s)

    # --- main loop -------------------------------------------------------------------------------------
    def publish_telemetry(self, fix=None) -> None:
        """The vehicle's state; ``fix``: a GLOBAL_POSITION_INT the track sampler picked, sent as is.

        Telemetry never goes back in the autopilot's time: a picked fix that a newer periodic
        message overtook is skipped (the newer one stands for its period)."""
        s = self.link.snapshot()
        if fix is not None:
            s.lat, s.lon, s.time_boot_s = fix.lat / 1e7, fix.lon / 1e7, fix.time_boot_ms / 1000.0
        if s.lat is None or (self._published_t is not None and s.time_boot_s < self._published_t):
            return
        self._published_t = s.time_boot_s
        payload = self._encode(
            "telemetry",
            "telemetry",
            t=s.time_boot_s,
            lat=s.lat,
            lon=s.lon,
            heading=s.heading,
            speed=s.speed,
            mode=s.mode,
            armed=s.armed,
            battery=s.battery,
            vehicle=self.vid,
        )
        self._publish("telemetry", payload, qos=0)

    def request_streams(self) -> None:
        """Ask for the messages the bridge needs, faster than Rover's 1 Hz default (position at
        twice the track rate at least, so that every period of the track has a fix)."""
        position_hz = max(5.0, 2 * self.config.telemetry_hz, 2 * self.config.track_rate)
        for msg_id, hz in (
            (mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, position_hz),
            (mavlink.MAVLINK_MSG_ID_VFR_HUD, self.config.telemetry_hz),
            (mavlink.MAVLINK_MSG_ID_SYS_STATUS, 1.0),
        ):
            self.link.request_interval(msg_id, hz)

    def tick(self) -> None:
        now = time.monotonic()
        s = self.link.snapshot()
        if now >= self._next_beat:
            self.link.send_heartbeat()
            self._next_beat = now + 1.0
        lost = now - s.last_heartbeat > LINK_LOST_S
        if lost and not self.link_lost:
            log.warning("no heartbeat from the autopilot for %.0f s", now - s.last_heartbeat)
        elif self.link_lost and not lost:
            log.info("autopilot heard again; asking for its telemetry streams")
            self.request_streams()
            self.wp_radius = None  # it may have rebooted with other parameters
        self.link_lost = lost
        if (
            self.last_contact is not None
            and self.state != "failsafe"
            and now - self.last_contact > self.config.failsafe_timeout
        ):
            self.trigger_failsafe(f"no planner message for {self.config.failsafe_timeout:g} s")
        self._ask_wp_radius(now)
        self._pursue_mode()
        self._pursue_arming(now)
        self.drive()
        if now >= self._next_telemetry:
            self.publish_telemetry()
            self._next_telemetry = now + 1.0 / self.config.telemetry_hz
        self.publish_status()

    def dispatch(self, event) -> None:
        kind = event[0]
        if kind == "message":
            _, vehicle, channel, data = event
            if vehicle == self.vid and channel == "command":
                self.handle_command(data)
            elif vehicle is None and channel == "status":
                self.handle_planner_status(data)
        elif kind == "dropped":
            self.drop(event[1], event[2])
        elif kind == "mav":
            self.handle_mavlink(event[1])
        elif kind == "sensor":
            self.finish_measure(*event[1:])
        elif kind == "connected":
            log.info("connected to the broker %s as vehicle %d", self.mqtt.url, self.vid)
            self.publish_status(force=True)
        elif kind == "disconnected" and not self.stop.is_set():
            log.warning("lost the broker (%s); reconnecting", event[1])
        elif kind == "refused":
            log.error("%s (%s)", event[1], self.mqtt.url)

    def run(self) -> None:
        """Serve until :attr:`stop` is set; then publish ``offline`` and (optionally) HOLD."""
        self.link.on_event = lambda msg: self.events.put(("mav", msg))
        self.link.start()
        self.request_streams()
        if self.config.guided:
            self.request_mode(MODE_GUIDED)
        worker = threading.Thread(target=self._sensor_worker, name="sensor", daemon=True)
        if self.sensor is not None:
            worker.start()
        self.mqtt.start()
        try:
            while not self.stop.is_set():
                try:
                    event = self.events.get(timeout=0.05)
                except queue.Empty:
                    event = None
                try:
                    if event is not None:
                        self.dispatch(event)
                    self.tick()
                except Exception:  # keep the vehicle's bridge alive; the log says what broke
                    log.exception("internal error while handling %s", event[0] if event else "a tick")
        finally:
            self.shutdown()
            if self.sensor is not None:
                self._sensor_jobs.put(None)

    def shutdown(self) -> None:
        # only a boat the bridge drives (GUIDED) is stopped; a pilot's mode is left alone
        if self.config.hold_on_exit and self.link.snapshot().custom_mode == MODE_GUIDED:
            try:
                self.link.set_mode(MODE_HOLD)
            except Exception as exc:
                log.warning("could not send HOLD on exit: %s", exc)
        info = self._publish(
            "status", self._encode("status", "status", state="offline", vehicle=self.vid), retain=True
        )
        self.mqtt.close([info])
        self.link.close()
        if self.sensor is not None:
            self.sensor.close()
        log.info("bridge for vehicle %d stopped", self.vid)
