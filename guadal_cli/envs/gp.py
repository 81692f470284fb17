"""``gp``: water-quality mapping with a Gaussian process (the paper's gpBasedEnv).

Vehicles sample a scalar field; an incremental GP estimates mean and standard deviation at every
node. Metrics: RMSE against the ground truth (where one exists), mean and max posterior std.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from .. import plugins
from ..errors import GuadalError
from ..fleet.base import Measurement
from ..models.gp import IncrementalGP, KernelConfig
from .base import Environment


class GPConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    ground_truth: dict | None = Field(
        default_factory=lambda: {"type": "shekel"},
        description="{type: shekel|gp_prior|file, ...}; null when only real sensors know the field.",
    )
    noise_std: float = Field(default=0.0, ge=0, description="Std of synthetic measurement noise.")
    kernel: KernelConfig = KernelConfig()
    prior_mean: float = 0.0
    fit_every: int = Field(
        default=0, ge=0, description="Re-fit kernel hyperparameters every N updates (0: never)."
    )


class GPEnvironment(Environment):
    Config = GPConfig
    provides = frozenset({"mean", "std"})
    metric_names = ("rmse", "mean_std", "max_std")

    def __init__(self, config: GPConfig, graph, base_dir=None):
        super().__init__(config, graph, base_dir)
        self._truth_plugin = None
        if config.ground_truth is not None:
            cls, cfg = plugins.build_config("ground_truth", config.ground_truth, "environment.ground_truth")
            self._truth_plugin = cls(cfg)
        self.model = IncrementalGP(config.kernel, graph.xy, prior_mean=config.prior_mean)
        self._truth: np.ndarray | None = None

    def reset(self, seed: int) -> None:
        truth_seq, noise_seq = np.random.SeedSequence(seed).spawn(2)
        self._truth = (
            None
            if self._truth_plugin is None
            else np.asarray(
                self._truth_plugin.generate(self.graph, np.random.default_rng(truth_seq), self.base_dir),
                float,
            )
        )
        self._noise_rng = np.random.default_rng(noise_seq)
        self.model.kernel = self.config.kernel
        self.model.reset()
        self._updates = 0

    def sense(self, vehicle: int, node: int) -> float:
        if self._truth is None:
            raise GuadalError(
                "environment.ground_truth is null, so measurements must come from the vehicles' sensors."
            )
        value = float(self._truth[node])
        if self.config.noise_std > 0:
            value += float(self._noise_rng.normal(0.0, self.config.noise_std))
        return value

    def update(self, measurements: Sequence[Measurement]) -> None:
        for m in measurements:
            self.model.add(self.graph.xy[m.node], m.value, point=m.node)
        self._updates += 1
        if self.config.fit_every and self._updates % self.config.fit_every == 0:
            self.model.fit_hyperparameters()

    def observation_fields(self) -> dict[str, np.ndarray]:
        return {"mean": self.model.mean, "std": self.model.std}

    def metrics(self) -> dict[str, float]:
        std = self.model.std
        rmse = (
            math.nan if self._truth is None else float(np.sqrt(np.mean((self.model.mean - self._truth) ** 2)))
        )
        return {"rmse": rmse, "mean_std": float(std.mean()), "max_std": float(std.max())}

    @property
    def ground_truth(self) -> np.ndarray | None:
        return self._truth
