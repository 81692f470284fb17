"""The algorithm-level fleet: ideal vehicles that move along graph edges instantly.

Time is simulated: each hop takes ``edge length / speed`` and the vehicles move together, so
the mission clock advances by the longest hop of a step.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from pydantic import BaseModel, ConfigDict

from ..graph import NavGraph
from .base import Backend, Fleet, Measurement, Sensor


class Vehicle:
    """One simulated vehicle: its node and the distance it has covered."""

    def __init__(self, vehicle_id: int):
        self.id = vehicle_id
        self.node = -1
        self.distance = 0.0


class LocalFleet(Fleet):
    """Batch control of simulated vehicles, with synthetic measurements from a sensor.

    A hop that would overrun a vehicle's budget is not taken; the rules are the Fleet base's.
    """

    def __init__(self, graph: NavGraph, n_vehicles: int, max_distance: float, speed: float, sensor: Sensor):
        self.graph = graph
        self.n_vehicles = int(n_vehicles)
        self.speed = float(speed)
        self.sensor = sensor
        self._max_distance = float(max_distance)
        self.vehicles = [Vehicle(i) for i in range(self.n_vehicles)]
        self._time = 0.0

    def reset(self, initial_nodes: Sequence[int]) -> None:
        self.check_initial_nodes(initial_nodes)
        for vehicle, node in zip(self.vehicles, initial_nodes):
            vehicle.node, vehicle.distance = int(node), 0.0
        self._time = 0.0

    def move(self, targets: Mapping[int, int]) -> tuple[dict[int, bool], dict[int, bool]]:
        longest = 0.0
        for vid, target in targets.items():
            vehicle, target = self.vehicles[vid], int(target)
            if vehicle.node == target:
                continue
            nxt = self.next_hop(vid, vehicle.node, target, vehicle.distance)
            if nxt is None:
                continue
            length = self.graph.edge_length(vehicle.node, nxt)
            vehicle.node = nxt
            vehicle.distance += length
            longest = max(longest, length)
        self._time += longest / self.speed
        reached = {vid: self.vehicles[vid].node == int(t) for vid, t in targets.items()}
        done = self.stuck()
        for vid in targets:
            reached[vid] = reached[vid] or done[vid]
        return reached, done

    def restore(self, positions: Mapping[int, int], distances: Mapping[int, float], time_s: float) -> None:
        for vehicle in self.vehicles:
            vehicle.node, vehicle.distance = int(positions[vehicle.id]), float(distances[vehicle.id])
        self._time = float(time_s)

    def take_measurement(self, vehicles: Sequence[int] | None = None) -> list[Measurement]:
        return self.synthetic_measurements_at(
            range(self.n_vehicles) if vehicles is None else vehicles, self._time
        )

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
