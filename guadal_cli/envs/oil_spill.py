"""``oil_spill``: detect and delimit a spreading contaminant (the paper's OilSpillEnv).

The truth is a concentration field on the water cells (units of contaminant per m2) that
spreads by advection with the surface drift and by diffusion, released by configurable
sources. It is integrated with a finite-volume scheme on the map's grid (cells of
``cell_size_m``): explicit first-order upwind advection plus diffusion across the faces
between 4-neighbouring *water* cells. No flux crosses a water-land face, so land is a no-flux
boundary and oil piles up against the shore; with no decay and no continuous release the total
mass is conserved up to float rounding. Each sub-step ``dt`` satisfies

    dt * ((|u| + |v|) / dx + 4 D / dx^2) <= 0.9

which keeps every cell's outflow below its content (no negative concentrations), and is no
longer than ``max_substep_s``. ``decay_rate`` k removes mass as ``exp(-k dt)`` (evaporation,
recovery): the only sink.

Sensing, as the paper describes: a vehicle at node ``p`` reads the concentration at ``p``
(:meth:`OilSpillEnvironment.sense`), and :meth:`OilSpillEnvironment.update` overwrites the
observed map at every node within ``view_radius_m`` of ``p`` with the concentration there at
the sample's time (``p`` itself with the reading), deterministically. The estimated
contaminated area is ``observed map > threshold``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator
from scipy.sparse import csr_matrix

from ..fleet.base import Measurement
from .base import Environment
from .world import DriftConfig, History, Site, count_or_list, place, substeps


class OilSource(Site):
    """Where and how contaminant enters: ``mass`` at once, then ``rate`` per second."""

    mass: float = Field(default=1000.0, ge=0, description="Units released at start_s.")
    rate: float = Field(default=0.0, ge=0, description="Units per second released from start_s on.")
    start_s: float = Field(default=0.0, ge=0, description="Mission time of the release.")
    duration_s: float | None = Field(
        default=None, gt=0, description="How long the rate lasts; null: to the end."
    )
    radius_m: float = Field(
        default=5.0, ge=0, description="The release is shared equally by the nodes within this radius."
    )


class OilSpillConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    sources: list[OilSource] = Field(
        default=1,
        validate_default=True,
        description="Number of random sources (default release) on the largest water body, or a list of sources.",
    )
    diffusivity: float = Field(
        default=0.05,
        ge=0,
        le=10,
        description="Horizontal diffusivity D, m2/s (at most 10: a lake's is below 1).",
    )
    drift: DriftConfig = DriftConfig()
    decay_rate: float = Field(default=0.0, ge=0, description="First-order loss rate k, 1/s (0: no sink).")
    threshold: float = Field(
        default=0.1, gt=0, description="Concentration above which water counts as contaminated."
    )
    view_radius_m: float = Field(
        default=10.0, ge=0, description="A sample overwrites the observed map within this radius."
    )
    stale_after_s: float = Field(
        default=600.0, gt=0, description="An observation older than this is a lead worth renewing."
    )
    max_substep_s: float = Field(default=30.0, gt=0, description="Longest integration sub-step, seconds.")

    @field_validator("sources", mode="before", json_schema_input_type=int | list[OilSource])
    @classmethod
    def _sources(cls, value):
        return count_or_list(value, "sources")


class OilSpillEnvironment(Environment):
    Config = OilSpillConfig
    provides = frozenset({"concentration", "observed", "age", "evidence"})
    metric_names = ("detection_coverage", "iou", "concentration_rmse", "observed_fraction", "total_mass")

    def __init__(self, config: OilSpillConfig, graph, base_dir=None):
        super().__init__(config, graph, base_dir)
        g = graph
        self._dx = float(g.map.cell_size_m)
        self._area = self._dx**2
        for i, source in enumerate(config.sources):  # a bad place is a validation error, not a run-time one
            source.resolve(g, f"environment.sources[{i}]")
        # faces between 4-neighbouring water cells: a -> b is east (along x) or south (along -y)
        east = [(a, g.node_at(int(g.rows[a]), int(g.cols[a]) + 1)) for a in range(g.n_nodes)]
        south = [(a, g.node_at(int(g.rows[a]) + 1, int(g.cols[a]))) for a in range(g.n_nodes)]
        east = np.array([(a, b) for a, b in east if b is not None], dtype=int).reshape(-1, 2)
        south = np.array([(a, b) for a, b in south if b is not None], dtype=int).reshape(-1, 2)
        self._face_a = np.concatenate([east[:, 0], south[:, 0]])
        self._face_b = np.concatenate([east[:, 1], south[:, 1]])
        u, v = config.drift.velocity
        # speed across each face from a to b: u on east faces, -v on south faces (y points north)
        self._face_speed = np.concatenate([np.full(len(east), u), np.full(len(south), -v)])
        rate = (abs(u) + abs(v)) / self._dx + 4 * config.diffusivity / self._dx**2
        self._max_substep = min(config.max_substep_s, 0.9 / rate if rate > 0 else math.inf)
        ones = np.ones(g.adjacency.nnz)
        self._touching = csr_matrix((ones, g.adjacency.indices, g.adjacency.indptr), shape=g.adjacency.shape)

    # --- the world ---------------------------------------------------------------------------
    def reset(self, seed: int) -> None:
        rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])
        g = self.graph
        self._sources = list(
            zip(place(self.config.sources, g, "environment.sources", rng), self.config.sources)
        )
        self._footprints = [g.nodes_within(n, s.radius_m) for n, s in self._sources]
        self.mass = np.zeros(g.n_nodes)
        self._started = [False] * len(self._sources)
        self._time = 0.0
        self._release(0.0, 0.0)
        self._history = History(0.0, self.concentration_truth)
        self.estimate = np.zeros(g.n_nodes)
        self._observed_at = np.full(g.n_nodes, np.nan)

    @property
    def concentration_truth(self) -> np.ndarray:
        return self.mass / self._area

    def _release(self, t0: float, t1: float) -> None:
        """Add what the sources release in (t0, t1]; instant releases due by t1 go in whole."""
        for i, ((_, s), nodes) in enumerate(zip(self._sources, self._footprints)):
            amount = 0.0
            if not self._started[i] and s.start_s <= t1 + 1e-9:
                amount += s.mass
                self._started[i] = True
            if s.rate > 0:
                end = math.inf if s.duration_s is None else s.start_s + s.duration_s
                amount += s.rate * max(0.0, min(t1, end) - max(t0, s.start_s))
            if amount > 0:
                self.mass[nodes] += amount / len(nodes)

    def _flow(self, dt: float) -> None:
        """One explicit finite-volume step: upwind advection plus diffusion, water faces only."""
        c = self.mass / self._area
        a, b, w = self._face_a, self._face_b, self._face_speed
        upwind = np.where(w > 0, c[a], c[b])
        flux = self._dx * (
            w * upwind - self.config.diffusivity * (c[b] - c[a]) / self._dx
        )  # a -> b, per second
        moved = flux * dt
        n = self.graph.n_nodes
        self.mass = self.mass - np.bincount(a, moved, minlength=n) + np.bincount(b, moved, minlength=n)
        if self.config.decay_rate > 0:
            self.mass *= math.exp(-self.config.decay_rate * dt)

    def advance(self, time_s: float) -> None:
        n, h = substeps(time_s - self._time, self._max_substep)
        t = self._time
        for i in range(n):
            t_next = self._time + (i + 1) * h
            self._flow(h)
            self._release(t, t_next)
            t = t_next
        if time_s > self._time:
            self._time = float(time_s)
            self._history.record(self._time, self.concentration_truth)

    # --- sensing and the observed map ----------------------------------------------------------
    def sense(self, vehicle: int, node: int) -> float:
        return float(self._history.latest[node])

    def update(self, measurements: Sequence[Measurement]) -> None:
        for m in sorted(measurements, key=lambda m: (m.time_s, m.vehicle)):
            truth = self._history.at(m.time_s)
            view = self.graph.nodes_within(m.node, self.config.view_radius_m)
            self.estimate[view] = truth[view]
            self.estimate[m.node] = m.value
            self._observed_at[view] = m.time_s
        self._history.forget()

    def _age(self) -> np.ndarray:
        observed = ~np.isnan(self._observed_at)
        return np.where(observed, self._time - np.nan_to_num(self._observed_at), np.nan)

    def observation_fields(self) -> dict[str, np.ndarray]:
        age = self._age()
        observed = ~np.isnan(age)
        return {
            "concentration": self.estimate.copy(),
            "observed": observed.astype(float),
            "age": age,
            "evidence": self._leads(age),
        }

    def _leads(self, age: np.ndarray) -> np.ndarray:
        """Where to look next: unobserved or stale nodes on or beside the estimated slick.

        The value is the highest estimated concentration among the node itself and its
        neighbours that are above the threshold; fresh nodes carry none.
        """
        contaminated = np.where(self.estimate > self.config.threshold, self.estimate, 0.0)
        beside = self._touching.multiply(contaminated[None, :]).max(axis=1).toarray().ravel()
        stale = np.isnan(age) | (age > self.config.stale_after_s)
        return np.where(stale, np.maximum(beside, contaminated), 0.0)

    def metrics(self) -> dict[str, float]:
        truth = self.concentration_truth
        true_area = truth > self.config.threshold
        est_area = self.estimate > self.config.threshold
        both = int(np.count_nonzero(true_area & est_area))
        union = int(np.count_nonzero(true_area | est_area))
        n_true = int(np.count_nonzero(true_area))
        return {
            "detection_coverage": both / n_true if n_true else math.nan,
            "iou": both / union if union else math.nan,
            "concentration_rmse": float(np.sqrt(np.mean((self.estimate - truth) ** 2))),
            "observed_fraction": float(np.mean(~np.isnan(self._observed_at))),
            "total_mass": float(self.mass.sum()),
        }

    @property
    def ground_truth(self) -> np.ndarray:
        return self.concentration_truth
