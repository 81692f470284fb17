"""``expected_improvement``: Bayesian-optimisation targets, one per vehicle (target mode).

Each vehicle is sent to the reachable node of highest expected improvement over the best
mean seen at a sampled node::

    EI(x) = (mu(x) - f* - xi) Phi(z) + sigma(x) phi(z),   z = (mu(x) - f* - xi) / sigma(x)

Coordination: vehicles choose in id order, and each choice removes from the others' candidates
every node within ``exclusion_radius`` metres of it (local penalisation), so the fleet spreads
over distinct promising regions instead of converging on one peak. Candidates must be
reachable within the vehicle's remaining budget and not held by another vehicle. Where EI
vanishes everywhere (a flat posterior), the node of highest std is chosen instead.
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.stats import norm

from ..envs.base import Observation
from .base import TARGET, Planner, best_node


class EIConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    xi: float = Field(default=0.01, ge=0, description="Exploration margin added to the incumbent.")
    exclusion_radius: float = Field(
        default=30.0, ge=0, description="Metres around a chosen target closed to other vehicles."
    )
    min_target_distance: float = Field(
        default=0.0, ge=0, description="Ignore nodes closer than this (metres) to the vehicle."
    )


def expected_improvement(mean: np.ndarray, std: np.ndarray, best: float, xi: float) -> np.ndarray:
    improvement = mean - best - xi
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(std > 1e-12, improvement / std, 0.0)
    ei = improvement * norm.cdf(z) + std * norm.pdf(z)
    return np.where(std > 1e-12, np.maximum(ei, 0.0), 0.0)


class ExpectedImprovement(Planner):
    Config = EIConfig
    modes = (TARGET,)
    requires = frozenset({"mean", "std"})

    def next_targets(self, observation: Observation) -> dict[int, int]:
        mean, std = observation.fields["mean"], observation.fields["std"]
        sampled = observation.visits > 0
        best = float(mean[sampled].max()) if sampled.any() else float(mean.max())
        ei = expected_improvement(mean, std, best, self.config.xi)
        graph = observation.graph
        open_nodes = np.ones(graph.n_nodes, dtype=bool)
        open_nodes[list(observation.positions.values())] = False
        targets = {}
        for v in sorted(observation.positions):
            if observation.done.get(v):
                continue
            budget = observation.remaining[v] + 1e-9
            dist = graph.distances_from(observation.positions[v], limit=max(budget, 0.0))
            ok = open_nodes & (dist <= budget) & (dist > max(self.config.min_target_distance, 1e-9))
            if not ok.any():
                continue
            score = np.where(ok, ei, -1.0)
            if score.max() <= 1e-12:
                score = np.where(ok, std, -1.0)
            target = best_node(np.arange(graph.n_nodes), score)
            targets[v] = target
            open_nodes[graph.nodes_within(target, self.config.exclusion_radius)] = False
            open_nodes[target] = False
        return targets
