"""The low-level planner on the boat: a water-only path to a target, as a few waypoints.

The planner's graph is coarse (one node per map cell); a boat steering straight from one
cell centre to another could clip a shoreline corner. So, as in the paper, the bridge plans on a
*high-resolution* graph: the same map with every cell split ``factor × factor``, searched with
Dijkstra through the project's own :class:`NavGraph`. The cell-by-cell path is then pulled tight
into the few waypoints a boat can follow (each leg in line of sight over water).

The geofence lives here too: a target is accepted only if it lies on a water cell of the map and
names that cell's node.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix
from scipy.spatial import cKDTree

from ..errors import GuadalError
from ..graph import NavGraph
from ..maps.format import Map


def _axis_positions(n_coarse: int, factor: int) -> np.ndarray:
    """Fractional coarse indices of the fine cell centres along one axis."""
    return (np.arange(n_coarse * factor) + 0.5) / factor - 0.5


def _interp_axis(values: np.ndarray, positions: np.ndarray, axis: int) -> np.ndarray:
    """Linear interpolation along ``axis`` at fractional indices, extrapolating at the edges."""
    n = values.shape[axis]
    base = np.clip(np.floor(positions).astype(int), 0, n - 2)
    weight = positions - base
    lo = np.take(values, base, axis=axis)
    hi = np.take(values, base + 1, axis=axis)
    shape = [1, 1]
    shape[axis] = -1
    weight = weight.reshape(shape)
    return lo + (hi - lo) * weight


def refine_map(map_: Map, factor: int) -> Map:
    """The same map with every cell split into ``factor × factor`` water or land cells.

    Fine cell centres are interpolated from the coarse cell centres in metres (exact for a
    north-up grid, and right for a grid given by coordinates), so both maps share one
    projection and a fine cell always lies inside its coarse cell.
    """
    if not isinstance(factor, int) or factor < 1:
        raise GuadalError(f"the refinement factor must be a whole number of at least 1 (got {factor!r}).")
    if factor == 1:
        return map_
    rows, cols = map_.shape
    mask = np.kron(map_.mask, np.ones((factor, factor), dtype=bool))
    fine = map_.cell_size_m / factor
    rpos, cpos = _axis_positions(rows, factor), _axis_positions(cols, factor)
    x, y = map_.x.astype(float), map_.y.astype(float)
    # a grid one cell wide gives no spacing along that axis: assume north-up square cells there
    if rows >= 2:
        x, y = _interp_axis(x, rpos, 0), _interp_axis(y, rpos, 0)
    else:
        x = np.repeat(x, rows * factor, axis=0)
        y = y[0:1, :] - (rpos[:, None] * map_.cell_size_m)
    if cols >= 2:
        x, y = _interp_axis(x, cpos, 1), _interp_axis(y, cpos, 1)
    else:
        x = x[:, 0:1] + (cpos[None, :] * map_.cell_size_m)
        y = np.repeat(y, cols * factor, axis=1)
    lat, lon = map_.projection.to_latlon(x, y)
    ref = map_.reference
    return Map(
        mask=mask,
        cell_size_m=fine,
        reference={
            "row": ref["row"] * factor + factor // 2,
            "col": ref["col"] * factor + factor // 2,
            "lat": ref["lat"],
            "lon": ref["lon"],
        },
        name=f"{map_.name} (x{factor})",
        latlon_grid=(lat, lon),
    )


@dataclass(frozen=True)
class Waypoint:
    lat: float
    lon: float


class LowLevelPlanner:
    """Geofence checks and water-only waypoint paths for one map."""

    def __init__(self, map_: Map, factor: int = 3, graph: NavGraph | None = None):
        self.map = map_
        self.graph = graph or NavGraph(map_)
        self.factor = factor
        self.fine_map = refine_map(map_, factor)
        self.fine = NavGraph(self.fine_map)
        self._discourage_corner_cuts()
        # every fine cell (land too), so "which cell is this point in" is one tree query
        self._cells = cKDTree(np.column_stack([self.fine_map.x.ravel(), self.fine_map.y.ravel()]))
        self._water = self.fine_map.mask.ravel()
        self._step = self.fine_map.cell_size_m / 4.0
        self._margin = self.fine_map.cell_size_m * 0.25

    def _discourage_corner_cuts(self) -> None:
        """Make diagonal steps past a land corner expensive, so paths keep off the shore.

        They stay possible (×10 their length): where the map joins two basins only at a corner,
        the planner's graph says the boat can pass, and the boat's graph must agree.
        """
        fine, mask = self.fine, self.fine_map.mask
        adj = fine.adjacency.tocoo()
        a, b = adj.row, adj.col
        diagonal = (fine.rows[a] != fine.rows[b]) & (fine.cols[a] != fine.cols[b])
        clear = mask[fine.rows[a], fine.cols[b]] & mask[fine.rows[b], fine.cols[a]]
        weights = np.where(diagonal & ~clear, adj.data * 10.0, adj.data)
        # NavGraph's Dijkstra reads .adjacency when first asked; nothing has been cached yet
        fine.adjacency = csr_matrix((weights, (a, b)), shape=adj.shape)

    # --- geofence --------------------------------------------------------------------------
    def check_target(self, node: int, lat: float, lon: float) -> str | None:
        """None if the target is allowed, else one sentence saying why not."""
        cell = self.map.rowcol_of(lat, lon)
        if cell is None:
            return f"target {lat:.7f},{lon:.7f} lies outside the map."
        row, col = cell
        if not self.map.mask[row, col]:
            return f"target {lat:.7f},{lon:.7f} lies on land (cell row {row}, col {col})."
        actual = self.graph.node_at(row, col)
        if actual != node:
            return f"target {lat:.7f},{lon:.7f} is node {actual}, not the node {node} the command names."
        return None

    # --- paths -----------------------------------------------------------------------------
    def _xy(self, lat: float, lon: float) -> np.ndarray:
        x, y = self.fine_map.projection.to_xy(lat, lon)
        return np.array([float(x), float(y)])

    def on_water(self, points: np.ndarray) -> np.ndarray:
        """Whether each (x, y) point lies in a water cell of the fine grid."""
        _, idx = self._cells.query(points)
        return self._water[idx]

    def line_of_sight(self, a: np.ndarray, b: np.ndarray) -> bool:
        """A straight leg that stays on water, with a small margin either side."""
        length = float(np.hypot(*(b - a)))
        n = max(2, int(math.ceil(length / self._step)) + 1)
        t = np.linspace(0.0, 1.0, n)[:, None]
        pts = a[None, :] + t * (b - a)[None, :]
        if length > 0:
            normal = np.array([-(b - a)[1], (b - a)[0]]) / length * self._margin
            pts = np.vstack([pts, pts + normal, pts - normal])
        return bool(self.on_water(pts).all())

    def plan(self, from_lat: float, from_lon: float, to_lat: float, to_lon: float) -> list[Waypoint]:
        """Waypoints from the boat's position to the target, ending exactly at the target.

        Raises :class:`GuadalError` when no water path joins them.
        """
        start = self.fine.nearest_node(from_lat, from_lon)
        goal = self.fine.nearest_node(to_lat, to_lon)
        cells = self.fine.shortest_path(start, goal)
        if not cells:
            raise GuadalError(
                f"no water path from {from_lat:.7f},{from_lon:.7f} to {to_lat:.7f},{to_lon:.7f}."
            )
        points = (
            [self._xy(from_lat, from_lon)] + [self.fine.xy[n] for n in cells] + [self._xy(to_lat, to_lon)]
        )
        keep = self._pull_tight(points)
        waypoints = []
        for i in keep[1:]:
            lat, lon = self.fine_map.projection.to_latlon(points[i][0], points[i][1])
            waypoints.append(Waypoint(float(lat), float(lon)))
        waypoints[-1] = Waypoint(float(to_lat), float(to_lon))
        return waypoints

    def _pull_tight(self, points: list[np.ndarray]) -> list[int]:
        """Indices of the points kept: from each kept point, go on while the leg stays in sight.

        A forward scan (not a search for the farthest visible point) keeps this linear in the
        path length, which matters on large maps.
        """
        keep = [0]
        i = 0
        last = len(points) - 1
        while i < last:
            j = i + 1
            while j < last and self.line_of_sight(points[i], points[j + 1]):
                j += 1
            keep.append(j)
            i = j
        # second pass over the few points kept: skip any that a longer leg can do without
        tight = [keep[0]]
        k = 0
        while keep[k] != last:
            m = len(keep) - 1
            while m > k + 1 and not self.line_of_sight(points[keep[k]], points[keep[m]]):
                m -= 1
            tight.append(keep[m])
            k = m
        return tight
