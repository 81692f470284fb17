"""The one loop that owns a remote fleet's state (MAVProxy's habit, as the bridge has it).

Everything that changes the fleet arrives on one queue: the channel's events (messages already
authenticated and checked, drops, connection changes) and the fleet's own requests (issue a
goto, hold everyone...), which :meth:`FleetOwner.call` runs on the loop's thread. Between
events the loop keeps every bridge in touch: an unanswered command again, a session start
until the bridge follows this session, or a ``ping`` carrying the last seq (never a new one,
so a ping never makes an outstanding command look old). Other threads only read, under
:attr:`FleetOwner.cond`, and wait for a predicate with :meth:`FleetOwner.wait`.
"""

from __future__ import annotations

import logging
import math
import queue
import threading
import time
import uuid
from collections import Counter
from collections.abc import Callable
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout

from ...channel import protocol as msg
from ...channel.client import Channel
from ...channel.session import new_session_id
from ...graph import NavGraph
from ..track import TrackSampler
from .config import RemoteConfig
from .state import Command, RemoteVehicle

log = logging.getLogger("guadal.remote")

#: how many warnings of one kind are logged before the rest go to debug (they are all counted)
_LOUD_WARNINGS = 5
#: answers the protocol expects now and then (a re-sent command answered twice): debug only
EXPECTED_DROPS = {"stale", "duplicate"}


