"""Run N emulated boats in one process: one selector loop, one simulated clock.

Simulated time runs ``speedup`` times faster than wall time.  Each telemetry stream is due at
simulated instants (1 Hz by default, like Rover), but no stream is sent more than ``max_rate``
times per *wall* second: at speed-up 200 a 1 Hz stream would be 200 messages a second per
message per boat, and ten boats would spend the machine on packing telemetry nobody can read.
When the cap binds, a stream's simulated interval stretches to ``speedup / max_rate`` seconds —
except the position fixes (``telemetry.TRACK_MESSAGES``), which the cap never thins below twice
``track_rate`` fixes per simulated second (when asked for that often): a GPS track recorded from
them at ``track_rate`` has the same density whatever the speed-up.
"""

from __future__ import annotations

import heapq
import itertools
import math
import selectors
import socket
import sys
import time
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ..errors import GuadalError
from ..fleet.track import DEFAULT_TRACK_RATE_HZ
from .link import Link, SerialPort, TcpListener, UdpOut
from .physics import GeoFrame, HullLimits
from .telemetry import TRACK_MESSAGES, TRACK_OVERSAMPLING, send_once
from .vehicle import EmulatedBoat, VehicleConfig

#: a position stream more than this many simulated seconds behind skips ahead instead of catching up
TRACK_CATCH_UP_S = 10.0
#: wall seconds between physics updates of every boat (arrivals are detected on this beat)
PHYSICS_TICK_S = 0.02
#: system ids 1..250; the top of the range is where ground stations live (255 by habit)
MAX_VEHICLES = 250
#: simulated seconds per wall second at most: 50 Hz physics is then 50,000 ticks a wall second
MAX_SPEEDUP = 1000.0
#: metres east between consecutive default homes
HOME_SPACING_M = 5.0


@dataclass
class SitlOptions:
    vehicles: int = 1
    home: tuple[float, float] = (37.41795, -5.98345)
    homes: list[tuple[float, float]] | None = None
    speedup: float = 1.0
    base_port: int = 5760
    host: str = "127.0.0.1"
    max_speed: float = 0.5
    gps_noise_m: float = 0.0
    current_en: tuple[float, float] = (0.0, 0.0)
    udp_out: tuple[str, int] | None = None
    serial: list[str] = field(default_factory=list)  # one per vehicle: a device path or "pty"
    baud: int = 115200
    seed: int = 0
    max_rate: float = 20.0  # wall messages per second per stream, per boat
    track_rate: float = DEFAULT_TRACK_RATE_HZ  # position fixes per simulated second, whatever the speed-up
    sysid: int = 1  # system id of vehicle 1; vehicle i gets sysid + i
    param_defaults: dict[str, float] = field(default_factory=dict)  # ArduPilot parameter values

    def vehicle_homes(self) -> list[tuple[float, float]]:
        if self.homes:
            if len(self.homes) != self.vehicles:
                raise GuadalError(
                    f"gives {len(self.homes)} positions for {self.vehicles} vehicles; give one LAT,LON per vehicle.",
                    field="homes",
                )
            return list(self.homes)
        frame = GeoFrame(*self.home)
        return [frame.to_global(HOME_SPACING_M * i, 0.0) for i in range(self.vehicles)]


class SimClock:
    """Simulated seconds since start, ``speedup`` times faster than the monotonic wall clock."""

    def __init__(self, speedup: float):
        self.speedup = speedup
        self.t0 = time.monotonic()

    def sim(self, wall: float | None = None) -> float:
        return ((time.monotonic() if wall is None else wall) - self.t0) * self.speedup

    def wall(self, sim: float) -> float:
        return self.t0 + sim / self.speedup


