"""``trash``: find and collect floating debris (the paper's trashCleanEnv).

The world is a set of items at continuous positions (metres, the graph's x east / y north),
scattered around a few spots and optionally drifting with the water as mission time passes.
An item is *at* the node whose cell contains it.

At every sample of vehicle ``v`` at node ``p`` (in the order the samples were taken, then by
vehicle id), :meth:`TrashEnvironment.update` does, against the world as it was at the sample's
time:

1. **detect**: every uncollected item within ``vision_radius_m`` of ``p``'s centre is seen; the
   belief map forgets what it believed inside the radius and records each seen item at its
   current node;
2. **pick up**: the uncollected items in ``p``'s cell are collected, lowest item id first, up
   to ``v``'s remaining ``capacity``. An item is collected once and never again.

The synthetic sensor (:meth:`TrashEnvironment.sense`) reads the number of items the vehicle's
collector would take at ``p`` at that moment (items in the cell, capped by the capacity left);
it changes nothing, so the same readings flow at every level. In target mode the runner folds
a whole leg in at once, so a reading may count an item another vehicle took earlier on the
same leg; the metrics always use what :meth:`update` actually collected.

Drift: every item moves with ``drift.velocity`` (current plus ``wind_factor`` times the wind)
plus a random walk of ``jitter`` m/sqrt(s), in sub-steps of at most half a cell. A move that
would end on land or off the grid keeps only its east or north part if that part ends on water
(the item slides along the shore), else the item stays. Every item is moved, collected or
not, so the world evolves identically whichever algorithm runs.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from ..fleet.base import Measurement
from .base import Environment
from .world import CellLocator, DriftConfig, History, Site, count_or_list, place, substeps


class TrashConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    items: int = Field(default=40, ge=1, le=100_000, description="Number of floating items.")
    spots: list[Site] = Field(
        default=3,
        validate_default=True,
        description="Number of random spots on the largest water body, or a list of {node}|{row, col}|{lat, lon}|{} (random).",
    )
    spot_radius_m: float = Field(
        default=8.0, gt=0, description="Spread (standard deviation, metres) of items around a spot."
    )
    vision_radius_m: float = Field(
        default=10.0, ge=0, description="Vehicles see items within this many metres of their node."
    )
    capacity: int | None = Field(default=None, ge=1, description="Items a vehicle can hold; null: unlimited.")
    drift: DriftConfig = DriftConfig()
    jitter: float = Field(
        default=0.0, ge=0, le=10, description="Random-walk strength of the drift, m/sqrt(s)."
    )

    @field_validator("spots", mode="before", json_schema_input_type=int | list[Site])
    @classmethod
    def _spots(cls, value):
        return count_or_list(value, "spots")


class TrashEnvironment(Environment):
    Config = TrashConfig
    provides = frozenset({"belief", "observed", "age", "evidence"})
    metric_names = (
        "fraction_collected",
        "items_collected",
        "items_detected",
        "distance_per_item",
        "time_to_50pct",
        "time_to_90pct",
    )

    def __init__(self, config: TrashConfig, graph, base_dir=None):
        super().__init__(config, graph, base_dir)
        self._locator = CellLocator(graph)
        for i, site in enumerate(config.spots):  # a bad place is a validation error, not a run-time one
            site.resolve(graph, f"environment.spots[{i}]")
        self._velocity = config.drift.velocity
        speed = float(np.hypot(*self._velocity))
        half_cell = 0.5 * graph.map.cell_size_m
        limits = [half_cell / speed if speed > 0 else math.inf]
        if config.jitter > 0:
            limits.append((half_cell / (3 * config.jitter)) ** 2)  # 3 sigma of a sub-step within half a cell
        self._max_substep = min(limits)

    # --- the world ---------------------------------------------------------------------------
    def reset(self, seed: int) -> None:
        world_seq, drift_seq = np.random.SeedSequence(seed).spawn(2)
        rng = np.random.default_rng(world_seq)
        self._drift_rng = np.random.default_rng(drift_seq)
        self.items_xy = self._scatter(rng)
        n = self.config.items
        self.collected = np.zeros(n, dtype=bool)
        self.collected_by = np.full(n, -1, dtype=int)
        self.collected_at = np.full(n, -1, dtype=int)  # node of the pick-up
        self.detected = np.zeros(n, dtype=bool)
        self._last_seen = np.full(n, -1, dtype=int)  # node where the belief puts the item
        self._observed_at = np.full(self.graph.n_nodes, np.nan)  # mission time of the last look
        self._time = 0.0
        self._history = History(0.0, (self.items_xy.copy(), self._locator.nodes(self.items_xy)))
        self._capacity_left: dict[int, float] = {}
        self._last_node: dict[int, int] = {}
        self._distance = 0.0
        self._milestones = {0.5: math.nan, 0.9: math.nan}

    def _scatter(self, rng: np.random.Generator) -> np.ndarray:
        """Items around spots, redrawn (up to 20 times) while on land, else at the spot's centre."""
        g = self.graph
        spots = np.asarray(place(self.config.spots, g, "environment.spots", rng), dtype=int)
        centres = g.xy[spots[rng.integers(len(spots), size=self.config.items)]]
        xy = centres + rng.normal(0.0, self.config.spot_radius_m, size=centres.shape)
        for _ in range(20):
            bad = self._locator.nodes(xy) < 0
            if not bad.any():
                break
            xy[bad] = centres[bad] + rng.normal(0.0, self.config.spot_radius_m, size=(int(bad.sum()), 2))
        bad = self._locator.nodes(xy) < 0
        xy[bad] = centres[bad]
        return xy

    def advance(self, time_s: float) -> None:
        n, h = substeps(time_s - self._time, self._max_substep)
        moving = math.isfinite(self._max_substep)
        for _ in range(n if moving else 0):
            step = np.broadcast_to(self._velocity * h, self.items_xy.shape).copy()
            if self.config.jitter > 0:
                step += (
                    self.config.jitter * math.sqrt(h) * self._drift_rng.standard_normal(self.items_xy.shape)
                )
            step[self.collected] = 0.0
            self.items_xy = self._slide(self.items_xy, step)
        if time_s > self._time:
            self._time = float(time_s)
            self._history.record(self._time, (self.items_xy.copy(), self._locator.nodes(self.items_xy)))

    def _slide(self, xy: np.ndarray, step: np.ndarray) -> np.ndarray:
        """Move on water; a move onto land keeps its east or north part if that stays on water."""
        out = xy.copy()
        todo = np.ones(len(xy), dtype=bool)
        for mask in ((1.0, 1.0), (1.0, 0.0), (0.0, 1.0)):
            trial = xy[todo] + step[todo] * np.asarray(mask)
            ok = self._locator.nodes(trial) >= 0
            idx = np.nonzero(todo)[0][ok]
            out[idx] = trial[ok]
            todo[idx] = False
        return out

    # --- sensing and the model -----------------------------------------------------------------
    def sense(self, vehicle: int, node: int) -> float:
        _, nodes = self._history.latest
        here = int(np.count_nonzero((nodes == node) & ~self.collected))
        return float(min(here, self._capacity_left.get(vehicle, self._full_capacity)))

    @property
    def _full_capacity(self) -> float:
        return math.inf if self.config.capacity is None else float(self.config.capacity)

    def update(self, measurements: Sequence[Measurement]) -> None:
        g = self.graph
        for m in sorted(measurements, key=lambda m: (m.time_s, m.vehicle)):
            xy, nodes = self._history.at(m.time_s)
            v, p = m.vehicle, m.node
            self._capacity_left.setdefault(v, self._full_capacity)
            if v in self._last_node:
                self._distance += g.distance(self._last_node[v], p)
            self._last_node[v] = p
            # detect
            alive = ~self.collected
            seen = alive & (np.hypot(*(xy - g.xy[p]).T) <= self.config.vision_radius_m + 1e-9)
            looked = g.nodes_within(p, self.config.vision_radius_m)
            self._last_seen[np.isin(self._last_seen, looked)] = -1
            self._last_seen[seen] = nodes[seen]
            self.detected |= seen
            self._observed_at[looked] = m.time_s
            # pick up
            here = np.nonzero(alive & (nodes == p))[0]
            room = self._capacity_left[v]
            taken = here if math.isinf(room) else here[: int(room)]
            self.collected[taken] = True
            self.collected_by[taken] = v
            self.collected_at[taken] = p
            self._last_seen[taken] = -1
            self._capacity_left[v] = room - len(taken)
            fraction = self.collected.mean()
            for level, when in self._milestones.items():
                if math.isnan(when) and fraction >= level - 1e-12:
                    self._milestones[level] = float(m.time_s)
        self._history.forget()

    def observation_fields(self) -> dict[str, np.ndarray]:
        belief = np.bincount(self._last_seen[self._last_seen >= 0], minlength=self.graph.n_nodes).astype(
            float
        )
        observed = ~np.isnan(self._observed_at)
        return {
            "belief": belief,
            "evidence": belief,
            "observed": observed.astype(float),
            "age": np.where(observed, self._time - np.nan_to_num(self._observed_at), np.nan),
        }

    def task_state(self) -> dict:
        return {"capacity_left": dict(self._capacity_left)}

    def metrics(self) -> dict[str, float]:
        collected = int(self.collected.sum())
        return {
            "fraction_collected": collected / self.config.items,
            "items_collected": collected,
            "items_detected": int(self.detected.sum()),
            "distance_per_item": self._distance / collected if collected else math.nan,
            "time_to_50pct": self._milestones[0.5],
            "time_to_90pct": self._milestones[0.9],
        }

    @property
    def ground_truth(self) -> np.ndarray:
        """Uncollected items per node, now."""
        nodes = self._locator.nodes(self.items_xy)
        keep = (~self.collected) & (nodes >= 0)
        return np.bincount(nodes[keep], minlength=self.graph.n_nodes).astype(float)
