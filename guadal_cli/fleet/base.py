"""The Fleet contract shared by every backend level.

Local and remote fleets are interchangeable behind it; that interchangeability is the product.
The Episode (guadal_cli/episode.py) drives a fleet one *hop* (one graph edge) at a time, exactly as the paper's loop::

    while not all(reached.values()):
        reached, done = fleet.move(targets)
    measurements = fleet.take_measurement()

so the same planner sees the same sequence of nodes at every level.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import ClassVar

from pydantic import BaseModel

from ..errors import GuadalError


@dataclass(frozen=True)
class Measurement:
    """One sample: where, when and what the sensor read."""

    vehicle: int
    node: int
    value: float
    lat: float
    lon: float
    time_s: float


#: A synthetic sensor: value at a node for a vehicle (the environment owns its randomness).
Sensor = Callable[[int, int], float]


class Fleet(ABC):
    """N vehicles on one graph, each with a position, a travelled distance and a budget."""

    n_vehicles: int
    #: set by the runner: a fleet that waits for its vehicles (a hop, a measurement under way) calls
    #: it on the mission's thread about once a second meanwhile; simulated vehicles never keep it waiting
    while_waiting: Callable[[], None] | None = None

    @abstractmethod
    def reset(self, initial_nodes: Sequence[int]) -> None:
        """Place vehicle ``i`` at ``initial_nodes[i]`` with zero distance travelled."""

    @abstractmethod
    def move(self, targets: Mapping[int, int]) -> tuple[dict[int, bool], dict[int, bool]]:
        """Advance towards ``{vehicle: node}``; return ``(reached, done)`` per vehicle.

        ``done`` is True for a vehicle that can no longer move (budget spent, failsafe).
        Call again until every vehicle has reached its target or is done.
        """

    @abstractmethod
    def take_measurement(self, vehicles: Sequence[int] | None = None) -> list[Measurement]:
        """One sample per vehicle (default: all) at its current node."""

    # Fleets keep their vehicles in ``self.vehicles`` (objects with ``id``, ``node`` and
    # ``distance``) and the budget in ``self._max_distance``, as the paper's Fleet manages its
    # Vehicles; a fleet that stores them otherwise overrides these three.
    @property
    def positions(self) -> dict[int, int]:
        """Current node of every vehicle."""
        return {v.id: v.node for v in self.vehicles}

    @property
    def distances(self) -> dict[int, float]:
        """Metres travelled along the graph by every vehicle."""
        return {v.id: v.distance for v in self.vehicles}

    @property
    def max_distance(self) -> float:
        """The distance budget of each vehicle, in metres."""
        return self._max_distance

    @property
    @abstractmethod
    def mission_time(self) -> float:
        """Seconds since reset: simulated at ``sim``, the vehicles' clock at remote levels."""

    def remaining(self) -> dict[int, float]:
        return {v: self.max_distance - d for v, d in self.distances.items()}

    # --- the rules every fleet applies the same way (they need ``self.graph``) ---------------
    def check_initial_nodes(self, initial_nodes: Sequence[int]) -> None:
        """``reset`` takes exactly one start node per vehicle."""
        if len(initial_nodes) != self.n_vehicles:
            raise GuadalError(f"reset needs {self.n_vehicles} initial nodes, got {len(initial_nodes)}.")

    def cannot_move(self, node: int, distance: float) -> bool:
        """True when no neighbour of ``node`` lies within the budget left after ``distance`` metres."""
        return self.graph.shortest_edge(node) > self.max_distance - distance + 1e-9

    def stuck(self) -> dict[int, bool]:
        """Per vehicle: True when it cannot move (see :meth:`cannot_move`)."""
        distances = self.distances
        return {v: self.cannot_move(node, distances[v]) for v, node in self.positions.items()}

    def next_hop(self, vehicle: int, node: int, target: int, distance: float) -> int | None:
        """The first node after ``node`` on the shortest water path to ``target``, or None when
        that edge would overrun the budget (the hop is not taken)."""
        path = self.graph.shortest_path(node, target)
        if len(path) < 2:
            raise GuadalError(f"vehicle {vehicle} cannot reach node {target} from node {node} over water.")
        nxt = path[1]
        if self.graph.edge_length(node, nxt) > self.max_distance - distance + 1e-9:
            return None
        return nxt

    def synthetic_measurements_at(self, vehicles: Sequence[int], time_s: float) -> list[Measurement]:
        """One sample per vehicle from the environment's sensor (``self.sensor``) at its node."""
        if self.sensor is None:
            raise GuadalError(
                "backend.measurements is 'synthetic', but the environment has no synthetic sensor."
            )
        graph, positions = self.graph, self.positions
        return [
            Measurement(
                vehicle=vid,
                node=(node := positions[vid]),
                value=float(self.sensor(vid, node)),
                lat=float(graph.lat[node]),
                lon=float(graph.lon[node]),
                time_s=time_s,
            )
            for vid in vehicles
        ]

    @property
    def lost(self) -> dict[int, str]:
        """Vehicles out of the mission through a fault (offline, failsafe, refused), with the
        sentence saying why; none in simulation. A run whose every vehicle is lost is aborted."""
        return {}

    def pending_controls(self) -> list[dict]:
        """Operator controls (pause, resume, abort, hold/release a vehicle) received since the
        last call, each once; the runner polls this between steps. None in simulation; see
        ``docs/protocol.md`` for the remote levels."""
        return []

    @property
    def synthetic_measurements(self) -> bool:
        """True when samples come from the environment's synthetic sensor (always at ``sim``)."""
        return True

    def restore(self, positions: Mapping[int, int], distances: Mapping[int, float], time_s: float) -> None:
        """Take over a resumed run: vehicles at ``positions`` having covered ``distances``, clock at ``time_s``."""
        raise GuadalError(f"the {type(self).__name__} cannot take over a resumed run.")

    def hold(self, vehicles: list[int] | None = None) -> None:
        """Stop vehicles (default: all) where they are until their next hop: an operator's pause,
        hold or abort. In simulation vehicles only move when told to, so there is nothing to do."""

    def vehicle_status(self) -> dict[int, dict]:
        """Each vehicle's state as its autopilot reports it, for operators: ``mode``, ``armed``,
        ``battery`` (percent, or None when not reported), ``link_age_s`` (seconds since the vehicle
        was last heard, None without a link) and ``fault`` (the last one, or '').

        Simulated vehicles follow each target at once, as an armed autopilot in GUIDED mode
        would; they have no battery and no link to age, and no battery figure is made up."""
        lost = self.lost
        simulated = {"mode": "GUIDED", "armed": True, "battery": None, "link_age_s": None}
        return {v: {**simulated, "fault": lost.get(v, "")} for v in range(self.n_vehicles)}

    def health(self) -> dict:
        """Faults met on the way (messages dropped, vehicles lost), for the run manifest."""
        return {}

    def track_rows(self) -> list[dict]:
        """GPS fixes received since the last call (remote levels); none in simulation.

        Each is ``{"vehicle": id, "lat": deg, "lon": deg, "time_s": vehicle clock}``; the runner
        writes them to ``trajectory.csv`` with ``source=gps``.
        """
        return []

    def close(self) -> None:
        """Release connections and processes; safe to call twice."""


class Backend(ABC):
    """A backend plugin (one ``backend.level``): builds the fleet a mission runs on.

    ``Config`` validates the mission's ``backend`` section (its ``level`` included); the
    constructor only stores it. ``make_fleet`` is called once per run; the fleet it returns is
    closed by the runner.
    """

    Config: ClassVar[type[BaseModel]]

    def __init__(self, config: BaseModel):
        self.config = config

    @abstractmethod
    def make_fleet(self, *, graph, fleet_config, sensor: Sensor, mission=None) -> Fleet:
        """The fleet for one run: ``fleet_config`` is the mission's ``fleet`` section, ``sensor``
        the environment's synthetic sensor, ``mission`` the prepared mission (or None)."""
