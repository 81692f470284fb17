"""The remote fleet: the Fleet contract spoken over MQTT to one bridge per vehicle.

The runner drives it exactly as it drives the local fleet, one hop at a time, so the planner
sees the same nodes at every level. Each hop is a ``goto`` with a fresh ``seq`` per vehicle;
the vehicle's node changes only on the ``reached`` ack echoing that seq, and the distance added
is the graph length of the hop, so ``distances`` agree with ``sim`` to the metre.

Reliability rests on the seq rule the bridges implement: a duplicate seq is answered again with
the current state. So every outstanding command is simply sent again after a reconnect, when a
vehicle comes back online, and every ``ping_interval`` seconds until answered; stale and
duplicate answers are counted and ignored. Those re-sends also keep the bridges' comms-loss
failsafe quiet; a vehicle with nothing outstanding gets a ``ping`` instead (with a fresh seq,
so it can never make an outstanding command look stale). Anything unusable that arrives (bad JSON, unknown
type, unknown vehicle) is logged, counted in :attr:`RemoteFleet.dropped` and never stops a
mission. A vehicle that goes offline, enters failsafe or refuses a goto is *done*, with a
sentence in :attr:`RemoteFleet.problems` saying why.
"""

from __future__ import annotations

import logging
import math
import os
import ssl
import threading
import time
import uuid
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal

import paho.mqtt.client as mqtt
from pydantic import BaseModel, ConfigDict, Field

from ..errors import GuadalError
from ..graph import NavGraph
from . import messages as msg
from .base import Fleet, Measurement, Sensor

log = logging.getLogger("guadal.remote")

#: how many warnings of one kind are logged before the rest go to debug (they are all counted)
_LOUD_WARNINGS = 5
#: answers the protocol expects now and then (a re-sent command answered twice): debug only
_EXPECTED_DROPS = {"stale", "duplicate"}


# --- configuration -------------------------------------------------------------------------
class RemoteConfig(BaseModel):
    """Settings shared by the ``sitl`` and ``real`` backends."""

    model_config = ConfigDict(extra="forbid")
    level: str
    host: str = Field(default="127.0.0.1", description="MQTT broker host name or address.")
    port: int = Field(default=1883, ge=1, le=65535, description="MQTT broker port (8883 is usual with TLS).")
    username: str | None = Field(default=None, description="Broker user name.")
    password: str | None = Field(default=None, description="Broker password (prefer password_env).")
    password_env: str | None = Field(
        default=None, description="Environment variable holding the broker password."
    )
    tls: bool = Field(default=False, description="Connect with TLS.")
    ca_file: str | None = Field(
        default=None, description="CA certificate file for TLS; default: the system's."
    )
    client_id: str | None = Field(default=None, description="MQTT client id; default: a unique one per run.")
    keepalive: int = Field(default=10, ge=1, le=3600, description="MQTT keepalive, seconds.")
    fleet: str = Field(
        default="guadal", min_length=1, description="Topic prefix shared with the bridges (--fleet)."
    )
    measurements: Literal["synthetic", "vehicle"] = Field(
        default="synthetic", description="synthetic: the environment's sensor; vehicle: ask each bridge."
    )
    connect_timeout: float = Field(
        default=20.0, gt=0, description="Seconds to reach the broker and see every vehicle online."
    )
    reset_timeout: float = Field(
        default=300.0, gt=0, description="Seconds for the vehicles to reach their start nodes."
    )
    hop_timeout: float = Field(default=60.0, gt=0, description="Seconds for one hop (one graph edge).")
    measure_timeout: float = Field(default=30.0, gt=0, description="Seconds for a measurement to come back.")
    ping_interval: float = Field(
        default=1.0,
        gt=0,
        description="Seconds between messages to each bridge: its unanswered command again, or a ping.",
    )

    def broker_password(self) -> str | None:
        if self.password_env:
            value = os.environ.get(self.password_env)
            if value is None:
                raise GuadalError(
                    f"backend.password_env: environment variable '{self.password_env}' is not set."
                )
            return value
        return self.password


# --- per-vehicle state ---------------------------------------------------------------------
@dataclass
class Command:
    """One command in flight: what was sent, and what came back."""

    seq: int
    kind: str
    payload: bytes
    node: int
    sent_at: float
    status: str = "sent"  # sent, accepted, reached, rejected, failed, answered
    reason: str = ""
    reply: dict | None = None
    from_node: int = -1
    count_distance: bool = True

    @property
    def open(self) -> bool:
        return self.status in ("sent", "accepted")