class FleetOwner:
    """The fleet's state and the only thread that changes it."""

    def __init__(self, graph: NavGraph, n_vehicles: int, config: RemoteConfig):
        self.graph = graph
        self.config = config
        self.session = new_session_id()
        self.vehicles = [
            RemoteVehicle(i, track_sampler=TrackSampler(config.track_rate)) for i in range(n_vehicles)
        ]
        self.dropped: Counter[str] = Counter()
        self.problems: list[str] = []
        self.controls: list[dict] = []
        self._control_ids: set[str] = set()
        self.cond = threading.Condition()
        self.connected = False
        self.last_connect_error = "no answer"
        self.inbox: queue.Queue = queue.Queue()
        fleet = config.fleet
        self.channel = Channel(
            config.endpoint(),
            fleet=fleet,
            client_id=config.client_id or f"guadal-planner-{uuid.uuid4().hex[:8]}",
            inbox=self.inbox,
            subscriptions=[
                (f"{fleet}/vehicle/+/ack", 1),
                (f"{fleet}/vehicle/+/measurement", 1),
                (f"{fleet}/vehicle/+/status", 1),
                (f"{fleet}/vehicle/+/telemetry", 0),
                (msg.topic(fleet, None, "control"), 1),
            ],
            codec=msg.Codec(config.fleet_key()),
            will=(msg.topic(fleet, None, "status"), "status", {"state": "offline", "session": self.session}),
            keepalive=config.keepalive,
        )
        self._thread = threading.Thread(target=self._serve, name="guadal-remote-fleet", daemon=True)

    # --- the loop ----------------------------------------------------------------------------
    def start(self) -> None:
        self.channel.start()
        self._thread.start()

    def stop(self) -> None:
        if self._thread.is_alive():
            self.inbox.put(("stop",))
            self._thread.join(10)

    def call(self, fn: Callable[[], object]):
        """Run ``fn`` on the loop's thread and return its result (or raise its exception)."""
        if not self._thread.is_alive():
            with self.cond:
                return fn()
        future: Future = Future()
        self.inbox.put(("call", fn, future))
        while True:
            try:
                return future.result(timeout=0.5)
            except FutureTimeout:
                if not self._thread.is_alive() and not future.done():  # stopped under our feet
                    with self.cond:
                        return fn()

    def wait(
        self,
        predicate: Callable[[], bool],
        timeout: float,
        tick: Callable[[], None] | None = None,
        every_s: float = 1.0,
    ) -> bool:
        """Wait until ``predicate()`` holds (True) or ``timeout`` passes (False); meanwhile call
        ``tick`` every ``every_s`` seconds on the waiting thread, without holding the state lock."""
        deadline = time.monotonic() + timeout
        next_tick = time.monotonic() + every_s
        while True:
            with self.cond:
                while not predicate():
                    now = time.monotonic()
                    if now >= deadline:
                        return False
                    if tick is not None and now >= next_tick:
                        break
                    self.cond.wait(min(deadline - now, next_tick - now if tick else 0.25, 0.25))
                else:
                    return True
            tick()
            next_tick = time.monotonic() + every_s

    def _serve(self) -> None:
        tick = self.config.ping_interval / 4
        while True:
            try:
                event = self.inbox.get(timeout=tick)
            except queue.Empty:
                event = None
            if event is not None and event[0] == "stop":
                self._drain_calls()
                return
            with self.cond:
                if event is not None:
                    self._dispatch(event)
                try:
                    self._keep_alive()
                except Exception as exc:  # a bug here must not stop the fleet
                    self._drop("error", f"keep-alive: {type(exc).__name__}: {exc}")
                self.cond.notify_all()

    def _drain_calls(self) -> None:
        """Requests that raced with stop still get an answer (run here, the loop's last act)."""
        while True:
            try:
                event = self.inbox.get_nowait()
            except queue.Empty:
                return
            if event[0] == "call":
                with self.cond:
                    self._dispatch(event)

    def _dispatch(self, event: tuple) -> None:
        kind = event[0]
        if kind == "call":
            _, fn, future = event
            try:
                future.set_result(fn())
            except BaseException as exc:
                future.set_exception(exc)
        elif kind == "message":
            try:
                self._on_message(*event[1:])
            except Exception as exc:  # a bug in a handler must not stop the fleet
                self._drop("error", f"{event[2]}: {type(exc).__name__}: {exc}")
        elif kind == "dropped":
            self._drop(event[1], event[2])
        elif kind == "connected":
            self._on_connected()
        elif kind == "disconnected":
            self.connected = False
            log.warning("lost the broker at %s (%s); reconnecting", self.channel.url, event[1])
        elif kind == "refused":
            self.last_connect_error = event[1]

    # --- connection ------------------------------------------------------------------------------
    def _on_connected(self) -> None:
        self.channel.send(
            msg.topic(self.config.fleet, None, "status"),
            "status",
            state="online",
            session=self.session,
            retain=True,
        )
        self.connected = True
        for v in self.vehicles:
            for cmd in (v.start, v.goto, v.measure):
                if cmd is not None and cmd.open:
                    self.send(v, cmd)
        log.info("connected to %s (session %s)", self.channel.url, self.session)

    # --- outgoing --------------------------------------------------------------------------------
    def send(self, v: RemoteVehicle, cmd: Command) -> None:
        cmd.sent_at = time.monotonic()
        self.channel.send(
            msg.topic(self.config.fleet, v.id, "command"),
            cmd.kind,
            session=self.session,
            seq=cmd.seq,
            **cmd.fields,
        )

    def issue(
        self, v: RemoteVehicle, kind: str, node: int = -1, count_distance: bool = True, **fields
    ) -> Command:
        """A new command with the next seq, recorded as outstanding and published."""
        if kind in ("goto", "measure"):
            fields = {"node": int(node), **fields}
        cmd = Command(
            seq=v.next_seq(),
            kind=kind,
            node=int(node),
            fields=fields,
            sent_at=time.monotonic(),
            from_node=v.node,
            count_distance=count_distance,
        )
        if kind in ("goto", "measure", "start"):
            setattr(v, kind, cmd)
        self.send(v, cmd)
        return cmd

    def start_session(self, v: RemoteVehicle) -> None:
        v.synced = False
        self.issue(v, "start")

    def _keep_alive(self) -> None:
        """Re-send unanswered commands, start sessions, ping the others; also lose vehicles
        whose bridge stayed offline too long. Every bridge hears from the planner at least every
        ``ping_interval`` seconds, which keeps its comms-loss failsafe quiet."""
        if not self.connected:
            return
        cfg = self.config
        now = time.monotonic()
        for v in self.vehicles:
            if v.away_since is not None and v.problem is None and now - v.away_since > cfg.offline_grace:
                self.vehicle_done(
                    v,
                    f"vehicle {v.id} went offline (its bridge stopped or lost the broker); "
                    "it takes no further part in the mission.",
                )
            if v.problem is not None:
                continue
            open_cmds = [c for c in (v.start, v.goto, v.measure) if c is not None and c.open]
            for cmd in open_cmds:
                if now - cmd.sent_at >= cfg.ping_interval:
                    self.send(v, cmd)
            last = max([v.last_ping] + [c.sent_at for c in (v.start, v.goto, v.measure) if c is not None])
            if not open_cmds and now - last >= cfg.ping_interval:
                if v.synced:
                    self.channel.send(
                        msg.topic(cfg.fleet, v.id, "command"), "ping", session=self.session, seq=v.seq
                    )
                else:
                    self.start_session(v)
                v.last_ping = now

    # --- incoming --------------------------------------------------------------------------------
    def _drop(self, kind: str, sentence: str) -> None:
        """Count an unusable message and say why (loudly for the first few of each kind)."""
        self.dropped[kind] += 1
        loud = kind not in EXPECTED_DROPS and self.dropped[kind] <= _LOUD_WARNINGS
        log.log(logging.WARNING if loud else logging.DEBUG, "ignored MQTT message: %s", sentence)

    def _on_message(self, vid: int | None, channel: str, data: dict) -> None:
        if vid is None:
            if channel == "control":
                return self._on_control(data)
            return  # our own status, echoed by a broker that matched it: nothing to do
        if not 0 <= vid < len(self.vehicles):
            return self._drop(
                "unknown_vehicle", f"vehicle {vid} is not in this fleet (0..{len(self.vehicles) - 1})."
            )
        if channel == "command":
            return self._drop("topic", f"vehicle {vid}: the planner does not take commands.")
        v = self.vehicles[vid]
        v.heard_at = time.monotonic()  # signed and checked by the channel: the link is alive
        if channel in ("ack", "measurement") and data["session"] != self.session:
            return self._drop(
                "foreign_session",
                f"vehicle {vid}: {channel} of session {data['session']}, not {self.session}.",
            )
        getattr(self, f"_on_{channel}")(v, data)

    @staticmethod
    def _clock(v: RemoteVehicle, data: dict) -> None:
        """Acks and measurements carry the vehicle's clock too: fresher than the last fix."""
        t = data.get("t")
        if (
            isinstance(t, (int, float))
            and not isinstance(t, bool)
            and math.isfinite(t)
            and (v.t is None or t > v.t)
        ):
            v.t = float(t)

    def _on_ack(self, v: RemoteVehicle, data: dict) -> None:
        seq, status = data["seq"], data["status"]
        if v.start is not None and v.start.seq == seq and data.get("command") == "start":
            if v.start.open and status == "accepted":
                v.start.status, v.synced = "answered", True
                self._reissue(v)
            return
        cmd = v.goto if v.goto is not None and v.goto.seq == seq else None
        if cmd is not None:
            self._clock(v, data)
        if cmd is not None and v.syncing and status == "reached" and "t" in data:
            v.syncing, v.t0 = False, v.t
            return
        if cmd is None:
            if v.measure is not None and v.measure.seq == seq:
                if status in ("rejected", "failed") and v.measure.open:
                    v.measure.status, v.measure.reason = status, str(data.get("reason") or "no reason given")
                    self.vehicle_done(
                        v, f"vehicle {v.id} could not measure at node {v.measure.node}: {v.measure.reason}"
                    )
                return  # an accepted measure is answered by a measurement
            kind = "stale" if seq <= v.seq else "unexpected_seq"
            return self._drop(
                kind, f"vehicle {v.id}: '{status}' ack for seq {seq}, which is not the current command."
            )
        if not cmd.open:
            return self._drop("duplicate", f"vehicle {v.id}: repeated '{status}' ack for seq {seq}.")
        if "node" in data and data["node"] != cmd.node:
            return self._drop(
                "mismatched_ack",
                f"vehicle {v.id}: '{status}' ack for seq {seq} names node {data['node']}, but that goto was to {cmd.node}.",
            )
        if status == "accepted":
            cmd.status = "accepted"
        elif status == "reached":
            self._claim_reached(v, cmd, data)
        else:  # rejected, failed
            cmd.status, cmd.reason = status, str(data.get("reason") or "no reason given")
            self.vehicle_done(v, f"vehicle {v.id} {status} the goto to node {cmd.node}: {cmd.reason}.")

    def _gap(self, node: int, lat: float, lon: float) -> float:
        x, y = self.graph.map.projection.to_xy(lat, lon)
        return math.hypot(float(x) - self.graph.x[node], float(y) - self.graph.y[node])

    def _claim_reached(self, v: RemoteVehicle, cmd: Command, data: dict) -> None:
        """Book a 'reached' ack only if its position and the vehicle's telemetry agree with it."""
        radius = self.config.arrival_radius
        lat, lon = data.get("lat"), data.get("lon")
        if not all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in (lat, lon)):
            return self._drop(
                "unconfirmed_reach", f"vehicle {v.id}: 'reached' ack for seq {cmd.seq} has no position."
            )
        gap = self._gap(cmd.node, lat, lon)
        if gap > radius:
            return self._drop(
                "unconfirmed_reach",
                f"vehicle {v.id}: 'reached' ack for node {cmd.node} places the boat {gap:.1f} m from it "
                f"(arrival radius {radius:g} m); waiting.",
            )
        cmd.claimed = data
        self._confirm(v, cmd)

    def _confirm(self, v: RemoteVehicle, cmd: Command) -> None:
        """Book the claimed arrival once the vehicle's own telemetry puts it within the arrival
        radius (the bridge sends a fix just before its ack); until then the claim waits, and each
        new fix is checked against it."""
        if v.fix is None or self._gap(cmd.node, *v.fix) > self.config.arrival_radius:
            if not cmd.waiting_fix:
                cmd.waiting_fix = True
                gap = (
                    "no fix yet"
                    if v.fix is None
                    else f"its last fix is {self._gap(cmd.node, *v.fix):.1f} m away"
                )
                self._drop(
                    "unconfirmed_reach",
                    f"vehicle {v.id}: 'reached' ack for node {cmd.node}, but {gap} "
                    f"(arrival radius {self.config.arrival_radius:g} m); waiting for its telemetry.",
                )
            return
        data = cmd.claimed
        cmd.status, cmd.reply, cmd.claimed = "reached", data, None
        if cmd.count_distance and cmd.from_node >= 0:
            v.distance += self.graph.distance(cmd.from_node, cmd.node)
        v.node = cmd.node

    def _reissue(self, v: RemoteVehicle) -> None:
        """After a (re)started session the bridge knows none of our open commands: send them anew."""
        for kind in ("goto", "measure"):
            cmd = getattr(v, kind)
            if cmd is not None and cmd.open:
                fresh = self.issue(
                    v,
                    kind,
                    cmd.node,
                    cmd.count_distance,
                    **{k: x for k, x in cmd.fields.items() if k != "node"},
                )
                fresh.from_node = cmd.from_node

    def _on_measurement(self, v: RemoteVehicle, data: dict) -> None:
        cmd = v.measure
        if cmd is None or cmd.seq != data["seq"]:
            return self._drop(
                "stale", f"vehicle {v.id}: measurement for seq {data['seq']}, which was not asked for now."
            )
        if not cmd.open:
            return self._drop("duplicate", f"vehicle {v.id}: repeated measurement for seq {data['seq']}.")
        self._clock(v, data)
        cmd.status, cmd.reply = "answered", data

    def _on_telemetry(self, v: RemoteVehicle, data: dict) -> None:
        t, lat, lon = float(data["t"]), float(data["lat"]), float(data["lon"])
        if v.fix_t is not None and t < v.fix_t:
            return self._drop(
                "stale", f"vehicle {v.id}: telemetry at t={t} is older than the last fix (t={v.fix_t})."
            )
        v.fix_t, v.fix = t, (lat, lon)
        self._clock(v, data)
        self._autopilot_state(v, data)
        if v.goto is not None and v.goto.open and v.goto.claimed is not None:
            self._confirm(v, v.goto)
        # the track keeps one fix per 1/track_rate seconds of the vehicle's clock, whatever the speed-up;
        # a fix taken before the mission's clock started (it can arrive after the start ack) is not in it
        if v.t0 is not None and t >= v.t0 and v.track_sampler.take(t):
            v.track.append({"vehicle": v.id, "lat": lat, "lon": lon, "time_s": t - v.t0})

    @staticmethod
    def _autopilot_state(v: RemoteVehicle, data: dict) -> None:
        """Mode, arming and battery where a telemetry or status message reports them (optional fields)."""
        mode, armed, battery = data.get("mode"), data.get("armed"), data.get("battery")
        if isinstance(mode, str) and mode:
            v.mode = mode[:40]
        if isinstance(armed, bool):
            v.armed = armed
        if "battery" in data:
            ok = (
                isinstance(battery, (int, float)) and not isinstance(battery, bool) and math.isfinite(battery)
            )
            v.battery = float(battery) if ok else None

    def _on_status(self, v: RemoteVehicle, data: dict) -> None:
        state, before = data["state"], v.state
        v.state = state
        if state != "offline":
            self._autopilot_state(v, data)
        if isinstance(data.get("counters"), dict):
            v.bridge_counters = {k: n for k, n in data["counters"].items() if isinstance(n, int) and n > 0}
        if state == "offline":
            if v.t0 is not None and v.away_since is None:
                v.away_since = time.monotonic()
                log.warning(
                    "vehicle %d went offline; waiting %g s for it to come back",
                    v.id,
                    self.config.offline_grace,
                )
            return
        v.away_since = None
        if state == "failsafe" and v.t0 is not None:
            self.vehicle_done(v, f"vehicle {v.id} entered failsafe; it takes no further part in the mission.")
            return
        if data.get("session") != self.session and v.synced:
            log.info(
                "vehicle %d follows session %s, not %s: starting ours again",
                v.id,
                data.get("session"),
                self.session,
            )
            self.start_session(v)
        elif before in ("unknown", "offline"):
            for cmd in (v.start, v.goto, v.measure):
                if cmd is not None and cmd.open:
                    self.send(v, cmd)  # it may have missed it while away

    def _on_control(self, data: dict) -> None:
        """An operator's signed control for this session, once (see ``pending_controls``)."""
        if data["session"] != self.session:
            return self._drop(
                "foreign_session", f"control for session {data['session']}, not {self.session}."
            )
        if data["id"] in self._control_ids:
            return self._drop("duplicate", f"control {data['id']} was already taken.")
        vehicle = data.get("vehicle")
        if data["action"] in ("hold", "release") and (
            not isinstance(vehicle, int) or isinstance(vehicle, bool) or not 0 <= vehicle < len(self.vehicles)
        ):
            return self._drop(
                "malformed",
                f"control '{data['action']}' needs field 'vehicle', one of 0..{len(self.vehicles) - 1} (got {vehicle!r}).",
            )
        self._control_ids.add(data["id"])
        self.controls.append({"action": data["action"], "vehicle": vehicle, "id": data["id"]})
        log.info("operator control: %s%s", data["action"], "" if vehicle is None else f" vehicle {vehicle}")

    def vehicle_done(self, v: RemoteVehicle, sentence: str) -> None:
        if v.problem is None:
            v.problem = sentence
            self.problems.append(sentence)
            log.warning("%s", sentence)
