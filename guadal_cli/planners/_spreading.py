"""Helpers shared by the planners that spread a fleet over distinct targets (``frontier`` and
``detection_greedy``): frontier nodes, reachable distances, per-decision claims, and a base
class that drops targets a vehicle proved it cannot reach."""

from __future__ import annotations

import numpy as np
from scipy.sparse.csgraph import dijkstra

from ..envs.base import Observation
from .base import SEQUENTIAL, TARGET, Planner, free_neighbours


def frontier_mask(graph, observed: np.ndarray) -> np.ndarray:
    """Unobserved nodes with an observed neighbour (all unobserved nodes if none is observed)."""
    if not observed.any():
        return ~observed
    adj = graph.adjacency
    observed_neighbours = np.bincount(
        np.repeat(np.arange(graph.n_nodes), np.diff(adj.indptr)),
        weights=observed[adj.indices].astype(float),
        minlength=graph.n_nodes,
    )
    return ~observed & (observed_neighbours > 0)


def route_distances(graph, here: int, blocked: set[int]) -> np.ndarray:
    """Water distance from ``here``; inf where the shortest path runs through a ``blocked`` node.

    Parked vehicles (done, out of budget) never move again, so a target whose shortest path
    crosses one could not be reached by the runner, which walks shortest paths.
    """
    if not blocked - {here}:
        return graph.distances_from(here)
    dist, pred = dijkstra(graph.adjacency, directed=False, indices=here, return_predecessors=True)
    through = np.zeros(graph.n_nodes, dtype=bool)
    for node in np.argsort(dist, kind="stable"):
        if not np.isfinite(dist[node]):
            break
        parent = pred[node]
        through[node] = node in blocked or (parent >= 0 and through[parent])
    return np.where(through, np.inf, dist)


def pick(dist: np.ndarray, budget: float, allowed: np.ndarray, *keys: np.ndarray) -> int | None:
    """The allowed node within ``budget`` (``dist`` from the vehicle) that sorts first by ``keys``.

    ``keys`` are per-node arrays, most significant first, smaller is better, then node id; with
    no keys the nearest node wins.
    """
    ok = allowed & (dist <= budget + 1e-9) & (dist > 0)
    if not ok.any():
        return None
    idx = np.nonzero(ok)[0]
    order = np.lexsort((idx,) + tuple(k[idx] for k in reversed(keys or (dist,))))
    return int(idx[order[0]])


def hop_towards(observation: Observation, vehicle: int, target: int, claimed: set[int]) -> int | None:
    """Sequential mode: the free neighbour from which ``target`` is nearest over water."""
    options = free_neighbours(observation, vehicle, claimed, budget=True)
    if not options:
        return None
    to_target = observation.graph.distances_from(target)
    return min(options, key=lambda n: (to_target[n], n))


class TargetAssigner:
    """One decision's bookkeeping: open nodes, claims, reachable distances, moves."""

    def __init__(
        self, observation: Observation, separation_m: float, sequential: bool, banned: dict[int, set[int]]
    ):
        self.observation = observation
        self.graph = observation.graph
        self.separation = separation_m
        self.sequential = sequential
        self.banned = banned
        self.open = np.ones(self.graph.n_nodes, dtype=bool)
        self.open[list(observation.positions.values())] = False
        self.parked = {n for v, n in observation.positions.items() if observation.done.get(v)}
        self.claimed: set[int] = set()
        self.targets: dict[int, int] = {}

    def vehicles(self):
        """Vehicles that can still move, in id order."""
        return [v for v in sorted(self.observation.positions) if not self.observation.done.get(v)]

    def distances(self, vehicle: int) -> np.ndarray:
        return route_distances(self.graph, self.observation.positions[vehicle], self.parked)

    def allowed(self, vehicle: int, candidates: np.ndarray) -> np.ndarray:
        ok = self.open & candidates
        ok[list(self.banned.get(vehicle, ()))] = False
        return ok

    def assign(self, vehicle: int, target: int) -> None:
        self.open[self.graph.nodes_within(target, self.separation)] = False
        self.open[target] = False
        move = hop_towards(self.observation, vehicle, target, self.claimed) if self.sequential else target
        if move is not None:
            self.targets[vehicle] = move
            self.claimed.add(move)


def explore(assigner: TargetAssigner, vehicle: int, fields: dict, revisit: bool) -> int | None:
    """The frontier choice for one vehicle: nearest open frontier, any unobserved node, or the stalest."""
    obs = assigner.observation
    budget = obs.remaining[vehicle]
    dist = assigner.distances(vehicle)
    observed = fields["observed"] > 0
    for candidates in (frontier_mask(obs.graph, observed), ~observed):
        target = pick(dist, budget, assigner.allowed(vehicle, candidates))
        if target is not None:
            return target
    if revisit and "age" in fields and observed.all():
        age = np.nan_to_num(fields["age"], nan=np.inf)
        return pick(dist, budget, assigner.allowed(vehicle, np.ones_like(observed)), -age, dist)
    return None


class SpreadingPlanner(Planner):
    """Shared by ``frontier`` and ``detection_greedy``: targets that cannot be reached are dropped.

    In target mode, a vehicle that was sent somewhere and did not move at all (its way was
    blocked for good) never gets that target again, so a mission cannot stall on it.
    """

    def reset(self, graph, n_vehicles, mode, seed) -> None:
        super().reset(graph, n_vehicles, mode, seed)
        self.banned_: dict[int, set[int]] = {}
        self.sent_: dict[int, tuple[int, int]] = {}  # vehicle -> (position when sent, target)

    def _assigner(self, observation: Observation) -> TargetAssigner:
        for v, (start, target) in self.sent_.items():
            if observation.positions.get(v) == start:
                self.banned_.setdefault(v, set()).add(target)
        return TargetAssigner(observation, self.config.separation_m, self.mode_ == SEQUENTIAL, self.banned_)

    def _sent(self, observation: Observation, targets: dict[int, int]) -> dict[int, int]:
        if self.mode_ == TARGET:  # a blocked hop in sequential mode is a passing conflict
            self.sent_ = {v: (observation.positions[v], t) for v, t in targets.items()}
        return targets
