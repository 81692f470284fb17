"""``greedy``: each vehicle moves to its neighbour of highest posterior standard deviation.

Sequential mode, as in the paper: one hop, one sample, one model update, decide again. Vehicles
choose in id order and never pick a node another vehicle holds or has just claimed; ties go to
the lowest node id so runs are reproducible.
"""

from __future__ import annotations

from ..envs.base import Observation
from .base import SEQUENTIAL, Planner, best_node, free_neighbours


class GreedyStd(Planner):
    modes = (SEQUENTIAL,)
    requires = frozenset({"std"})

    def next_targets(self, observation: Observation) -> dict[int, int]:
        std = observation.fields["std"]
        claimed: set[int] = set()
        targets = {}
        for v in sorted(observation.positions):
            if observation.done.get(v):
                continue
            options = free_neighbours(observation, v, claimed, budget=True)
            if not options:
                continue
            best = best_node(options, std[options])
            targets[v] = best
            claimed.add(best)
        return targets
