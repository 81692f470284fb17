"""RemoteFleet: the Fleet contract spoken over MQTT to one bridge per vehicle.

The runner drives it exactly as it drives the local fleet, one hop at a time, so the planner
sees the same nodes at every level. Each hop is a ``goto`` with a fresh ``seq``; the vehicle's
node changes only on a ``reached`` ack for that seq whose position, and the vehicle's own
telemetry, agree with it; the distance added is the graph length of the hop, so ``distances``
agree with ``sim`` to the metre. The state itself lives in :class:`~.owner.FleetOwner`; this
class turns the contract's calls into requests to it and waits for their outcome.

Operator controls (``pause``, ``resume``, ``abort``, ``hold``/``release`` one vehicle) arrive
signed on the planner's control topic; :meth:`RemoteFleet.pending_controls` hands them to the
runner, once each, and :meth:`RemoteFleet.hold` / :meth:`RemoteFleet.release` act on boats.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping, Sequence

from ...errors import GuadalError
from ...graph import NavGraph
from ..base import Fleet, Measurement, Sensor
from .config import RemoteConfig
from .owner import EXPECTED_DROPS, FleetOwner
from .state import RemoteVehicle

log = logging.getLogger("guadal.remote")


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
        self._closed = False
        self._started = False
        self._owner = FleetOwner(graph, self.n_vehicles, config)

    # --- read-only views of the owner's state ---------------------------------------------------
    @property
    def vehicles(self) -> list[RemoteVehicle]:
        return self._owner.vehicles

    @property
    def dropped(self):
        return self._owner.dropped

    @property
    def problems(self) -> list[str]:
        return self._owner.problems

    @property
    def session(self) -> str:
        """This run's session id (commands, acks and operator controls carry it)."""
        return self._owner.session

    @property
    def broker_url(self) -> str:
        return self._owner.channel.url

    @property
    def _connected(self) -> bool:
        return self._owner.connected

    # --- connection ------------------------------------------------------------------------------
    def connect(self, with_whoever_answers: bool = False) -> None:
        """Reach the broker, see every bridge online with a position, and start our session on each.

        ``with_whoever_answers`` (a resumed run): a vehicle not ready within ``connect_timeout`` is
        lost, with a sentence saying why, and the others go on; only a fleet with none is refused."""
        if self._started:
            return
        self._started = True
        owner = self._owner
        owner.start()
        timeout = self.config.connect_timeout
        if not owner.wait(lambda: owner.connected, timeout):
            raise GuadalError(
                f"cannot reach the MQTT broker at {self.broker_url} within {timeout:g} s "
                f"({owner.last_connect_error}); is it running, and are backend.host/port/username right?"
            )
        if with_whoever_answers:
            return self._connect_whoever_answers(timeout)
        # a bridge is ready when its status is not offline (a failsafe from an earlier run ends with
        # the first goto) and it reports a position
        silent = lambda: [v.id for v in self.vehicles if v.state in ("unknown", "offline")]  # noqa: E731
        if not owner.wait(lambda: not silent(), timeout):
            ids = silent()
            raise GuadalError(
                f"vehicle{'s' if len(ids) > 1 else ''} {', '.join(map(str, ids))} not online on {self.broker_url} "
                f"within {timeout:g} s (no live status on {self.config.fleet}/vehicle/{ids[0]}/status); "
                f"is a bridge running for each with --fleet {self.config.fleet}?"
            )
        blind = lambda: [v.id for v in self.vehicles if v.fix is None]  # noqa: E731
        if not owner.wait(lambda: not blind(), timeout):
            ids = blind()
            raise GuadalError(
                f"vehicle{'s' if len(ids) > 1 else ''} {', '.join(map(str, ids))} sent no position within {timeout:g} s; "
                "is the autopilot connected to its bridge, does it have a GPS fix, and do planner and "
                "bridges share the fleet key?"
            )
        unsynced = lambda: [v.id for v in self.vehicles if not v.synced]  # noqa: E731
        if not owner.wait(lambda: not unsynced(), timeout):
            ids = unsynced()
            raise GuadalError(
                f"vehicle{'s' if len(ids) > 1 else ''} {', '.join(map(str, ids))} did not take session "
                f"{self.session} within {timeout:g} s; their bridges log why (a different fleet key?)."
            )

    def _connect_whoever_answers(self, timeout: float) -> None:
        """(``connect`` for a resumed run.) One wait for everyone; the silent ones are lost."""
        owner = self._owner

        def why_not(v: RemoteVehicle) -> str | None:
            if v.state in ("unknown", "offline"):
                return f"no live status on {self.config.fleet}/vehicle/{v.id}/status"
            if v.fix is None:
                return "no position"
            return None if v.synced else f"did not take session {self.session}"

        owner.wait(lambda: not any(why_not(v) for v in self.vehicles), timeout)

        def lose_the_silent():
            for v in self.vehicles:
                reason = why_not(v)
                if reason:
                    owner.vehicle_done(
                        v,
                        f"vehicle {v.id} did not answer within {timeout:g} s when the run resumed ({reason}); "
                        "the mission goes on without it.",
                    )

        owner.call(lose_the_silent)
        if len(self.lost) == self.n_vehicles:
            raise GuadalError(
                f"no vehicle answered on {self.broker_url} within {timeout:g} s, so the run cannot resume: "
                f"{' '.join(self.lost.values())}"
            )

    # --- the Fleet contract ------------------------------------------------------------------
    def reset(self, initial_nodes: Sequence[int]) -> None:
        """Bring every vehicle to its start node (not counted) and start the clocks there."""
        self.check_initial_nodes(initial_nodes)
        self.connect()
        self._owner.call(lambda: [setattr(v, "problem", None) for v in self.vehicles])
        self._start_at(dict(enumerate(int(n) for n in initial_nodes)))

    def _start_at(self, nodes: Mapping[int, int], with_whoever_answers: bool = False) -> None:
        """Bring every vehicle still in the mission to its node (not counted) and start the clocks
        there; a lost one only stands at its node. ``with_whoever_answers``: a vehicle that does not
        get there in time, or refuses, is lost instead of stopping the fleet."""
        sailing = [v for v in self.vehicles if v.problem is None]

        def start():
            for v in sailing:
                v.distance, v.t0 = 0.0, None
                self._goto(v, nodes[v.id], count_distance=False)

        self._owner.call(start)
        timeout = self.config.reset_timeout
        ended = lambda: all(not v.goto.open or v.problem for v in sailing)  # noqa: E731
        if not self._owner.wait(ended, timeout) and not with_whoever_answers:
            late = [f"{v.id} (node {v.goto.node}, {v.goto.status})" for v in sailing if v.goto.open]
            raise GuadalError(
                f"vehicles {', '.join(late)} did not reach their start nodes within {timeout:g} s; "
                "raise backend.reset_timeout or check the bridges."
            )
        if with_whoever_answers:

            def lose_the_late():
                for v in sailing:
                    if v.goto.open and v.problem is None:
                        # it answers: told to stop where it is, not left sailing on unaccounted for
                        self._owner.issue(v, "hold")
                        self._owner.vehicle_done(
                            v,
                            f"vehicle {v.id} did not reach node {v.goto.node} within {timeout:g} s when the "
                            "run resumed; the mission goes on without it.",
                        )

            self._owner.call(lose_the_late)
            sailing = [v for v in sailing if v.problem is None]
            if not sailing:
                raise GuadalError(
                    f"no vehicle could take over the resumed run: {' '.join(self.lost.values())}"
                )
        refused = [v.problem for v in sailing if v.problem]
        if refused:
            raise GuadalError(f"the fleet could not take its start positions: {' '.join(refused)}")
        self._start_clocks(sailing)

        def place():
            for v in self.vehicles:
                v.node, v.distance = int(nodes[v.id]), 0.0
                v.track.clear()
                v.track_sampler.reset()

        self._owner.call(place)

    def restore(self, positions: Mapping[int, int], distances: Mapping[int, float], time_s: float) -> None:
        """Take over a resumed run with the boats that answer: each goes on from the node nearest
        its GPS fix (where it really is; the short way there is not counted, as at reset), with
        its distance as recorded and its clock going on from ``time_s``. A boat that does not
        answer is lost and stays, for the planner, at the node the record last saw it at."""
        self.connect(with_whoever_answers=True)

        def where():
            return {
                v.id: int(positions[v.id]) if v.problem else self.graph.nearest_node(*v.fix)
                for v in self.vehicles
            }

        self._start_at(self._owner.call(where), with_whoever_answers=True)

        def carry_on():
            for v in self.vehicles:
                v.distance = float(distances[v.id])
                if v.t0 is not None:
                    v.t0 -= float(time_s)

        self._owner.call(carry_on)

    @property
    def synthetic_measurements(self) -> bool:
        return self.config.measurements == "synthetic"

    def _start_clocks(self, vehicles: list[RemoteVehicle]) -> None:
        """Read every vehicle's clock now that all are in place: mission time starts here.

        Each autopilot has its own clock, so each gets its own origin. Asking the start goto
        again (a duplicate seq; pings never moved the bridge's last seq) makes each bridge
        repeat its ``reached`` ack with a fresh ``t``.
        """

        def ask():
            for v in vehicles:
                v.syncing = True
                self._owner.send(v, v.goto)

        self._owner.call(ask)
        self._owner.wait(lambda: not any(v.syncing for v in vehicles), min(5.0, self.config.reset_timeout))

        def settle():
            for v in vehicles:
                if v.syncing:  # no fresh answer: the latest reading will do
                    log.warning(
                        "vehicle %d did not repeat its start ack; its clock starts at its last reading", v.id
                    )
                    v.syncing, v.t0 = False, v.t

        self._owner.call(settle)

    def _goto(self, v: RemoteVehicle, node: int, count_distance: bool = True) -> None:
        """(On the owner's thread.)"""
        self._owner.issue(
            v,
            "goto",
            node,
            count_distance,
            lat=float(self.graph.lat[node]),
            lon=float(self.graph.lon[node]),
        )

    def _done(self) -> dict[int, bool]:
        return {v.id: v.problem is not None or self.cannot_move(v.node, v.distance) for v in self.vehicles}

    def move(self, targets: Mapping[int, int]) -> tuple[dict[int, bool], dict[int, bool]]:
        """One edge towards each target, all vehicles at once; returns when every hop ended."""
        moving: list[RemoteVehicle] = []
        hops: list[tuple[RemoteVehicle, int]] = []
        for vid, target in targets.items():
            v, target = self.vehicles[vid], int(target)
            if v.problem is not None or v.node == target:
                continue
            nxt = self.next_hop(v.id, v.node, target, v.distance)
            if nxt is None:
                continue  # the hop would overrun the budget: not taken, as in simulation
            hops.append((v, nxt))
            moving.append(v)
        self._owner.call(lambda: [self._goto(v, node) for v, node in hops])
        timeout = self.config.hop_timeout
        hops_ended = lambda: all(not v.goto.open or v.problem for v in moving)  # noqa: E731
        if not self._owner.wait(hops_ended, timeout, tick=self.while_waiting):
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
            return self.synthetic_measurements_at(ids, self.mission_time)
        return self._measure_on_vehicles(ids)

    def _measure_on_vehicles(self, ids: list[int]) -> list[Measurement]:
        asked = [self.vehicles[vid] for vid in ids if self.vehicles[vid].problem is None]
        self._owner.call(lambda: [self._owner.issue(v, "measure", v.node) for v in asked])
        timeout = self.config.measure_timeout
        answered = lambda: all(not v.measure.open or v.problem for v in asked)  # noqa: E731
        if not self._owner.wait(answered, timeout, tick=self.while_waiting):
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
        with self._owner.cond:
            spans = [v.t - v.t0 for v in self.vehicles if v.t is not None and v.t0 is not None]
        return max(spans, default=0.0)

    # --- operator controls ----------------------------------------------------------------------
    def pending_controls(self) -> list[dict]:
        """Operator controls received since the last call, oldest first, each once:
        ``{"action": "pause"|"resume"|"abort"|"hold"|"release", "vehicle": id or None, "id": str}``.
        The runner polls this between steps and decides what each means for the mission."""

        def take():
            out, self._owner.controls[:] = list(self._owner.controls), []
            return out

        return self._owner.call(take)

    def hold(self, vehicles: Sequence[int] | None = None) -> None:
        """Put vehicles (default: all) in HOLD where they are; the next goto moves them again."""
        ids = range(self.n_vehicles) if vehicles is None else vehicles
        self._owner.call(lambda: [self._owner.issue(self.vehicles[i], "hold") for i in ids])

    @property
    def lost(self) -> dict[int, str]:
        """Vehicles out of the mission (offline, failsafe, refused), with the reason."""
        return {v.id: v.problem for v in self.vehicles if v.problem is not None}

    def vehicle_status(self) -> dict[int, dict]:
        """What each bridge last reported of its autopilot, how long ago it was heard, and its fault:
        why it is out of the mission, or its bridge's state when that is not a normal one."""
        now = time.monotonic()
        with self._owner.cond:
            return {
                v.id: {
                    "mode": v.mode,
                    "armed": v.armed,
                    "battery": v.battery,
                    "link_age_s": None if v.heard_at is None else round(now - v.heard_at, 2),
                    "fault": v.problem or (f"bridge {v.state}" if v.state in ("failsafe", "offline") else ""),
                }
                for v in self.vehicles
            }

    def health(self) -> dict:
        with self._owner.cond:
            return {
                "session": self.session,
                # trajectory.csv's source=gps rows: one fix per this many seconds of the vehicles' clock
                "gps_track_rate_hz": self.config.track_rate,
                "dropped_messages": dict(sorted(self.dropped.items())),
                "problems": list(self.problems),
                # what each bridge refused or met (unsigned, foreign_session, seq_ahead...): attacks
                # on the command topics are seen there, not here
                "bridges": {v.id: dict(v.bridge_counters) for v in self.vehicles if v.bridge_counters},
            }

    def track_rows(self) -> list[dict]:
        def take():
            rows = [row for v in self.vehicles for row in v.track]
            for v in self.vehicles:
                v.track.clear()
            return rows

        return sorted(self._owner.call(take), key=lambda r: (r["time_s"], r["vehicle"]))

    def close(self) -> None:
        """Hold every vehicle, say the planner is going offline, disconnect, stop a launched stack."""
        if self._closed:
            return
        self._closed = True
        noisy = {k: n for k, n in self.dropped.items() if k not in EXPECTED_DROPS}
        if noisy:
            log.warning(
                "ignored %d unusable MQTT messages during the mission (%s).",
                sum(noisy.values()),
                ", ".join(f"{k}: {n}" for k, n in sorted(noisy.items())),
            )
        try:
            if self._started:
                owner = self._owner
                pending = []
                if owner.connected:

                    def goodbye():
                        for v in self.vehicles:
                            pending.append(
                                owner.channel.send(
                                    f"{self.config.fleet}/vehicle/{v.id}/command",
                                    "hold",
                                    session=owner.session,
                                    seq=v.next_seq(),
                                )
                            )
                        pending.append(
                            owner.channel.send(
                                f"{self.config.fleet}/planner/status",
                                "status",
                                state="offline",
                                session=owner.session,
                                retain=True,
                            )
                        )

                    owner.call(goodbye)
                owner.stop()
                owner.channel.close(pending)
        finally:
            if self._on_close is not None:
                self._on_close()