@dataclass
class RemoteVehicle:
    """What the planner knows of one remote vehicle: node, distance, clock, link state."""

    id: int
    node: int = -1
    distance: float = 0.0
    state: str = "unknown"  # the bridge's retained status
    problem: str | None = None  # why this vehicle is done, if it is
    goto: Command | None = None
    measure: Command | None = None
    seq: int = 0
    t: float | None = None  # latest reading of the vehicle's clock (telemetry, acks, measurements)
    fix_t: float | None = None  # clock of the latest GPS fix
    t0: float | None = None  # the vehicle's clock at the end of reset
    syncing: bool = False  # waiting for a fresh clock reading to set t0
    fix: tuple[float, float] | None = None
    track: list[dict] = field(default_factory=list)

    def next_seq(self) -> int:
        self.seq += 1
        return self.seq


# --- the fleet -----------------------------------------------------------------------------
class RemoteFleet(Fleet):
    """N vehicles behind MQTT bridges, driven hop by hop like the local fleet."""

    def __init__(
        self,
        graph: NavGraph,
        n_vehicles: int,
        max_distance: float,
        sensor: Sensor | None,
        config: RemoteConfig,
        on_close: Callable[[], None] | None = None,
    ):
        self.graph = graph
        self.n_vehicles = int(n_vehicles)
        self.config = config
        self.sensor = sensor
        self._max_distance = float(max_distance)
        self._on_close = on_close
        # seqs start from the wall clock in microseconds, so a new run never looks stale to a
        # bridge that is still running from the previous one
        start = time.time_ns() // 1000
        self.vehicles = [RemoteVehicle(i, seq=start) for i in range(self.n_vehicles)]
        self.dropped: Counter[str] = Counter()
        self.problems: list[str] = []
        self._cond = threading.Condition()
        self._send_lock = threading.RLock()  # a seq is allocated and published in one step
        self._stop = threading.Event()
        self._connected = False
        self._last_connect_error = "no answer"
        self._closed = False
        self._client = self._make_client()
        self._keeper = threading.Thread(target=self._keep_alive, name="guadal-remote-keeper", daemon=True)
        self._started = False

    # --- connection ------------------------------------------------------------------------
    @property
    def broker_url(self) -> str:
        return f"mqtt{'s' if self.config.tls else ''}://{self.config.host}:{self.config.port}"

    def _make_client(self) -> mqtt.Client:
        cfg = self.config
        client_id = cfg.client_id or f"guadal-planner-{uuid.uuid4().hex[:8]}"
        client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, clean_session=True)
        if cfg.username is not None:
            client.username_pw_set(cfg.username, cfg.broker_password())
        if cfg.tls:
            try:
                client.tls_set(ca_certs=cfg.ca_file, cert_reqs=ssl.CERT_REQUIRED)
            except (OSError, ssl.SSLError, ValueError) as exc:
                raise GuadalError(
                    f"backend.ca_file: cannot load the CA certificate '{cfg.ca_file}' ({exc})."
                ) from exc
        client.will_set(
            msg.topic(cfg.fleet, None, "status"), msg.encode("status", state="offline"), qos=1, retain=True
        )
        client.reconnect_delay_set(min_delay=0.1, max_delay=2)
        client.max_inflight_messages_set(100)
        client.on_connect = self._on_connect
        client.on_disconnect = self._on_disconnect
        client.on_connect_fail = self._on_connect_fail
        client.on_message = self._on_message
        return client

    def connect(self) -> None:
        """Reach the broker and wait until every vehicle's bridge says it is online."""
        if self._started:
            return
        self._started = True
        try:
            self._client.connect_async(self.config.host, self.config.port, keepalive=self.config.keepalive)
        except (OSError, ValueError) as exc:
            raise GuadalError(f"cannot connect to the MQTT broker at {self.broker_url}: {exc}.") from exc
        self._client.loop_start()
        self._keeper.start()
        timeout = self.config.connect_timeout
        if not self._wait(lambda: self._connected, timeout):
            raise GuadalError(
                f"cannot reach the MQTT broker at {self.broker_url} within {timeout:g} s "
                f"({self._last_connect_error}); is it running, and are backend.host/port right?"
            )
        # a bridge is ready when its status is not offline (a failsafe from an earlier run ends with
        # the first goto) and it reports a position
        silent = lambda: [v.id for v in self.vehicles if v.state in ("unknown", "offline")]  # noqa: E731
        if not self._wait(lambda: not silent(), timeout):
            ids = silent()
            raise GuadalError(
                f"vehicle{'s' if len(ids) > 1 else ''} {', '.join(map(str, ids))} not online on {self.broker_url} "
                f"within {timeout:g} s (no live status on {msg.topic(self.config.fleet, ids[0], 'status')}); "
                f"is a bridge running for each with --fleet {self.config.fleet}?"
            )
        blind = lambda: [v.id for v in self.vehicles if v.fix is None]  # noqa: E731
        if not self._wait(lambda: not blind(), timeout):
            ids = blind()
            raise GuadalError(
                f"vehicle{'s' if len(ids) > 1 else ''} {', '.join(map(str, ids))} sent no position within {timeout:g} s; "
                "is the autopilot connected to its bridge and does it have a GPS fix?"
            )

    def _on_connect(self, client, userdata, flags, reason_code, properties=None) -> None:
        if reason_code.is_failure:
            self._last_connect_error = f"broker refused the connection: {reason_code}"
            return
        msg.no_delay(client)
        fleet = self.config.fleet
        client.subscribe(
            [
                (f"{fleet}/vehicle/+/ack", 1),
                (f"{fleet}/vehicle/+/measurement", 1),
                (f"{fleet}/vehicle/+/status", 1),
                (f"{fleet}/vehicle/+/telemetry", 0),
            ]
        )
        client.publish(
            msg.topic(fleet, None, "status"), msg.encode("status", state="online"), qos=1, retain=True
        )
        with self._cond:
            self._connected = True
            outstanding = [c for v in self.vehicles for c in (v.goto, v.measure) if c is not None and c.open]
            ids = [v.id for v in self.vehicles for c in (v.goto, v.measure) if c is not None and c.open]
            self._cond.notify_all()
        for vid, command in zip(ids, outstanding):
            self._send(vid, command)
        log.info("connected to %s", self.broker_url)

    def _on_disconnect(self, client, userdata, flags, reason_code, properties=None) -> None:
        with self._cond:
            self._connected = False
        if not self._closed:
            log.warning("lost the broker at %s (%s); reconnecting", self.broker_url, reason_code)

    def _on_connect_fail(self, client, userdata) -> None:
        self._last_connect_error = "connection refused or unreachable"

    # --- incoming --------------------------------------------------------------------------
    def _drop(self, kind: str, sentence: str) -> None:
        """Count an unusable message and say why (loudly for the first few of each kind)."""
        self.dropped[kind] += 1
        loud = kind not in _EXPECTED_DROPS and self.dropped[kind] <= _LOUD_WARNINGS
        level = logging.WARNING if loud else logging.DEBUG
        log.log(level, "ignored MQTT message: %s", sentence)

    def _on_message(self, client, userdata, message) -> None:
        try:
            self._handle(message.topic, message.payload)
        except Exception as exc:  # a bug here must not kill paho's network thread
            self._drop("error", f"{message.topic}: {type(exc).__name__}: {exc}")

    _EXPECTED = {
        "ack": {"ack"},
        "telemetry": {"telemetry"},
        "measurement": {"measurement"},
        "status": {"status"},
    }

    def _handle(self, name: str, payload: bytes) -> None:
        try:
            vid, channel = msg.parse_topic(self.config.fleet, name)
        except msg.ProtocolError as exc:
            return self._drop("topic", str(exc))
        if vid is None or channel not in self._EXPECTED:
            return self._drop("topic", f"topic '{name}' is not one the planner listens to.")
        if not 0 <= vid < self.n_vehicles:
            return self._drop(
                "unknown_vehicle", f"{name}: vehicle {vid} is not in this fleet (0..{self.n_vehicles - 1})."
            )
        try:
            data = msg.decode(payload, self._EXPECTED[channel])
        except msg.ProtocolError as exc:
            return self._drop("malformed", f"{name}: {exc}")
        with self._cond:
            getattr(self, f"_on_{channel}")(self.vehicles[vid], data)
            self._cond.notify_all()

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
                    self._vehicle_done(
                        v, f"vehicle {v.id} could not measure at node {v.measure.node}: {v.measure.reason}"
                    )
                return  # an accepted measure is answered by a measurement
            kind = "stale" if seq <= v.seq else "unexpected_seq"
            return self._drop(
                kind, f"vehicle {v.id}: '{status}' ack for seq {seq}, which is not the current command."
            )
        if not cmd.open:
            return self._drop("duplicate", f"vehicle {v.id}: repeated '{status}' ack for seq {seq}.")
        if status == "accepted":
            cmd.status = "accepted"
        elif status == "reached":
            cmd.status, cmd.reply = "reached", data
            if cmd.count_distance and cmd.from_node >= 0:
                v.distance += self.graph.distance(cmd.from_node, cmd.node)
            v.node = cmd.node
        else:  # rejected, failed
            cmd.status, cmd.reason = status, str(data.get("reason") or "no reason given")
            self._vehicle_done(v, f"vehicle {v.id} {status} the goto to node {cmd.node}: {cmd.reason}.")

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
        if v.t0 is not None:
            v.track.append({"vehicle": v.id, "lat": lat, "lon": lon, "time_s": t - v.t0})

    def _on_status(self, v: RemoteVehicle, data: dict) -> None:
        state, before = data["state"], v.state
        v.state = state
        if state in ("offline", "failsafe") and v.t0 is not None:
            why = (
                "went offline (its bridge stopped or lost the broker)"
                if state == "offline"
                else "entered failsafe"
            )
            self._vehicle_done(v, f"vehicle {v.id} {why}; it takes no further part in the mission.")
        elif state != "offline" and before in ("unknown", "offline"):
            for cmd in (v.goto, v.measure):
                if cmd is not None and cmd.open:
                    self._send(v.id, cmd)  # it may have missed it while away

    def _vehicle_done(self, v: RemoteVehicle, sentence: str) -> None:
        if v.problem is None:
            v.problem = sentence
            self.problems.append(sentence)
            log.warning("%s", sentence)

    # --- outgoing --------------------------------------------------------------------------
    def _send(self, vid: int, cmd: Command) -> None:
        cmd.sent_at = time.monotonic()
        self._client.publish(msg.topic(self.config.fleet, vid, "command"), cmd.payload, qos=1)

    def _issue(
        self, v: RemoteVehicle, kind: str, node: int, count_distance: bool = True, **fields
    ) -> Command:
        """A new command with the next seq, recorded as outstanding and published."""
        with self._send_lock:
            seq = v.next_seq()
            cmd = Command(
                seq=seq,
                kind=kind,
                payload=msg.encode(kind, seq=seq, node=int(node), **fields),
                node=int(node),
                sent_at=time.monotonic(),
                from_node=v.node,
                count_distance=count_distance,
            )
            with self._cond:
                setattr(v, "goto" if kind == "goto" else "measure", cmd)
            self._send(v.id, cmd)
        return cmd

    def _goto(self, v: RemoteVehicle, node: int, count_distance: bool = True) -> None:
        self._issue(
            v, "goto", node, count_distance, lat=float(self.graph.lat[node]), lon=float(self.graph.lon[node])
        )

    def _keep_alive(self) -> None:
        """Re-send unanswered commands; ping the vehicles with nothing outstanding.

        Either way every bridge hears from the planner at least every ``ping_interval`` seconds,
        which keeps its comms-loss failsafe quiet while the planner is alive.
        """
        cfg = self.config
        last_ping = {v.id: 0.0 for v in self.vehicles}
        while not self._stop.wait(cfg.ping_interval / 4):
            if not self._connected:
                continue
            for v in self.vehicles:
                with self._send_lock:
                    now = time.monotonic()
                    open_cmds = [c for c in (v.goto, v.measure) if c is not None and c.open]
                    for cmd in open_cmds:
                        if now - cmd.sent_at >= cfg.ping_interval:
                            self._send(v.id, cmd)
                    last = max([last_ping[v.id]] + [c.sent_at for c in (v.goto, v.measure) if c is not None])
                    if not open_cmds and now - last >= cfg.ping_interval:
                        self._client.publish(
                            msg.topic(cfg.fleet, v.id, "command"), msg.encode("ping", seq=v.next_seq()), qos=1
                        )
                        last_ping[v.id] = now

    def _wait(self, predicate: Callable[[], bool], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        with self._cond:
            while not predicate():
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(min(left, 0.25))
        return True

    # --- the Fleet contract ------------------------------------------------------------------
    def reset(self, initial_nodes: Sequence[int]) -> None:
        """Bring every vehicle to its start node (not counted) and start the clocks there."""
        if len(initial_nodes) != self.n_vehicles:
            raise GuadalError(f"reset needs {self.n_vehicles} initial nodes, got {len(initial_nodes)}.")
        self.connect()
        for v, node in zip(self.vehicles, initial_nodes):
            v.problem, v.distance, v.t0 = None, 0.0, None
            self._goto(v, int(node), count_distance=False)
        timeout = self.config.reset_timeout
        if not self._wait(lambda: all(not v.goto.open for v in self.vehicles), timeout):
            late = [f"{v.id} (node {v.goto.node}, {v.goto.status})" for v in self.vehicles if v.goto.open]
            raise GuadalError(
                f"vehicles {', '.join(late)} did not reach their start nodes within {timeout:g} s; "
                "raise backend.reset_timeout or check the bridges."
            )
        refused = [v.problem for v in self.vehicles if v.problem]
        if refused:
            raise GuadalError(f"the fleet could not take its start positions: {' '.join(refused)}")
        self._start_clocks()
        with self._cond:
            for v, node in zip(self.vehicles, initial_nodes):
                v.node, v.distance = int(node), 0.0
                v.track.clear()

    def _start_clocks(self) -> None:
        """Read every vehicle's clock now that all are in place: mission time starts here.

        Each autopilot has its own clock, so each gets its own origin. Asking the start goto
        again (a duplicate seq) makes each bridge repeat its ``reached`` ack with a fresh ``t``.
        """
        with self._cond:
            for v in self.vehicles:
                v.syncing = True
        for v in self.vehicles:
            self._send(v.id, v.goto)
        self._wait(lambda: not any(v.syncing for v in self.vehicles), min(5.0, self.config.reset_timeout))
        with self._cond:
            for v in self.vehicles:
                if v.syncing:  # no fresh answer: the latest reading will do
                    v.syncing, v.t0 = False, v.t

    def _cannot_move(self, v: RemoteVehicle) -> bool:
        """Same rule as the local fleet: no neighbour within the remaining budget."""
        remaining = self._max_distance - v.distance
        nbrs = self.graph.neighbors(v.node)
        return not nbrs or min(self.graph.edge_length(v.node, n) for n in nbrs) > remaining + 1e-9

    def _done(self) -> dict[int, bool]:
        return {v.id: v.problem is not None or self._cannot_move(v) for v in self.vehicles}

    def move(self, targets: Mapping[int, int]) -> tuple[dict[int, bool], dict[int, bool]]:
        """One edge towards each target, all vehicles at once; returns when every hop ended."""
        moving: list[RemoteVehicle] = []
        for vid, target in targets.items():
            v, target = self.vehicles[vid], int(target)
            if v.problem is not None or v.node == target:
                continue
            path = self.graph.shortest_path(v.node, target)
            if len(path) < 2:
                raise GuadalError(f"vehicle {v.id} cannot reach node {target} from node {v.node} over water.")
            if self.graph.edge_length(v.node, path[1]) > self._max_distance - v.distance + 1e-9:
                continue  # the hop would overrun the budget: not taken, as in simulation
            self._goto(v, path[1])
            moving.append(v)
        timeout = self.config.hop_timeout
        if not self._wait(lambda: all(not v.goto.open or v.problem for v in moving), timeout):
            late = next(v for v in moving if v.goto.open and not v.problem)
            raise GuadalError(self._late_sentence(late, timeout))
        reached = {vid: self.vehicles[vid].node == int(t) for vid, t in targets.items()}
        done = self._done()
        return {vid: reached[vid] or done[vid] for vid in targets}, done

    def _late_sentence(self, v: RemoteVehicle, timeout: float) -> str:
        cmd = v.goto
        where = ""
        if v.fix is not None:
            x, y = self.graph.map.projection.to_xy(*v.fix)
            gap = math.hypot(float(x) - self.graph.x[cmd.node], float(y) - self.graph.y[cmd.node])
            where = f", last fix {gap:.1f} m from it"
        link = "" if self._connected else f"; the broker at {self.broker_url} is unreachable"
        return (
            f"vehicle {v.id} did not reach node {cmd.node} within {timeout:g} s "
            f"(goto seq {cmd.seq} {'accepted' if cmd.status == 'accepted' else 'never acknowledged'}{where}{link}); "
            "raise backend.hop_timeout or check the vehicle and its bridge."
        )

    def take_measurement(self, vehicles: Sequence[int] | None = None) -> list[Measurement]:
        ids = list(range(self.n_vehicles) if vehicles is None else vehicles)
        if self.config.measurements == "synthetic":
            if self.sensor is None:
                raise GuadalError(
                    "backend.measurements is 'synthetic', but the environment has no synthetic sensor."
                )
            now = self.mission_time
            return [
                Measurement(
                    vehicle=vid,
                    node=(n := self.vehicles[vid].node),
                    value=float(self.sensor(vid, n)),
                    lat=float(self.graph.lat[n]),
                    lon=float(self.graph.lon[n]),
                    time_s=now,
                )
                for vid in ids
            ]
        return self._measure_on_vehicles(ids)

    def _measure_on_vehicles(self, ids: list[int]) -> list[Measurement]:
        asked = [self.vehicles[vid] for vid in ids if self.vehicles[vid].problem is None]
        for v in asked:
            self._issue(v, "measure", v.node)
        timeout = self.config.measure_timeout
        if not self._wait(lambda: all(not v.measure.open or v.problem for v in asked), timeout):
            late = [str(v.id) for v in asked if v.measure.open and not v.problem]
            raise GuadalError(
                f"vehicle {', '.join(late)} sent no measurement within {timeout:g} s; "
                "raise backend.measure_timeout or check the bridge's --sensor."
            )
        failed = [v.problem for v in asked if v.measure.status in ("rejected", "failed")]
        if failed and len(failed) == len(asked):
            raise GuadalError(f"no vehicle could measure: {' '.join(failed)}")
        out = []
        for v in asked:
            if v.measure.reply is None:
                continue  # failed, or went offline while measuring: that vehicle is done
            r = v.measure.reply
            lat, lon = r.get("lat"), r.get("lon")
            if not all(isinstance(x, (int, float)) and math.isfinite(x) for x in (lat, lon)):
                lat, lon = float(self.graph.lat[v.node]), float(self.graph.lon[v.node])
            t = r.get("t")
            time_s = t - v.t0 if isinstance(t, (int, float)) and v.t0 is not None else self.mission_time
            out.append(
                Measurement(
                    vehicle=v.id,
                    node=v.node,
                    value=float(r["value"]),
                    lat=float(lat),
                    lon=float(lon),
                    time_s=float(time_s),
                )
            )
        return out

    @property
    def mission_time(self) -> float:
        """The vehicles' clock since reset (the latest of them), from telemetry."""
        with self._cond:
            spans = [v.t - v.t0 for v in self.vehicles if v.t is not None and v.t0 is not None]
        return max(spans, default=0.0)

    def health(self) -> dict:
        with self._cond:
            return {"dropped_messages": dict(sorted(self.dropped.items())), "problems": list(self.problems)}

    def track_rows(self) -> list[dict]:
        with self._cond:
            rows = [row for v in self.vehicles for row in v.track]
            for v in self.vehicles:
                v.track.clear()
        return sorted(rows, key=lambda r: (r["time_s"], r["vehicle"]))

    def close(self) -> None:
        """Hold every vehicle, say the planner is going offline, disconnect, stop a launched stack."""
        if self._closed:
            return
        self._closed = True
        noisy = {k: n for k, n in self.dropped.items() if k not in _EXPECTED_DROPS}
        if noisy:
            log.warning(
                "ignored %d unusable MQTT messages during the mission (%s).",
                sum(noisy.values()),
                ", ".join(f"{k}: {n}" for k, n in sorted(noisy.items())),
            )
        try:
            self._stop.set()
            if self._started:
                if self._keeper.is_alive():
                    self._keeper.join(5)
                if self._connected:
                    with self._send_lock:
                        infos = [
                            self._client.publish(
                                msg.topic(self.config.fleet, v.id, "command"),
                                msg.encode("hold", seq=v.next_seq()),
                                qos=1,
                            )
                            for v in self.vehicles
                        ]
                    infos.append(
                        self._client.publish(
                            msg.topic(self.config.fleet, None, "status"),
                            msg.encode("status", state="offline"),
                            qos=1,
                            retain=True,
                        )
                    )
                    for info in infos:
                        try:
                            info.wait_for_publish(2.0)
                        except (RuntimeError, ValueError):
                            break
                self._client.disconnect()
                self._client.loop_stop()
        finally:
            if self._on_close is not None:
                self._on_close()


# --- backends ------------------------------------------------------------------------------
class SitlConfig(RemoteConfig):
    """Backend ``sitl``: MAVLink boats in software behind real bridges and a real broker."""

    level: str = "sitl"
    measurements: Literal["synthetic", "vehicle"] = "synthetic"
    launch: bool = Field(
        default=False, description="Start broker, emulator and bridges for this run, and stop them after."
    )
    speedup: float = Field(default=50.0, gt=0, description="Emulator time speed-up when launching.")
    broker_kind: Literal["auto", "mosquitto", "embedded"] = Field(
        default="auto", description="Broker to launch: Mosquitto if installed (auto), or the embedded one."
    )
    failsafe_timeout: float = Field(
        default=30.0, gt=0, description="Bridges' comms-loss failsafe when launching, seconds."
    )
    emulator_args: list[str] = Field(
        default_factory=list, description="Extra 'guadal sitl' options when launching."
    )
    bridge_args: list[str] = Field(
        default_factory=list, description="Extra 'guadal bridge' options when launching."
    )
    stack_timeout: float = Field(
        default=60.0, gt=0, description="Seconds for a launched stack to become ready."
    )


class RealConfig(RemoteConfig):
    """Backend ``real``: physical boats; their bridges run on the companion computers."""

    level: str = "real"
    measurements: Literal["synthetic", "vehicle"] = "vehicle"
    hop_timeout: float = 600.0
    reset_timeout: float = 1800.0
    connect_timeout: float = 60.0


def _fleet(config: RemoteConfig, graph, fleet_config, sensor, on_close=None) -> RemoteFleet:
    return RemoteFleet(
        graph, fleet_config.vehicles, fleet_config.max_distance, sensor, config, on_close=on_close
    )


class SitlBackend:
    """Entry point of the ``sitl`` level; with ``launch: true`` it owns a whole stack for the run."""

    Config = SitlConfig

    def __init__(self, config: SitlConfig):
        self.config = config

    def make_fleet(self, *, graph: NavGraph, fleet_config, sensor: Sensor, mission=None) -> Fleet:
        cfg = self.config
        if not cfg.launch:
            return _fleet(cfg, graph, fleet_config, sensor)
        from ..stack import Stack

        if mission is None or getattr(graph.map, "source", None) is None:
            raise GuadalError("backend.launch needs the mission's map file to start the bridges.")
        homes = [(float(graph.lat[n]), float(graph.lon[n])) for n in mission.initial_nodes]
        stack = Stack.launch(
            map_path=graph.map.source,
            vehicles=fleet_config.vehicles,
            homes=homes,
            speedup=cfg.speedup,
            fleet=cfg.fleet,
            broker_kind=cfg.broker_kind,
            failsafe_timeout=cfg.failsafe_timeout,
            emulator_args=cfg.emulator_args,
            bridge_args=cfg.bridge_args,
            timeout=cfg.stack_timeout,
        )
        try:
            launched = cfg.model_copy(
                update={
                    "host": stack.broker_host,
                    "port": stack.broker_port,
                    "tls": False,
                    "username": None,
                    "password": None,
                    "password_env": None,
                }
            )
            return _fleet(launched, graph, fleet_config, sensor, on_close=stack.down)
        except BaseException:
            stack.down()
            raise


class RealBackend:
    """Entry point of the ``real`` level: the same RemoteFleet, with field-sized timeouts."""

    Config = RealConfig

    def __init__(self, config: RealConfig):
        self.config = config

    def make_fleet(self, *, graph: NavGraph, fleet_config, sensor: Sensor, mission=None) -> Fleet:
        return _fleet(self.config, graph, fleet_config, sensor)
