"""``gp``: water-quality mapping with a Gaussian process (the paper's gpBasedEnv).

Vehicles sample a scalar field; a GP estimates mean and standard deviation at every node.
Metrics: RMSE against the ground truth (where one exists), mean and max posterior std.

The model is the exact incremental GP while its samples x nodes matrix fits in
``model.exact_max_mb``; past that (from the first sample on a very large lake) the local GP
(each node from its nearest samples) takes over, built from the samples so far. The run
manifest says which model ran and from which sample. Model updates run with one BLAS thread
(``model.blas_threads``): missions run side by side on shared cores then do not slow each other
down by oversubscribing them.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from contextlib import nullcontext
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from threadpoolctl import ThreadpoolController

from .. import plugins
from ..errors import GuadalError
from ..fleet.base import Measurement
from ..models.gp import IncrementalGP, KernelConfig
from ..models.local_gp import LocalGP
from .base import Environment


class ModelConfig(BaseModel):
    """Which GP estimates the field, and the local GP's settings."""

    model_config = ConfigDict(extra="forbid")
    type: Literal["auto", "exact", "local"] = Field(
        default="auto", description="auto: exact while it fits in exact_max_mb, then local."
    )
    exact_max_mb: float = Field(
        default=256.0, ge=0, description="Memory the exact GP may use before auto switches to local."
    )
    neighbours: int = Field(default=32, ge=1, le=256, description="Local GP: samples per node.")
    radius: float = Field(
        default=4.0, gt=0, description="Local GP: samples farther than this many length scales are ignored."
    )
    blas_threads: int = Field(
        default=1, ge=0, description="BLAS threads for model updates (0: the library's default)."
    )


class GPConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    ground_truth: dict | None = Field(
        default_factory=lambda: {"type": "shekel"},
        description="{type: shekel|gp_prior|file, ...}; null when only real sensors know the field.",
    )
    noise_std: float = Field(
        default=0.0, ge=0, le=1e6, description="Std of synthetic measurement noise (at most 1e6)."
    )
    kernel: KernelConfig = KernelConfig()
    prior_mean: float = 0.0
    fit_every: int = Field(
        default=0, ge=0, description="Re-fit kernel hyperparameters every N updates (0: never)."
    )
    model: ModelConfig = ModelConfig()


class GPEnvironment(Environment):
    Config = GPConfig
    provides = frozenset({"mean", "std"})
    metric_names = ("rmse", "mean_std", "max_std")

    def __init__(self, config: GPConfig, graph, base_dir=None):
        super().__init__(config, graph, base_dir)
        self._truth_plugin = None
        if config.ground_truth is not None:
            cls, cfg = plugins.build_config("ground_truth", config.ground_truth, "environment.ground_truth")
            try:
                self._truth_plugin = cls(cfg)
            except GuadalError as exc:
                raise exc.within("environment.ground_truth") from None
        self.model: IncrementalGP | LocalGP = self._exact_model()
        self._local_since: int | None = None  # the sample from which the local GP took over
        self._truth: np.ndarray | None = None

    def _exact_model(self) -> IncrementalGP:
        return IncrementalGP(self.config.kernel, self.graph.xy, prior_mean=self.config.prior_mean)

    def _local_model(self) -> LocalGP:
        m = self.config.model
        return LocalGP(
            self.config.kernel,
            self.graph.xy,
            prior_mean=self.config.prior_mean,
            neighbours=m.neighbours,
            radius=m.radius,
        )

    def _switch_to_local(self) -> None:
        """Hand the samples so far to a local GP (the exact one would outgrow its memory)."""
        exact = self.model
        self.model = self._local_model()
        self.model.kernel = exact.kernel
        self.model.add_many(exact.X_, exact.y_)
        self._local_since = exact.n_

    def _blas(self):
        threads = self.config.model.blas_threads
        return BlasThreads(threads) if threads else nullcontext()

    def reset(self, seed: int) -> None:
        truth_seq, noise_seq = np.random.SeedSequence(seed).spawn(2)
        self._truth = None
        if self._truth_plugin is not None:
            try:
                truth = self._truth_plugin.generate(
                    self.graph, np.random.default_rng(truth_seq), self.base_dir
                )
            except GuadalError as exc:
                raise exc.within("environment.ground_truth") from None
            self._truth = np.asarray(truth, float)
        self._noise_rng = np.random.default_rng(noise_seq)
        self._local_since = 0 if self.config.model.type == "local" else None
        self.model = self._local_model() if self._local_since == 0 else self._exact_model()
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
        with self._blas():
            if (
                self.config.model.type == "auto"
                and self._local_since is None
                and self.model.memory_bytes(self.model.n_ + len(measurements))
                > self.config.model.exact_max_mb * 2**20
            ):
                self._switch_to_local()
            nodes = [m.node for m in measurements]
            self.model.add_many(self.graph.xy[nodes], [m.value for m in measurements], points=nodes)
            self._updates += 1
            if self.config.fit_every and self._updates % self.config.fit_every == 0:
                self.model.fit_hyperparameters()

    def model_description(self) -> dict:
        if self._local_since is None:
            return {"type": "exact"}
        m = self.config.model
        return {
            "type": "local",
            "since_sample": self._local_since,
            "neighbours": m.neighbours,
            "radius_length_scales": m.radius,
            "reason": "model.type is local"
            if m.type == "local"
            else f"the exact GP would have outgrown model.exact_max_mb ({m.exact_max_mb:g} MB)",
        }

    def observation_fields(self) -> dict[str, np.ndarray]:
        return {"mean": self.model.mean, "std": self.model.std}

    def metrics(self) -> dict[str, float]:
        # np.add.reduce(x) / n is np.mean(x) to the bit, without its per-call overhead (every step)
        std = self.model.std
        n = len(std)
        rmse = math.nan
        if self._truth is not None:
            error = self.model.mean - self._truth
            rmse = math.sqrt(np.add.reduce(error * error) / n)
        return {"rmse": rmse, "mean_std": float(np.add.reduce(std) / n), "max_std": float(std.max())}

    @property
    def ground_truth(self) -> np.ndarray | None:
        return self._truth


@functools.cache
def blas_controller() -> ThreadpoolController:
    """The BLAS libraries loaded (inspected once: ~1 ms, too much to repeat at every update)."""
    return ThreadpoolController()


@functools.cache
def blas_libraries() -> list:
    """The BLAS libraries' controllers (each reads and sets its library's thread count)."""
    return blas_controller().select(user_api="blas").lib_controllers


class BlasThreads:
    """``threads`` BLAS threads inside the block, each library's own count restored after.

    What ``blas_controller().limit(limits=threads, user_api="blas")`` does, but reading and
    setting only the libraries' thread counts (~1 µs) instead of re-inspecting them (~10 µs):
    the model is updated at every hop of the fleet.
    """

    def __init__(self, threads: int):
        self.threads = threads
        self._libraries = blas_libraries()
        self._restore: list = []

    def __enter__(self) -> BlasThreads:
        for library in self._libraries:
            before = library.num_threads
            if before != self.threads:
                library.set_num_threads(self.threads)
                self._restore.append((library, before))
        return self

    def __exit__(self, *exc) -> None:
        while self._restore:
            library, before = self._restore.pop()
            library.set_num_threads(before)
