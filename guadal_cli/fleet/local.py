"""The algorithm-level fleet: ideal vehicles that move along graph edges instantly.

Time is simulated: each hop takes ``edge length / speed`` and the vehicles move together, so
the mission clock advances by the longest hop of a step.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from pydantic import BaseModel, ConfigDict

from ..errors import GuadalError
from ..graph import NavGraph
from .base import Backend, Fleet, Measurement, Sensor


class Vehicle:
    """One simulated vehicle: its node, the distance it has covered and its budget."""

    def __init__(self, vehicle_id: int, graph: NavGraph, max_distance: float):
        self.id = vehicle_id
        self.graph = graph
        self.max_distance = float(max_distance)
        self.node = -1
        self.distance = 0.0

    def reset(self, node: int) -> None:
        self.node = int(node)
        self.distance = 0.0

    @property
    def remaining(self) -> float:
        return self.max_distance - self.distance

    def step_towards(self, target: int) -> float:
        """Move one edge along the shortest water path; return the metres covered (0 if none).

        A hop that would overrun the budget is not taken.
        """
        if target == self.node:
            return 0.0
        path = self.graph.shortest_path(self.node, target)
        if len(path) < 2:
            raise GuadalError(
                f"vehicle {self.id} cannot reach node {target} from node {self.node} over water."
            )
        nxt = path[1]
        length = self.graph.edge_length(self.node, nxt)
        if length > self.remaining + 1e-9:
            return 0.0
        self.node = nxt
        self.distance += length
        return length


class LocalFleet(Fleet):
    """Batch control of simulated vehicles, with synthetic measurements from a sensor."""

    def __init__(self, graph: NavGraph, n_vehicles: int, max_distance: float, speed: float, sensor: Sensor):
        self.graph = graph
        self.n_vehicles = int(n_vehicles)
        self.speed = float(speed)
        self.sensor = sensor
        self._max_distance = float(max_distance)
        self.vehicles = [Vehicle(i, graph, max_distance) for i in range(self.n_vehicles)]
        self._time = 0.0

    def reset(self, initial_nodes: Sequence[int]) -> None:
        if len(initial_nodes) != self.n_vehicles:
            raise GuadalError(f"reset needs {self.n_vehicles} initial nodes, got {len(initial_nodes)}.")
        for vehicle, node in zip(self.vehicles, initial_nodes):
            vehicle.reset(node)
        self._time = 0.0

    def move(self, targets: Mapping[int, int]) -> tuple[dict[int, bool], dict[int, bool]]:
        longest = 0.0
        for vid, target in targets.items():
            longest = max(longest, self.vehicles[vid].step_towards(int(target)))
        self._time += longest / self.speed
        reached = {vid: self.vehicles[vid].node == int(t) for vid, t in targets.items()}
        done = self.stuck()
        for vid in targets:
            reached[vid] = reached[vid] or done[vid]
        return reached, done

    def stuck(self) -> dict[int, bool]:
        """Per vehicle: True when no neighbour lies within its remaining budget."""
        return {v.id: self._cannot_move(v) for v in self.vehicles}

    def _cannot_move(self, vehicle: Vehicle) -> bool:
        nbrs = self.graph.neighbors(vehicle.node)
        return (
            not nbrs or min(self.graph.edge_length(vehicle.node, n) for n in nbrs) > vehicle.remaining + 1e-9
        )

    def restore(self, positions: Mapping[int, int], distances: Mapping[int, float], time_s: float) -> None:
        for vehicle in self.vehicles:
            vehicle.node, vehicle.distance = int(positions[vehicle.id]), float(distances[vehicle.id])
        self._time = float(time_s)

    def take_measurement(self, vehicles: Sequence[int] | None = None) -> list[Measurement]:
        ids = range(self.n_vehicles) if vehicles is None else vehicles
        out = []
        for vid in ids:
            node = self.vehicles[vid].node
            out.append(
                Measurement(
                    vehicle=vid,
                    node=node,
                    value=float(self.sensor(vid, node)),
                    lat=float(self.graph.lat[node]),
                    lon=float(self.graph.lon[node]),
                    time_s=self._time,
                )
            )
        return out

    @property
    def mission_time(self) -> float:
        return self._time


class SimConfig(BaseModel):
    """Backend ``sim``: nothing to configure beyond the level."""

    model_config = ConfigDict(extra="forbid")
    level: str = "sim"


class SimBackend(Backend):
    """Entry point of the ``sim`` level: builds a :class:`LocalFleet`."""

    Config = SimConfig

    def make_fleet(self, *, graph: NavGraph, fleet_config, sensor: Sensor, mission=None) -> Fleet:
        return LocalFleet(graph, fleet_config.vehicles, fleet_config.max_distance, fleet_config.speed, sensor)
