"""The Environment contract.

An environment owns the ground truth (where one exists), the model built from measurements and
the task's metrics. Planners never see the ground truth: they read :class:`Observation`.

Each environment declares the per-node fields it ``provides`` (for example ``mean`` and ``std``)
and each planner the fields it ``requires``, so a mismatch is caught when the mission is
validated, not halfway through a run.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
from pydantic import BaseModel

from ..fleet.base import Measurement
from ..graph import NavGraph


@dataclass
class Observation:
    """Everything a planner may look at when choosing the next targets."""

    step: int
    time_s: float
    graph: NavGraph
    positions: dict[int, int]
    remaining: dict[int, float]
    done: dict[int, bool]
    visits: np.ndarray  # samples taken per node so far
    fields: dict[str, np.ndarray] = field(default_factory=dict)  # per-node arrays: mean, std, ...
    task: dict = field(default_factory=dict)


class Environment(ABC):
    """Ground truth, model and metrics for one task on one graph.

    Subclasses set ``Config`` (a pydantic model of their parameters), ``provides`` and
    ``metric_names``. ``sense`` is the synthetic sensor used at ``sim`` level (and at remote
    levels when measurements are synthetic); it owns its random generator so the same seed
    gives the same samples at every level.
    """

    Config: ClassVar[type[BaseModel]]
    provides: ClassVar[frozenset[str]] = frozenset()
    metric_names: ClassVar[tuple[str, ...]] = ()

    def __init__(self, config: BaseModel, graph: NavGraph, base_dir=None):
        self.config = config
        self.graph = graph
        self.base_dir = base_dir  # where relative paths in the config resolve

    @abstractmethod
    def reset(self, seed: int) -> None:
        """Draw the ground truth and clear the model; same seed, same world."""

    @abstractmethod
    def sense(self, vehicle: int, node: int) -> float:
        """A synthetic measurement at ``node`` (ground truth plus configured noise)."""

    @abstractmethod
    def update(self, measurements: Sequence[Measurement]) -> None:
        """Fold new measurements into the model and the task state."""

    def advance(self, time_s: float) -> None:
        """Let an evolving world run on to mission time ``time_s`` (static worlds ignore it)."""

    @abstractmethod
    def observation_fields(self) -> dict[str, np.ndarray]:
        """Per-node arrays for planners, keyed by the names in ``provides``."""

    def task_state(self) -> dict:
        """Task facts for planners that are not per-node arrays."""
        return {}

    @abstractmethod
    def metrics(self) -> dict[str, float]:
        """Task metrics, keyed exactly by ``metric_names`` (NaN where not applicable)."""

    @property
    def ground_truth(self) -> np.ndarray | None:
        """Per-node truth for plots and RMSE; None when the world is only known by sensing."""
        return None

    def model_description(self) -> dict | None:
        """Which model estimated the world, for the run manifest (None: nothing to state)."""
        return None


class GroundTruth(ABC):
    """A ground-truth plugin (``environment.ground_truth.type``): one scalar value per node.

    ``Config`` validates its section; the constructor only stores it (and may refuse an
    inconsistent one). ``generate`` draws the field; all its randomness comes from ``rng``.
    """

    Config: ClassVar[type[BaseModel]]

    def __init__(self, config: BaseModel):
        self.config = config

    @abstractmethod
    def generate(self, graph: NavGraph, rng: np.random.Generator, base_dir=None) -> np.ndarray:
        """Values at ``graph``'s nodes; ``base_dir`` resolves relative file paths."""
