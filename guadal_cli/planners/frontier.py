"""``frontier``: explore the nearest unobserved frontier, vehicles spread over distinct ones.

A frontier node is a node the environment has not observed yet (its ``observed`` field is 0)
with an observed 8-neighbour, the edge of what is known; before anything is observed every
node is one. Vehicles choose in id order: each takes the frontier node nearest to it along the
water (ties to the lowest node id) that it can reach within its remaining budget, and closes
every node within ``separation_m`` of its choice to the vehicles after it, so they head for
distinct frontiers. A vehicle with no open frontier left takes any open unobserved node.

When everything has been observed and the environment reports an ``age`` per node (an
evolving world), vehicles renew the stalest observations instead (oldest first, then nearest),
if ``revisit`` is on; otherwise the planner has nothing left to send and the mission ends.

Target mode sends the chosen node; sequential mode sends the first hop towards it (a free
neighbour nearest to it along the water).
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

from ..envs.base import Observation
from ._spreading import SpreadingPlanner, explore
from .base import SEQUENTIAL, TARGET


class FrontierConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    separation_m: float = Field(
        default=15.0, ge=0, description="Metres around a chosen target closed to the other vehicles."
    )
    revisit: bool = Field(
        default=True, description="Once all is observed, renew the stalest observations (needs 'age')."
    )


class Frontier(SpreadingPlanner):
    Config = FrontierConfig
    modes = (TARGET, SEQUENTIAL)
    requires = frozenset({"observed"})

    def next_targets(self, observation: Observation) -> dict[int, int]:
        assigner = self._assigner(observation)
        for v in assigner.vehicles():
            target = explore(assigner, v, observation.fields, self.config.revisit)
            if target is not None:
                assigner.assign(v, target)
        return self._sent(observation, assigner.targets)
