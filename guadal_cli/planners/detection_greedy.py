"""``detection_greedy``: go for the evidence the fleet has detected and not yet dealt with.

The environment's ``evidence`` field says where detected work waits: believed items for
``trash``, unobserved or stale water on and beside the estimated slick for ``oil_spill``.
Vehicles choose in id order among open nodes with evidence that they can reach within their
remaining budget:

* ``strategy: nearest``: the nearest such node along the water, ties to the denser;
* ``strategy: densest``: the node with the most evidence within ``density_radius_m`` (a
  cluster, not a lone item), ties to the nearer.

A choice closes every node within ``separation_m`` of it to the vehicles after it, so two
vehicles do not chase the same cluster. A vehicle with no evidence to go for, or whose
``capacity_left`` (from the environment's task state) is zero, explores as ``frontier`` does:
the nearest open frontier of unobserved water, then, once everything is observed, the stalest
observation. Target mode sends the chosen node; sequential mode the first hop towards it.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.sparse import csr_matrix

from ..envs.base import Observation
from ._spreading import SpreadingPlanner, explore, pick
from .base import SEQUENTIAL, TARGET


class DetectionGreedyConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    strategy: Literal["nearest", "densest"] = Field(
        default="nearest", description="Which evidence to go for first."
    )
    density_radius_m: float = Field(
        default=10.0, ge=0, description="Evidence within this radius counts towards a node's density."
    )
    separation_m: float = Field(
        default=15.0, ge=0, description="Metres around a chosen target closed to the other vehicles."
    )


class DetectionGreedy(SpreadingPlanner):
    Config = DetectionGreedyConfig
    modes = (TARGET, SEQUENTIAL)
    requires = frozenset({"evidence", "observed"})

    def reset(self, graph, n_vehicles, mode, seed) -> None:
        super().reset(graph, n_vehicles, mode, seed)
        rows, cols = [], []
        for node in range(graph.n_nodes):
            near = graph.nodes_within(node, self.config.density_radius_m)
            rows.extend([node] * len(near))
            cols.extend(near.tolist())
        self.within_ = csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(graph.n_nodes, graph.n_nodes))

    def next_targets(self, observation: Observation) -> dict[int, int]:
        evidence = np.asarray(observation.fields["evidence"], float)
        density = self.within_ @ evidence
        capacity = observation.task.get("capacity_left", {})
        assigner = self._assigner(observation)
        for v in assigner.vehicles():
            target = None
            if capacity.get(v, np.inf) > 0:
                dist = assigner.distances(v)
                keys = (dist, -density) if self.config.strategy == "nearest" else (-density, dist)
                target = pick(dist, observation.remaining[v], assigner.allowed(v, evidence > 0), *keys)
            if target is None:
                target = explore(assigner, v, observation.fields, revisit=True)
            if target is not None:
                assigner.assign(v, target)
        return self._sent(observation, assigner.targets)
