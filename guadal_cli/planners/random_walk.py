"""``random``: the baseline every informed planner must beat.

Sequential mode: a random free neighbour. Target mode: a random node reachable within the
remaining budget. Randomness comes only from the mission seed.
"""

from __future__ import annotations

import numpy as np

from ..envs.base import Observation
from .base import SEQUENTIAL, TARGET, Planner, free_neighbours


class RandomPlanner(Planner):
    modes = (SEQUENTIAL, TARGET)

    def next_targets(self, observation: Observation) -> dict[int, int]:
        graph = observation.graph
        claimed: set[int] = set(observation.positions.values())
        targets = {}
        for v in sorted(observation.positions):
            if observation.done.get(v):
                continue
            here = observation.positions[v]
            if self.mode_ == SEQUENTIAL:
                options = free_neighbours(observation, v, claimed - {here}, budget=True)
            else:
                dist = graph.distances_from(here)
                ok = (dist <= observation.remaining[v] + 1e-9) & (dist > 0)
                ok[list(claimed)] = False
                options = np.nonzero(ok)[0].tolist()
            if options:
                targets[v] = int(options[self.rng_.integers(len(options))])
                claimed.add(targets[v])
        return targets
