"""What the planner knows of each remote vehicle and of each command in flight."""

from __future__ import annotations

from dataclasses import dataclass, field

from ..track import TrackSampler


@dataclass
class Command:
    """One command in flight: what was sent, and what came back."""

    seq: int
    kind: str
    node: int
    fields: dict
    sent_at: float
    status: str = "sent"  # sent, accepted, reached, rejected, failed, answered
    reason: str = ""
    reply: dict | None = None
    claimed: dict | None = None  # a 'reached' ack not yet confirmed by the vehicle's telemetry
    waiting_fix: bool = False  # that claim was logged and counted as unconfirmed
    from_node: int = -1
    count_distance: bool = True

    @property
    def open(self) -> bool:
        return self.status in ("sent", "accepted")


@dataclass
class RemoteVehicle:
    """One remote vehicle: node, distance, clock, link and session state."""

    id: int
    node: int = -1
    distance: float = 0.0
    state: str = "unknown"  # the bridge's retained status
    problem: str | None = None  # why this vehicle is done, if it is
    goto: Command | None = None
    measure: Command | None = None
    start: Command | None = None  # the session start in flight, until the bridge accepts it
    synced: bool = False  # the bridge follows this planner's session
    away_since: float | None = None  # monotonic time its bridge went offline mid-mission
    seq: int = 0
    last_ping: float = 0.0
    t: float | None = None  # latest reading of the vehicle's clock (telemetry, acks, measurements)
    fix_t: float | None = None  # clock of the latest GPS fix
    t0: float | None = None  # the vehicle's clock at the end of reset
    syncing: bool = False  # waiting for a fresh clock reading to set t0
    fix: tuple[float, float] | None = None
    track: list[dict] = field(default_factory=list)
    track_sampler: TrackSampler = field(default_factory=TrackSampler)  # keeps fixes at the track rate
    bridge_counters: dict = field(default_factory=dict)  # the bridge's own fault counters (its status)
    heard_at: float | None = None  # monotonic time of its latest message (any kind)
    mode: str | None = None  # the autopilot's mode, arming and battery, as its telemetry reports them
    armed: bool | None = None
    battery: float | None = None

    def next_seq(self) -> int:
        self.seq += 1
        return self.seq