class SitlServer:
    """The boats, their links and the loop that drives them; ``open`` then ``run``."""

    def __init__(self, options: SitlOptions):
        if not 1 <= options.vehicles <= MAX_VEHICLES:
            raise GuadalError(
                f"must be between 1 and {MAX_VEHICLES} (got {options.vehicles}).", field="vehicles"
            )
        if not 1 <= options.sysid <= MAX_VEHICLES - options.vehicles + 1:
            raise GuadalError(
                f"must be between 1 and {MAX_VEHICLES - options.vehicles + 1} for {options.vehicles} vehicles "
                f"(got {options.sysid}).",
                field="sysid",
            )
        last = 10 * (options.vehicles - 1)
        if options.base_port and not 0 < options.base_port <= 65535 - last:
            raise GuadalError(
                f"{options.base_port} leaves no port for vehicle {options.vehicles}; use 1..{65535 - last}, or 0.",
                field="base_port",
            )
        if options.udp_out and not 0 < options.udp_out[1] <= 65535 - last:
            raise GuadalError(
                f"port {options.udp_out[1]} leaves no port for vehicle {options.vehicles}; use 1..{65535 - last}.",
                field="udp_out",
            )
        for name in ("speedup", "max_speed", "gps_noise_m", "max_rate", "track_rate"):
            if not math.isfinite(getattr(options, name)):
                raise GuadalError(f"must be a finite number (got {getattr(options, name)}).", field=name)
        if not all(math.isfinite(v) for v in options.current_en):
            raise GuadalError(f"must be finite E,N m/s (got {options.current_en}).", field="current_en")
        if not 0 < options.speedup <= MAX_SPEEDUP:
            raise GuadalError(
                f"must be positive and at most {MAX_SPEEDUP:g} (got {options.speedup:g}): beyond it the "
                "boats' physics cannot keep up with the clock.",
                field="speedup",
            )
        if options.max_speed <= 0:
            raise GuadalError(f"must be positive (got {options.max_speed}).", field="max_speed")
        if options.max_rate <= 0:
            raise GuadalError(f"must be positive (got {options.max_rate}).", field="max_rate")
        if not options.track_rate > 0:
            raise GuadalError(
                f"must be positive fixes per simulated second (got {options.track_rate}).", field="track_rate"
            )
        if options.serial and len(options.serial) not in (1, options.vehicles):
            raise GuadalError(
                f"gives {len(options.serial)} devices for {options.vehicles} vehicles; give one, or one per vehicle.",
                field="serial",
            )
        if (
            options.serial
            and len(options.serial) == 1
            and options.vehicles > 1
            and options.serial[0] != "pty"
        ):
            raise GuadalError(
                "names one device, which cannot serve several vehicles; give one per vehicle, or 'pty'.",
                field="serial",
            )
        self.options = options
        self.selector = selectors.DefaultSelector()
        self.clock: SimClock | None = None
        self.boats: list[EmulatedBoat] = []
        self.links: list[Link] = []
        self.listeners: list[TcpListener] = []
        self.serials: list[SerialPort | None] = []
        self._heap: list[tuple[float, int, int, int, int]] = []
        self._generation: dict[tuple[int, int], int] = {}
        self._next_sim: dict[tuple[int, int], float] = {}
        self._counter = itertools.count()
        self._stopping = False
        self._reported_failures: set[int] = set()
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)

    # ---------------------------------------------------------------- setup
    def open(self) -> dict:
        """Bind every endpoint and start the clock; returns the ready description."""
        opts = self.options
        homes = opts.vehicle_homes()
        self.selector.register(self._wake_r, selectors.EVENT_READ, self._drain_wake)
        limits = HullLimits(max_speed=opts.max_speed)
        try:
            for i, home in enumerate(homes):
                sysid = opts.sysid + i
                link = Link(sysid, self.selector)
                self.links.append(link)
                boat = EmulatedBoat(
                    VehicleConfig(
                        sysid, home, limits, opts.gps_noise_m, opts.current_en, opts.seed, opts.param_defaults
                    ),
                    link.mav,
                )
                link.deliver = self._deliverer(boat)
                port = 0 if opts.base_port == 0 else opts.base_port + 10 * i
                try:
                    self.listeners.append(TcpListener(link, opts.host, port))
                except OSError as exc:
                    raise GuadalError(
                        f"cannot be used: nothing can listen on {opts.host}:{port} for vehicle {sysid} "
                        f"({exc.strerror}); choose another, or 0 for free ports.",
                        field="base_port",
                    ) from None
                if opts.udp_out:
                    host, port = opts.udp_out[0], opts.udp_out[1] + 10 * i
                    try:
                        UdpOut(link, host, port)
                    except OSError as exc:
                        raise GuadalError(
                            f"cannot send UDP to {host}:{port} for vehicle {sysid} ({exc})."
                        ) from None
                serial = None
                if opts.serial:
                    path = opts.serial[i] if len(opts.serial) > 1 else opts.serial[0]
                    try:
                        serial = SerialPort(link, path, opts.baud)
                    except (OSError, ValueError) as exc:
                        raise GuadalError(
                            f"cannot open serial device {path!r} for vehicle {sysid}: {exc}."
                        ) from None
                self.serials.append(serial)
                self.boats.append(boat)
        except GuadalError:
            self.close()
            raise
        self.clock = SimClock(opts.speedup)
        for i, boat in enumerate(self.boats):
            boat.streams.listener = self._restream(i)
            for msg_id, interval in boat.streams.items():
                if interval is not None:
                    self._schedule(i, msg_id, 0.0, self.clock.t0)
        return self.ready_info()

    def ready_info(self) -> dict:
        return {
            "ready": True,
            "speedup": self.options.speedup,
            "vehicles": [
                {
                    "sysid": boat.sysid,
                    "tcp": listener.port,
                    "udp_out": (
                        f"{self.options.udp_out[0]}:{self.options.udp_out[1] + 10 * i}"
                        if self.options.udp_out
                        else None
                    ),
                    "serial": serial.path if serial else None,
                    "home": list(boat.config.home),
                }
                for i, (boat, listener, serial) in enumerate(zip(self.boats, self.listeners, self.serials))
            ],
        }

    # ---------------------------------------------------------------- incoming
    def _deliverer(self, boat: EmulatedBoat):
        def deliver(msgs: list) -> None:
            boat.advance(self.clock.sim())
            for msg in msgs:
                if isinstance(msg, mavlink.MAVLink_bad_data):
                    boat.counters["bad_packets"] += 1
                    continue
                try:
                    boat.handle(msg)
                except Exception:  # a message with out-of-range fields must not stop the fleet
                    boat.counters["bad_packets"] += 1

        return deliver

    # ---------------------------------------------------------------- telemetry scheduling
    def _restream(self, index: int):
        def changed(msg_id: int) -> None:
            now = time.monotonic()
            self._schedule(
                index, msg_id, self.clock.sim(now) + (self.boats[index].streams.interval(msg_id) or 0), now
            )

        return changed

    def _schedule(self, index: int, msg_id: int, due_sim: float, not_before_wall: float) -> None:
        """(Re)plan stream ``msg_id`` of boat ``index``; older heap entries become stale."""
        key = (index, msg_id)
        gen = self._generation.get(key, 0) + 1
        self._generation[key] = gen
        if self.boats[index].streams.interval(msg_id) is None:
            return
        self._next_sim[key] = due_sim
        wall = max(self.clock.wall(due_sim), not_before_wall)
        heapq.heappush(self._heap, (wall, next(self._counter), index, msg_id, gen))

    def _send_due(self, now: float) -> None:
        sim_now = self.clock.sim(now)
        min_gap = 1.0 / self.options.max_rate
        # position fixes: never thinned below TRACK_OVERSAMPLING x track_rate per simulated second
        track_floor = min(
            self.options.speedup / self.options.max_rate,
            1.0 / (TRACK_OVERSAMPLING * self.options.track_rate),
        )
        while self._heap and self._heap[0][0] <= now:
            wall, _, index, msg_id, gen = heapq.heappop(self._heap)
            key = (index, msg_id)
            if self._generation.get(key) != gen:
                continue
            boat = self.boats[index]
            interval = boat.streams.interval(msg_id)
            if interval is None:
                continue
            if self.links[index].has_peers:
                # entries leave the heap in time order, so a loop that woke late still reports each
                # message at the simulated instant it was due (the boat integrates up to it first)
                boat.advance(min(sim_now, self.clock.sim(wall)))
                self._send_safely(boat, msg_id)
            if msg_id in TRACK_MESSAGES:
                due = self._next_sim[key] + max(interval, track_floor)
                if due <= sim_now - TRACK_CATCH_UP_S:  # hopelessly behind (a stopped process): skip ahead
                    due = sim_now
                self._schedule(index, msg_id, due, now)
                continue
            due = self._next_sim[key] + interval
            if due <= sim_now:  # fell behind (the wall-rate cap, or a slow loop): resynchronise
                due = sim_now + interval
            self._schedule(index, msg_id, due, now + min_gap)

    def _send_safely(self, boat: EmulatedBoat, msg_id: int) -> None:
        """A telemetry bug must not stop the fleet: report it once per message and carry on."""
        try:
            send_once(boat, msg_id)
        except Exception as exc:  # noqa: BLE001 - the loop must keep serving the other boats
            if msg_id not in self._reported_failures:
                self._reported_failures.add(msg_id)
                sys.stderr.write(f"sitl: vehicle {boat.sysid} could not send message {msg_id}: {exc!r}\n")

    # ---------------------------------------------------------------- loop
    def run(self) -> None:
        """Serve until :meth:`request_stop`."""
        if self.clock is None:
            self.open()
        next_tick = time.monotonic()
        while not self._stopping:
            now = time.monotonic()
            wake = next_tick if not self._heap else min(next_tick, self._heap[0][0])
            events = self.selector.select(max(0.0, wake - now))
            # telemetry first: what fell due while this process waited is stamped at its own instant
            # before incoming messages and the physics tick bring the boats up to now
            self._send_due(time.monotonic())
            for key, mask in events:
                key.data(mask)
                if self._stopping:
                    break
            now = time.monotonic()
            if now >= next_tick:
                sim_now = self.clock.sim(now)
                for boat in self.boats:
                    boat.advance(sim_now)
                next_tick = max(next_tick + PHYSICS_TICK_S, now)
            self._send_due(now)

    def request_stop(self) -> None:
        """Safe from a signal handler or another thread."""
        self._stopping = True
        try:
            self._wake_w.send(b"x")
        except OSError:
            pass

    def _drain_wake(self, mask: int) -> None:
        try:
            self._wake_r.recv(64)
        except OSError:
            pass

    def close(self) -> None:
        for listener in self.listeners:
            listener.close()
        for link in self.links:
            link.close()
        try:
            self.selector.unregister(self._wake_r)
        except (KeyError, ValueError):
            pass
        self._wake_r.close()
        self._wake_w.close()
        self.selector.close()


def stats(server: SitlServer) -> list[dict]:
    """Per-vehicle counters, for the shutdown summary."""
    return [
        dict(
            sysid=b.sysid,
            dropped_packets=link.dropped_packets,
            **b.counters,
            odometer_m=round(b.hull.odometer, 1),
        )
        for b, link in zip(server.boats, server.links)
    ]
