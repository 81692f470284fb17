"""Pieces shared by environments whose world moves with mission time (``trash``, ``oil_spill``).

* :class:`Site`: a place on the map given as a node, a grid cell or a lat/lon, resolved to a
  water node with one clear sentence when it is not one.
* :class:`DriftConfig`: the water's surface velocity, current plus a fraction of the wind, the
  way floating debris and oil are carried.
* :class:`CellLocator`: which node's cell holds a continuous position in metres.
* :class:`History`: the world's state at each mission time since the last model update, so a
  measurement is judged against the world as it was when it was taken, even when the runner
  folds a whole leg of samples in at once (target mode).
"""

from __future__ import annotations

import bisect
import math
from typing import Annotated, Generic, TypeVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator
from scipy.spatial import cKDTree

from ..errors import GuadalError
from ..graph import NavGraph


class Site(BaseModel):
    """At most one of ``{node}``, ``{row, col}`` or ``{lat, lon}``; none: a random water node."""

    model_config = ConfigDict(extra="forbid")
    node: int | None = Field(default=None, ge=0)
    row: int | None = None
    col: int | None = None
    lat: float | None = Field(default=None, ge=-90, le=90)
    lon: float | None = Field(default=None, ge=-180, le=180)

    @model_validator(mode="after")
    def _one_form(self):
        forms = [
            self.node is not None,
            self.row is not None or self.col is not None,
            self.lat is not None or self.lon is not None,
        ]
        if sum(forms) > 1:
            raise ValueError(
                "give one of {node}, {row, col} or {lat, lon} (or none for a random place), not several"
            )
        if forms[1] and (self.row is None or self.col is None):
            raise ValueError("a grid position needs both row and col")
        if forms[2] and (self.lat is None or self.lon is None):
            raise ValueError("a geographic position needs both lat and lon")
        return self

    @property
    def is_random(self) -> bool:
        return self.node is None and self.row is None and self.lat is None

    def resolve(self, graph: NavGraph, where: str) -> int | None:
        """The water node of this site (None when random); ``where`` names the field in errors."""
        if self.is_random:
            return None
        if self.node is not None:
            if self.node >= graph.n_nodes:
                raise GuadalError(
                    f"{where}: node {self.node} does not exist (nodes are 0..{graph.n_nodes - 1})."
                )
            return self.node
        if self.row is not None:
            node = graph.node_at(self.row, self.col)
            if node is None:
                raise GuadalError(
                    f"{where}: cell ({self.row}, {self.col}) is land or off the grid; it must be water."
                )
            return node
        rc = graph.map.rowcol_of(self.lat, self.lon)
        node = None if rc is None else graph.node_at(*rc)
        if node is None:
            raise GuadalError(
                f"{where}: ({self.lat}, {self.lon}) is on land or outside the map; it must be water."
            )
        return node


def count_or_list(value, what: str):
    """Let a list of places also be written as a count: ``3`` means three random places."""
    if isinstance(value, bool) or not isinstance(value, (int, list)):
        raise ValueError(f"must be a number of random {what} or a list of them")
    if isinstance(value, int):
        if not 1 <= value <= 1000:
            raise ValueError(f"must be between 1 and 1000 {what}")
        return [{} for _ in range(value)]
    if not value:
        raise ValueError(f"must name at least one of the {what}")
    return value


def place(sites: list[Site], graph: NavGraph, where: str, rng: np.random.Generator) -> list[int]:
    """Water nodes of ``sites``; random ones are drawn from the largest water body."""
    fixed = [s.resolve(graph, f"{where}[{i}]") for i, s in enumerate(sites)]
    body = np.nonzero(graph.component == int(np.argmax(np.bincount(graph.component))))[0]
    return [int(body[rng.integers(len(body))]) if n is None else n for n in fixed]


_Current = Annotated[float, Field(ge=-10, le=10)]
_Wind = Annotated[float, Field(ge=-100, le=100)]


class DriftConfig(BaseModel):
    """Surface velocity in m/s: ``current + wind_factor * wind`` (east, north)."""

    model_config = ConfigDict(extra="forbid")
    # physical ranges: the fastest tidal races run at about 5 m/s, hurricanes blow at about 80 m/s;
    # beyond them the drift's sub-steps would run a mission without end
    current: tuple[_Current, _Current] = Field(
        default=(0.0, 0.0), description="Water current [east, north], m/s (each within ±10)."
    )
    wind: tuple[_Wind, _Wind] = Field(
        default=(0.0, 0.0), description="Wind at 10 m [east, north], m/s (each within ±100)."
    )
    wind_factor: float = Field(
        default=0.03,
        ge=0,
        le=1,
        description="Share of the wind speed a floating object drifts with (about 3% for oil and litter).",
    )

    @property
    def velocity(self) -> np.ndarray:
        return np.asarray(self.current, float) + self.wind_factor * np.asarray(self.wind, float)


class CellLocator:
    """Maps positions in metres (the graph's x east, y north) to the node whose cell holds them.

    A position belongs to the cell with the nearest centre; a land cell, or a point more than one
    cell size from every centre (off the grid), gives ``-1``.
    """

    def __init__(self, graph: NavGraph):
        m = graph.map
        self._tree = cKDTree(np.column_stack([m.x.ravel(), m.y.ravel()]))
        self._node = np.full(m.mask.size, -1, dtype=int)
        self._node[graph.rows * m.mask.shape[1] + graph.cols] = np.arange(graph.n_nodes)
        self._reach = float(m.cell_size_m)

    def nodes(self, xy: np.ndarray) -> np.ndarray:
        dist, flat = self._tree.query(np.atleast_2d(xy))
        out = self._node[flat]
        out[dist > self._reach] = -1
        return out


T = TypeVar("T")


class History(Generic[T]):
    """Snapshots of an evolving world keyed by mission time.

    ``at(t)`` returns the latest snapshot taken at or before ``t`` (the earliest if ``t``
    precedes them all). ``forget()`` keeps only the newest: the environment calls it once it
    has folded in a batch of measurements, since later measurements are never older.
    """

    def __init__(self, time_s: float, state: T):
        self._times = [float(time_s)]
        self._states = [state]

    def record(self, time_s: float, state: T) -> None:
        """Add the state at ``time_s``, which must not precede the newest snapshot."""
        if time_s > self._times[-1]:
            self._times.append(float(time_s))
            self._states.append(state)
        else:
            self._states[-1] = state

    def at(self, time_s: float) -> T:
        i = bisect.bisect_right(self._times, float(time_s) + 1e-9) - 1
        return self._states[max(i, 0)]

    @property
    def latest(self) -> T:
        return self._states[-1]

    def forget(self) -> None:
        self._times, self._states = self._times[-1:], self._states[-1:]


def substeps(duration_s: float, max_step_s: float) -> tuple[int, float]:
    """Split ``duration_s`` into the fewest equal steps no longer than ``max_step_s``."""
    if duration_s <= 0:
        return 0, 0.0
    n = max(1, math.ceil(duration_s / max_step_s - 1e-12))
    return n, duration_s / n
