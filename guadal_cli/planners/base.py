"""The Planner contract, in scikit-learn's manner.

The constructor only stores the validated parameters; everything learned during a mission lives
in attributes with a trailing underscore, created in :meth:`reset`, where the seed becomes a
generator. A planner declares the modes it supports (the first is its default) and the
observation fields it needs.

Modes (from the paper):

* ``sequential``: every vehicle gets one of its (up to 8) neighbours; the model is updated
  after every hop.
* ``target``: every vehicle gets any reachable node; the runner walks it there along the
  shortest water path, measuring at every node, and updates the model once all have arrived.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict

from ..envs.base import Observation
from ..graph import NavGraph

SEQUENTIAL = "sequential"
TARGET = "target"


class NoParams(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Planner(ABC):
    """Chooses the next node of every vehicle that can still move."""

    Config: ClassVar[type[BaseModel]] = NoParams
    modes: ClassVar[tuple[str, ...]] = (SEQUENTIAL,)
    requires: ClassVar[frozenset[str]] = frozenset()

    def __init__(self, config: BaseModel | None = None):
        self.config = config if config is not None else self.Config()

    @classmethod
    def for_mission(cls, config: BaseModel, *, mission, graph: NavGraph, mode: str, base_dir, provides):
        """The config to run ``mission`` with, checked against what only the mission knows (its
        map, fleet, folder and environment): called once when the mission is prepared, so that
        ``guadal validate`` catches what ``Config`` alone cannot. Raise :class:`GuadalError`
        (its ``field`` relative to the algorithm section) to refuse it. Default: unchanged."""
        return config

    def reset(self, graph: NavGraph, n_vehicles: int, mode: str, seed: int) -> None:
        """Forget the last mission; seed the generator."""
        self.graph_ = graph
        self.n_vehicles_ = n_vehicles
        self.mode_ = mode
        self.rng_ = np.random.default_rng(seed)

    @abstractmethod
    def next_targets(self, observation: Observation) -> dict[int, int]:
        """``{vehicle: node}`` for vehicles that should move; omit a vehicle to keep it idle."""

    @property
    def done(self) -> bool:
        """True when the planner has nothing left to do (a finished coverage, say)."""
        return False


def best_node(candidates, scores, decimals: int = 9) -> int:
    """The candidate with the highest score; scores equal to ``decimals`` places are ties and go
    to the first candidate. Posteriors computed in different but equivalent ways differ by
    1e-12 or so; without this, such noise would decide between equally good nodes and two
    equivalent runs would part ways."""
    rounded = np.asarray(scores, dtype=float).round(decimals)
    best = int(rounded.argmax())
    return (
        int(candidates[best]) if isinstance(candidates, (list, tuple)) else int(np.asarray(candidates)[best])
    )


def free_neighbours(
    observation: Observation, vehicle: int, claimed: set[int], budget: bool = False
) -> list[int]:
    """Neighbours of a vehicle's node that no other vehicle holds or has claimed this step;
    with ``budget``, only those one edge within the vehicle's remaining distance."""
    node = observation.positions[vehicle]
    blocked = claimed | {n for v, n in observation.positions.items() if v != vehicle}
    graph = observation.graph
    options = (
        graph.neighbours_within(node, observation.remaining[vehicle]) if budget else graph.neighbors(node)
    )
    return [n for n in options if n not in blocked]
